"""Make the example inputs of ``areasearch assign``: a partial map as a SLAM system would have it
after a few minutes, and the robots' poses on it.

Plays three robots on the bundled map ``robotathome_sarmis`` for 5 decisions (200 steps, Greedy
goals), then writes what the team has mapped as a ROS ``map_server`` map with a ROS-style origin
(``partial_map.yaml`` + ``partial_map.png``: 254 free, 0 occupied, 205 unknown), the robots' poses
and their past positions and goals (``robots.json``) and two targets seen so far (``targets.json``),
all in the map frame. Run from anywhere: ``python examples/make_partial_map.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from areasearch.assign import OccupancyMap, dumps, save_occupancy_yaml
from areasearch.harness.evaluate import planner_rng
from areasearch.goal_env import AreaSearchEnv
from areasearch.planners import make_planner

HERE = Path(__file__).resolve().parent
ORIGIN = (-4.0, -6.5)
"""Map-frame position of the map's lower-left corner, metres (a SLAM map rarely starts at 0, 0)."""


def main() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=3)
    obs, _ = env.reset(seed=3)
    planner = make_planner("greedy")
    planner.reset(planner_rng(3))
    past_positions: list[list[list[float]]] = [[] for _ in range(3)]
    past_goals: list[list[list[float] | None]] = [[] for _ in range(3)]
    world = env.world
    assert world.scene is not None and world.mapper is not None
    shift = np.asarray(ORIGIN) - np.asarray(world.scene.origin_xy)
    for _ in range(5):
        here = world.poses[:, :2] + shift
        obs, *_ = env.step(planner.assign(obs))
        goals = world.scene.cell_to_world(env.goals) + shift
        for r in range(3):
            past_positions[r].insert(0, [round(float(v), 3) for v in here[r]])
            past_goals[r].insert(0, [round(float(v), 3) for v in goals[r]] if env.goals[r, 0] >= 0 else None)
    mapper = world.mapper
    grid = OccupancyMap(mapper.explored & ~mapper.occupied, mapper.occupied.copy(), world.scene.cell_m, ORIGIN)
    save_occupancy_yaml(grid, HERE / "partial_map.yaml")
    poses = world.poses.copy()
    poses[:, :2] += shift
    robots = [
        {
            "id": f"tb3_{r}",
            "x": round(float(poses[r, 0]), 3),
            "y": round(float(poses[r, 1]), 3),
            "yaw": round(float(poses[r, 2]), 3),
            "past_positions": past_positions[r],
            "past_goals": past_goals[r],
        }
        for r in range(3)
    ]
    (HERE / "robots.json").write_text(dumps({"robots": robots}))
    seen = np.flatnonzero(world.discovered & ~world.covered)[:2]
    targets = [
        {"id": f"person_{k}", "x": round(float(xy[0]), 3), "y": round(float(xy[1]), 3)}
        for k, xy in enumerate(world.targets_xy[seen] + shift)
    ]
    (HERE / "targets.json").write_text(dumps({"targets": targets}))
    print(f"wrote {HERE / 'partial_map.yaml'}, robots.json ({len(robots)} robots), targets.json ({len(targets)})")


if __name__ == "__main__":
    main()
