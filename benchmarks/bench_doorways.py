"""Which doorways do the team and the action planner pass? A geometric sweep over two-room layouts.

For every doorway geometry (clear width, wall angle, wall thickness, clean or jagged edges;
:func:`areasearch.sim.layouts.two_rooms`) it says whether the world's collision rule lets the robot's
footprint through (the far room is in the team's reachable region), and, for each classical planner
and team size, whether a team started in the west room (poses drawn there from the seed) gets a
robot's centre into the far room within ``--max-steps``, and at which step. There are no targets by
default (``--targets``), so that the planners' goals are frontiers: the question is the doorway.

    python benchmarks/bench_doorways.py [--widths 0.40 0.45 0.5 0.9] [--angles 0 30 60]
        [--walls 0.05 0.2] [--robots 1 3 5] [--methods greedy voronoi] [--max-steps 1500] [--targets 0]

Prints one Markdown table: a row per geometry, ``fits`` by the world's rule, then per method and
team size the first step a robot was in the far room (``-``: never within the horizon; ``n/a``:
the footprint does not fit), marked ``*`` when the team did not finish (everything explored, every
target covered) within the horizon.
"""

from __future__ import annotations

import argparse
import itertools
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.envs.goal import AreaSearchEnv
from areasearch.planners import make_planner
from areasearch.sim.layouts import TwoRooms, two_rooms
from areasearch.sim.scene import Scene, scene_from_grid
from areasearch.sim.world import sample_start_poses


def west_poses(scene: Scene, rooms: TwoRooms, robots: int, seed: int) -> np.ndarray:
    """Start poses drawn in the west room (the part of the team's region west of the wall)."""
    reachable = scene.reachable(0.18) & ~rooms.far
    return sample_start_poses(scene, reachable, robots, 0.18, np.random.default_rng(seed))


def first_step_in_far_room(
    scene: Scene, rooms: TwoRooms, method: str, robots: int, steps: int, seed: int, targets: int = 0
) -> int:
    """The first step at which a robot centre was in the far room; -1 if none within ``steps``."""
    return play(scene, rooms, method, robots, steps, seed, targets)[0]


def play(
    scene: Scene, rooms: TwoRooms, method: str, robots: int, steps: int, seed: int, targets: int = 0
) -> tuple[int, bool]:
    """The first step at which a robot centre was in the far room (-1 if none within ``steps``), and
    whether the team finished: everything explored and every target covered."""
    env = AreaSearchEnv(map=scene, num_robots=robots, seed=seed, max_steps=steps, **{"targets.count": targets})
    obs, info = env.reset(seed=seed, options={"poses": west_poses(scene, rooms, robots, seed)})
    planner = make_planner(method)
    planner.reset(np.random.default_rng(seed))
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.assign(obs))
        done = terminated or truncated
    cells = scene.world_to_cell(env.world.trajectory[: info["steps"] + 1, :, :2])
    inside = rooms.far[cells[..., 0], cells[..., 1]].any(axis=1)
    finished = info["explored_pct"] >= 100.0 and info["covered_pct"] >= 100.0
    return (int(np.argmax(inside)) if inside.any() else -1), bool(finished)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", type=float, nargs="+", default=[0.40, 0.45, 0.5, 0.9])
    parser.add_argument("--angles", type=float, nargs="+", default=[0.0, 30.0, 60.0])
    parser.add_argument("--walls", type=float, nargs="+", default=[0.05, 0.2])
    parser.add_argument("--jagged", choices=("no", "yes", "both"), default="both")
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 3, 5])
    parser.add_argument("--methods", nargs="+", default=["greedy", "utility", "voronoi", "coscan", "hungarian"])
    parser.add_argument("--max-steps", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--targets", type=int, default=0, help="targets per episode (default 0: frontiers only)")
    args = parser.parse_args()
    jagged = {"no": [False], "yes": [True], "both": [False, True]}[args.jagged]
    runs = list(itertools.product(args.methods, args.robots))
    print("| width (m) | angle (°) | wall (m) | jagged | fits | " + " | ".join(f"{m} ×{r}" for m, r in runs) + " |")
    print("|---:|---:|---:|---|---|" + "---:|" * len(runs))
    for width, angle, wall, jag in itertools.product(args.widths, args.angles, args.walls, jagged):
        rooms = two_rooms(width, wall_angle_deg=angle, wall_m=wall, jagged=jag, seed=args.seed)
        scene = scene_from_grid("two_rooms", rooms.free, rooms.cell_m)
        fits = bool((scene.reachable(0.18) & rooms.far).any() and (scene.reachable(0.18) & ~rooms.far).any())
        cells = []
        for method, robots in runs:
            if not fits:
                cells.append("n/a")
                continue
            step, finished = play(scene, rooms, method, robots, args.max_steps, args.seed, args.targets)
            cells.append((str(step) if step >= 0 else "-") + ("" if finished else "*"))
        row = f"| {width:.2f} | {angle:g} | {wall:.2f} | {'yes' if jag else 'no'} | {'yes' if fits else 'no'} | "
        print(row + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
