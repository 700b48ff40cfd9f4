"""Floor 7, training: the run's settings (:mod:`.config`), the episodes and their records
(:mod:`.trajectory`), the rollouts (:mod:`.rollout`), PPO (:mod:`.ppo`, the sharded gradient in
:mod:`.ppo_shards`), validation and the final selection (:mod:`.validation`), the run folder
(:mod:`.runfolder`), its figures read back (:mod:`.figures`) and the loop (:mod:`.train`). Where the
rollouts and the shards run is a :class:`areasearch.runners.Runner`, chosen once by the loop.

Imports the harness (the validation episodes are seeded as the harness seeds its episodes), the
networks and the floors below.
"""
