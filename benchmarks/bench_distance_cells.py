"""The candidates' distances on coarser cells: time saved, distances moved, paths kept.

Plays one episode per map (:class:`areasearch.envs.goal.AreaSearchEnv`, the nearest-candidate choice,
the map's own 5 cm cells) and keeps the inputs of every ``--every``-th decision's candidate
extraction (the team's map, the robots, the targets, the action planner's bump marks). On each it
runs :func:`areasearch.planning.candidates.extract_candidates` with the distances marched on the
map's cells and on blocks of ``--block`` cells (``candidates.distance_cell_m``), alternating, the
fastest of ``--repeats``, and compares:

* time of the extraction (with the robots' fields kept, as the environment runs it) and of its
  distance fields alone (:func:`areasearch.planning.geodesic.fields_to`);
* the robot-candidate distances of the nodes both extractions offer: the coarse minus the fine
  distance (median, 95th percentile and largest absolute difference, metres), and the pairs one finds
  reachable and the other not;
* each robot's path to its nearest and to its farthest reachable candidate
  (:func:`areasearch.planning.paths.route_path`): time, and the coarse path's length over the fine one's.

Single process, one thread.

    python benchmarks/bench_distance_cells.py [--maps robotathome_sarmis bormann_lab_ipa] [--robots 4]
        [--block 2] [--every 4] [--repeats 3] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.envs import goal as goal_module
from areasearch.envs.goal import AreaSearchEnv, decide, nearest_candidate
from areasearch.planning import candidates as cand
from areasearch.planning.paths import route_path
from areasearch.sim.scene import load_scene


def capture(map_id: str, robots: int, seed: int, every: int) -> list[tuple[tuple[Any, ...], dict[str, Any]]]:
    """The arguments of every ``every``-th decision's ``extract_candidates`` call in one episode."""
    calls: list[tuple[tuple[Any, ...], dict[str, Any]]] = []
    original = goal_module.extract_candidates

    def keep(*args: Any, **kwargs: Any) -> cand.Candidates:
        copied = tuple(np.array(a, copy=True) if isinstance(a, np.ndarray) else a for a in args)
        calls.append((copied, {k: None if v is None else np.array(v, copy=True) for k, v in kwargs.items()}))
        return original(*args, **kwargs)

    goal_module.extract_candidates = keep  # type: ignore[assignment]
    try:
        env = AreaSearchEnv(map=map_id, num_robots=robots, seed=seed)
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(decide(env, nearest_candidate))
            done = terminated or truncated
    finally:
        goal_module.extract_candidates = original  # type: ignore[assignment]
    return calls[::every]


def timed_extract(
    args: tuple[Any, ...], kwargs: dict[str, Any], params: cand.CandidateParams
) -> tuple[float, float, Any]:
    """(extraction s, fields s, candidates) of one extraction."""
    spent: list[float] = []
    fields_to = cand.fields_to

    def timed(*a: Any, **k: Any) -> Any:
        t0 = time.perf_counter()
        out = fields_to(*a, **k)
        spent.append(time.perf_counter() - t0)
        return out

    cand.fields_to = timed  # type: ignore[assignment]
    try:
        t0 = time.perf_counter()
        found = cand.extract_candidates(*args[:5], params, **kwargs)
        total = time.perf_counter() - t0
    finally:
        cand.fields_to = fields_to  # type: ignore[assignment]
    return total, sum(spent), found


def path_length(path: np.ndarray, cell_m: float) -> float:
    if len(path) < 2:
        return 0.0
    return float(np.hypot(*np.diff(path, axis=0).T).sum() * cell_m)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", nargs="+", default=["robotathome_sarmis", "bormann_lab_ipa"])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--block", type=int, default=2, help="cells per side of a coarse cell")
    parser.add_argument("--every", type=int, default=4, help="keep every n-th decision of the episode")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(
        f"{'map':24} {'dec':>4} {'extract ms':>15} {'fields ms':>15} {'ratio':>6} {'|err| m p50/p95/max':>20} "
        f"{'pairs':>6} {'lost':>5} {'new':>4} {'path ms':>13} {'len ratio p50/max':>17}"
    )
    warm = False
    for map_id in args.maps:
        cell_m = load_scene(map_id).cell_m
        calls = capture(map_id, args.robots, args.seed, args.every)
        if not warm and calls:  # compile the kernels first (numba's cache is per source file version)
            found = cand.extract_candidates(
                *calls[0][0][:5], dataclasses.replace(calls[0][0][5], distance_block=args.block), **calls[0][1]
            )
            if found.routes is not None and len(found):
                route_path(found.routes, 0, found.cells[0] - found.routes.box.origin)
            warm = True
        t_fine = t_coarse = f_fine = f_coarse = 0.0
        p_fine = p_coarse = 0.0
        errors: list[np.ndarray] = []
        lost = new = pairs = 0
        ratios: list[float] = []
        for call_args, kwargs in calls:
            fine_p = call_args[5]
            coarse_p = dataclasses.replace(fine_p, distance_block=args.block)
            best: dict[int, tuple[float, float]] = {}
            results: dict[int, Any] = {}
            for _ in range(args.repeats):
                for block, params in ((1, fine_p), (args.block, coarse_p)):
                    total, fields, found = timed_extract(call_args, kwargs, params)
                    if block not in best or total < best[block][0]:
                        best[block] = (total, fields)
                    results[block] = found
            t_fine += best[1][0]
            f_fine += best[1][1]
            t_coarse += best[args.block][0]
            f_coarse += best[args.block][1]
            fine, coarse = results[1], results[args.block]
            # the nodes both offer, matched by cell
            flat_f = fine.cells[:, 0] * 100_000 + fine.cells[:, 1]
            flat_c = coarse.cells[:, 0] * 100_000 + coarse.cells[:, 1]
            _, i_f, i_c = np.intersect1d(flat_f, flat_c, return_indices=True)
            d_f, d_c = fine.distance_m[:, i_f], coarse.distance_m[:, i_c]
            both = np.isfinite(d_f) & np.isfinite(d_c)
            errors.append(d_c[both] - d_f[both])
            lost += int((np.isfinite(d_f) & ~np.isfinite(d_c)).sum())
            new += int((~np.isfinite(d_f) & np.isfinite(d_c)).sum())
            pairs += int(np.isfinite(d_f).sum())
            # paths to each robot's nearest and farthest reachable candidate
            for r in range(fine.distance_m.shape[0]):
                row = np.where(both[r], d_f[r], np.nan)
                if np.isnan(row).all():
                    continue
                for j in {int(np.nanargmin(row)), int(np.nanargmax(row))}:
                    cell = fine.cells[i_f[j]]
                    spans = []
                    for routes in (fine.routes, coarse.routes):
                        t0 = time.perf_counter()
                        path = route_path(routes, r, cell - routes.box.origin)
                        spans.append((time.perf_counter() - t0, path))
                    p_fine += spans[0][0]
                    p_coarse += spans[1][0]
                    a, b = path_length(spans[0][1], cell_m), path_length(spans[1][1], cell_m)
                    if a > 0 and b > 0:
                        ratios.append(b / a)
        err = np.abs(np.concatenate(errors)) if errors else np.zeros(1)
        n = max(len(calls), 1)
        print(
            f"{map_id:24} {len(calls):4d} {1e3 * t_fine / n:6.2f} -> {1e3 * t_coarse / n:5.2f} "
            f"{1e3 * f_fine / n:6.2f} -> {1e3 * f_coarse / n:5.2f} {f_coarse / max(f_fine, 1e-12):6.2f} "
            f"{np.median(err):6.3f}/{np.percentile(err, 95):5.3f}/{err.max():5.3f} "
            f"{pairs:6d} {lost:5d} {new:4d} {1e3 * p_fine / n:5.2f} -> {1e3 * p_coarse / n:5.2f} "
            f"{np.median(ratios) if ratios else float('nan'):7.3f}/{max(ratios) if ratios else float('nan'):6.3f}"
        )
    print(
        f"({args.robots} robots, nearest-candidate episodes of seed {args.seed}, every {args.every}th decision, "
        f"blocks of {args.block} cells; ms per decision, fastest of {args.repeats}; ratio = coarse / fine fields time; "
        "pairs = robot-candidate pairs reachable on the fine grid; lost / new = pairs reachable on one grid only; "
        "path ms = the paths to each robot's nearest and farthest candidate, per decision)"
    )


if __name__ == "__main__":
    main()
