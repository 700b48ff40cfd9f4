"""Floor 2, planning on the team's map: geodesic distance fields (the FMM), the frontier and target
candidates, and the FMM action planner that drives each robot to its long-term goal (:mod:`.paths`).

Imports the world (:mod:`areasearch.sim`) and the shared leaves.
"""
