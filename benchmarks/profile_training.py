"""Where a training decision's time goes, part by part: the table behind docs/performance.md's
"Where a decision's time goes".

Plays the episodes of the first ``--iterations`` iterations of a training config (its untrained
network, sampled goals, the rollout's lockstep groups) in this process on one core under cProfile,
then times one PPO update over their decisions (``ppo.shards`` as the config or ``--set`` says; with
shards > 1 in ``--workers`` worker processes, and cProfile sees only the learner). A sharded update's
minibatch is taken apart: the time its shards take in the workers (the slowest and the mean shard, each
timed where it ran) and the learner's own part (splitting, sending the weights, adding the gradients,
clipping, Adam). Prints
milliseconds per decision by part (cProfile's cumulative times, so the parts' own overhead is in
them) and the robot-steps per decision:

    python benchmarks/profile_training.py [--config configs/dahgnn.toml] [--iterations 2]
        [--set KEY=VALUE ...] [--workers 2]

From the same run it prints the bound that the goal loop alone sets on the training speed ratio
(training robot-steps/s per worker over the bare ``ParallelEnv``'s on one core): with the network
and the update free, a worker spends the candidates', action planner's, world's and observation's
time per decision, and it is divided by the ``ParallelEnv``'s time for the same robot-steps.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import os
import pstats
import time
from collections.abc import Callable, Sequence
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")


PARTS = (
    # (label, file suffix, function name, part of the goal loop: counted in the ratio's bound)
    ("candidates: frontiers, targets, FMM fields (extract_candidates)", "candidates.py", "extract_candidates", True),
    ("  of which the FMM fields (geodesic.fields_to)", "geodesic.py", "fields_to", False),
    ("network: graph building and forward (dahgnn.act)", "dahgnn.py", "act", False),
    ("action planner, 40 steps (ActionPlanner.act)", "planner.py", "act", True),
    ("world, 40 steps (World.step: motion, depth, mapping, targets)", "world.py", "step", True),
    ("observation (observation.build_observation)", "observation.py", "build_observation", True),
)


def timed(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """``fn(*args)`` and the seconds it took, where it ran (a worker process)."""
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


class TimedRunner:
    """A runner that records, for each :meth:`call` (a sharded minibatch), its wall time in this process
    and each task's own time in the worker that ran it."""

    def __init__(self, runner: Any) -> None:
        self.runner = runner
        self.calls: list[tuple[float, float, list[float]]] = []
        """(start, end, each task's own seconds) of each call"""

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        t0 = time.perf_counter()
        results = self.runner.call(timed, [(fn, *task) for task in tasks])
        self.calls.append((t0, time.perf_counter(), [seconds for _, seconds in results]))
        return [out for out, _ in results]

    def __getattr__(self, name: str) -> Any:  # imap, put, share, close: the runner's own
        return getattr(self.runner, name)


def cumulative(stats: pstats.Stats, suffix: str, name: str) -> float:
    """Cumulative seconds of the functions ``name`` defined in a file ending in ``suffix``."""
    total = 0.0
    for (filename, _, function), entry in stats.stats.items():  # type: ignore[attr-defined]
        if function == name and filename.endswith(suffix):
            total += entry[3]
    return total


def main() -> None:
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.runners import make_runner
    from areasearch.training.config import load_config
    from areasearch.training.ppo import ppo_update, whole_minibatch
    from areasearch.training.ppo_shards import ShardedGradient
    from areasearch.training.rollout import expand_maps, iteration_episodes, lockstep_groups, play_group

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/dahgnn.toml")
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2, help="processes of a sharded update (ppo.shards > 1)")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    overrides = {key: json.loads(value) for key, _, value in (item.partition("=") for item in args.set)}
    config = load_config(args.config, overrides)
    torch.manual_seed(config.seed)
    torch.set_num_threads(1)
    model = DAHGNN(config.network).eval()
    network = dataclasses.asdict(config.network)
    weights = {k: v.detach().numpy().copy() for k, v in model.state_dict().items()}
    maps = expand_maps(config.rollout.maps)
    specs = [s for i in range(1, args.iterations + 1) for s in iteration_episodes(config, maps, i)]
    groups = lockstep_groups(specs, config.rollout.lockstep)
    play_group(network, weights, groups[0][:1])  # numba's and PyTorch's warm-up, not profiled
    profile = cProfile.Profile()
    t0 = time.perf_counter()
    profile.enable()
    trajectories = [t for g in groups for t in play_group(network, weights, g)]
    profile.disable()
    rollout_s = time.perf_counter() - t0
    decisions = sum(len(t.rewards) for t in trajectories)
    robot_steps = sum(t.robot_steps for t in trajectories)
    stats = pstats.Stats(profile)
    per = 1e3 / decisions
    print(f"{args.config} {' '.join(args.set)}: {len(trajectories)} episodes of iterations 1-{args.iterations}")
    print(f"{decisions} decisions, {robot_steps:,} robot-steps ({robot_steps / decisions:.0f} per decision), one core")
    print(
        f"rollout (under cProfile): {rollout_s * per:.1f} ms per decision, {robot_steps / rollout_s:,.0f} robot-steps/s"
    )
    loop = 0.0
    for label, suffix, name, in_loop in PARTS:
        seconds = cumulative(stats, suffix, name)
        loop += seconds if in_loop else 0.0
        print(f"  {label:64s} {seconds * per:6.1f} ms  {100 * seconds / rollout_s:4.0f} %")
    rest = rollout_s - loop - cumulative(stats, "dahgnn.py", "act")
    print(
        f"  {'the rest (episode bookkeeping, storing observations)':64s} {rest * per:6.1f} ms  "
        f"{100 * rest / rollout_s:4.0f} %"
    )

    def adam() -> torch.optim.Adam:  # as the trainer makes it
        return torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5, foreach=True)

    runner = TimedRunner(make_runner("local", args.workers if config.ppo.shards > 1 else 0))
    gradient = ShardedGradient(runner) if config.ppo.shards > 1 else whole_minibatch
    try:
        ppo_update(model, adam(), trajectories[:1], config, 1, 0.0, gradient)  # warm-up (starts the workers)
        model.load_state_dict({k: torch.from_numpy(v) for k, v in weights.items()})
        runner.calls.clear()
        t0 = time.perf_counter()
        update = ppo_update(model, adam(), trajectories, config, 1, 0.0, gradient)
        update_s = time.perf_counter() - t0
    finally:
        runner.close()
    minibatches = update["losses/minibatches"]
    print(
        f"PPO update (ppo.shards = {config.ppo.shards}, ppo.threads = {config.ppo.threads}): "
        f"{update_s * per:.1f} ms per decision, {minibatches:.0f} minibatches of up to {config.ppo.minibatch_size} "
        f"({1e3 * update_s / minibatches:.0f} ms each)"
    )
    if runner.calls:  # sharded: what the update's time is made of
        calls = runner.calls
        n = len(calls)
        wall = sum(end - start for start, end, _ in calls) / n
        slowest = sum(max(own) for _, _, own in calls) / n
        mean = sum(sum(own) / len(own) for _, _, own in calls) / n
        between = sum(calls[i + 1][0] - calls[i][1] for i in range(n - 1)) / max(1, n - 1)
        before = calls[0][0] - t0
        print(
            f"  before the first minibatch (graphs built and shared, health): {1e3 * before:.0f} ms "
            f"({1e3 * before / decisions:.1f} ms per decision)\n"
            f"  a minibatch: its shards in the workers {1e3 * wall:.0f} ms (the slowest shard {1e3 * slowest:.0f} ms, "
            f"the shards' mean {1e3 * mean:.0f} ms), the learner between two minibatches {1e3 * between:.0f} ms"
        )
    from bench_train import env_rate  # a sibling script

    bare = env_rate("robotathome_sarmis", 4, 20000)
    loop_ms = loop * per
    bound = (robot_steps / decisions) / (loop_ms / 1e3) / bare
    print(f"ParallelEnv (4 robots, random actions, robotathome_sarmis, one core): {bare:,.0f} robot-steps/s")
    print(
        f"goal loop without network and update: {loop_ms:.1f} ms per decision -> ratio at most {bound:.3f} "
        "(network and update free)"
    )


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
