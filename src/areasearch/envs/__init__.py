"""Floor 3, the environments: the PettingZoo parallel and AEC environments (one primitive action per
robot per step, :mod:`.parallel`), the Gymnasium goal environment (one long-term goal per robot per
decision, :mod:`.goal`) and the goal planners' observation (:mod:`.observation`).

Imports planning, the world and the shared leaves.
"""
