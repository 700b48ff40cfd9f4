"""Does covering need deliberate visits? Explore-only teams against the cover radius.

A team that only explores (each robot takes its nearest frontier node, targets are ignored) runs
on bundled medium maps until no frontier is left (or the paper's 3600-step horizon); the script
prints the explored and covered shares at that moment, under the ``paper`` protocol (a robot centre
passes over the target's cell) and under the ``passby`` rule with several cover radii: what
exploring alone covers on the way. A protocol in which coverage is a task of its own leaves a clear
share of targets uncovered by exploring alone.

    python benchmarks/cover_radius.py [--radii 0.2 0.3 0.5] [--maps 4] [--episodes 2] [--robots 3]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.envs.goal import AreaSearchEnv
from areasearch.planning.candidates import CandidateKind
from areasearch.sim.scene import bundled_index


def nearest_frontier(obs: dict[str, np.ndarray]) -> np.ndarray:
    """Each robot's nearest allowed frontier node (targets ignored)."""
    frontier = obs["candidates"][:, 2] == CandidateKind.FRONTIER
    allowed = obs["action_mask"].astype(bool) & frontier
    return np.where(allowed, obs["distances"], np.inf).argmin(axis=1).astype(np.int64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radii", type=float, nargs="+", default=[0.2, 0.3, 0.5])
    parser.add_argument("--maps", type=int, default=4, help="medium maps, evenly spaced by id")
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--robots", type=int, default=3)
    args = parser.parse_args()
    medium = sorted(e["id"] for e in bundled_index() if e["size_class"] == "medium")
    maps = [medium[i] for i in np.linspace(0, len(medium) - 1, args.maps).round().astype(int)]
    print(f"explore-only team of {args.robots} until no frontier is left, maps: {', '.join(maps)}")
    print(f"{'rule':>16} {'explored %':>11} {'covered %':>10} {'covered / discovered':>21}")
    for radius in [None, *args.radii]:
        settings = {"protocol": "paper"} if radius is None else {"protocol": "passby", "targets.cover_radius_m": radius}
        explored, covered, ratio = [], [], []
        for map_id in maps:
            for episode in range(args.episodes):
                env = AreaSearchEnv(map=map_id, num_robots=args.robots, **settings)
                obs, _ = env.reset(seed=episode)
                done = False
                while not done:
                    obs, _, terminated, truncated, info = env.step(nearest_frontier(obs))
                    frontiers = obs["candidate_mask"].astype(bool) & (obs["candidates"][:, 2] == CandidateKind.FRONTIER)
                    done = terminated or truncated or not frontiers.any()
                explored.append(info["explored_pct"])
                covered.append(info["covered_pct"])
                ratio.append(info["covered"] / max(info["discovered"], 1))
        rule = "paper" if radius is None else f"passby {radius:.2f} m"
        print(f"{rule:>16} {np.mean(explored):11.1f} {np.mean(covered):10.1f} {100 * np.mean(ratio):20.1f}%")


if __name__ == "__main__":
    main()
