"""Floor 7, training: the run's settings (:mod:`.config`), the rollouts (:mod:`.rollout`), PPO
(:mod:`.ppo`, the sharded gradient in :mod:`.ppo_shards`), the run folder (:mod:`.runfolder`) and the
loop (:mod:`.train`).

Imports the harness (the validation episodes are seeded as the harness seeds its episodes), the
networks and the floors below.
"""
