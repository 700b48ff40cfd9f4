"""Time of the PPO update alone, by thread and shard setting: the question behind ``ppo.threads`` and
``ppo.shards``.

Plays a few episodes of a training config with its untrained network once (one process, one thread),
then times :func:`areasearch.training.ppo.ppo_update` over their decisions in fresh processes, one per setting,
alternating the settings for ``--rounds`` rounds (each process: one warm-up update, then
``--repeat`` timed ones; the median is printed):

* ``threads=1``: the update on one PyTorch thread (the shipped configs);
* ``threads=2``: on two;
* ``threads=2 passive``: on two, with ``OMP_WAIT_POLICY=PASSIVE`` (idle OpenMP threads sleep instead
  of spinning: the suspect when two threads stall on a machine where another process runs);
* ``shards=2``: each minibatch cut into two shards whose gradients two worker processes compute
  (``ppo.shards = 2``, :func:`areasearch.training.ppo_shards.shard_gradient`; one thread each), as in training with
  2 workers.

    python benchmarks/bench_update.py [--config configs/dahgnn.toml] [--episodes 2] [--rounds 3]

Run it once on a quiet machine and once with something else busy (e.g. a training run): the
ratios of the settings are the result, not the seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from areasearch.training.config import load_config

SETTINGS = {
    "threads=1": (1, 1, {}),
    "threads=2": (2, 1, {}),
    "threads=2 passive": (2, 1, {"OMP_WAIT_POLICY": "PASSIVE"}),
    "shards=2": (1, 2, {}),
}
"""name -> (ppo.threads, ppo.shards, environment variables)"""


def play(config_path: str, episodes: int, folder: Path) -> None:
    """Play the episodes and store them as NumPy files (no pickle) for the timing processes."""
    import numpy as np
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.training.config import load_config
    from areasearch.training.rollout import expand_maps, iteration_episodes, play_group

    config = load_config(config_path, {"rollout.episodes": episodes})
    torch.manual_seed(config.seed)
    model = DAHGNN(config.network)
    weights = {k: v.detach().numpy().copy() for k, v in model.state_dict().items()}
    specs = iteration_episodes(config, expand_maps(config.rollout.maps), 1)
    trajectories = play_group(dataclasses.asdict(config.network), weights, specs)
    for i, t in enumerate(trajectories):
        arrays = {f"obs{j}_{k}": v for j, o in enumerate(t.observations) for k, v in o.items()}
        arrays |= {f"action{j}": a for j, a in enumerate(t.actions)}
        arrays |= {"log_probs": t.log_probs, "values": t.values, "rewards": t.rewards, "explored": t.explored}
        np.savez(folder / f"episode{i}.npz", **arrays)
        (folder / f"episode{i}.json").write_text(json.dumps({"decisions": len(t.rewards), "robots": t.spec.robots}))
    np.savez(folder / "weights.npz", **weights)


def time_updates(config_path: str, folder: Path, threads: int, shards: int, repeat: int) -> list[float]:
    """Seconds per minibatch of ``repeat`` updates (after one of warm-up): ``target_kl`` may stop
    updates of different settings after different numbers of minibatches (their sums differ in
    the last bits), so the time of a whole update would compare different work."""
    import numpy as np
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.runners import make_runner
    from areasearch.training.config import load_config
    from areasearch.training.ppo import ppo_update, whole_minibatch
    from areasearch.training.ppo_shards import ShardedGradient
    from areasearch.training.trajectory import EpisodeSpec, Trajectory

    config = load_config(config_path, {"ppo.threads": threads, "ppo.shards": shards})
    trajectories = []
    for meta_path in sorted(folder.glob("episode*.json")):
        meta = json.loads(meta_path.read_text())
        data = np.load(meta_path.with_suffix(".npz"))
        n = meta["decisions"]
        keys = {k.split("_", 1)[1] for k in data.files if k.startswith("obs0_")}
        observations = [{k: data[f"obs{j}_{k}"] for k in keys} for j in range(n)]
        actions = [data[f"action{j}"] for j in range(n)]
        spec = EpisodeSpec("bench", meta["robots"], 0, config.rollout.max_steps)
        arrays = (data["log_probs"], data["values"], data["rewards"], data["explored"])
        trajectories.append(Trajectory(spec, observations, actions, *arrays, True, 0.0, {"steps": 0}, [], [], 0.0))
    weights = np.load(folder / "weights.npz")
    times = []
    runner = make_runner("local", shards)  # the shards in as many worker processes
    gradient = ShardedGradient(runner) if shards > 1 else whole_minibatch
    try:
        for i in range(repeat + 1):
            model = DAHGNN(config.network)
            model.load_state_dict({k: torch.from_numpy(weights[k]) for k in weights.files})
            optimizer = torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5)
            t0 = time.perf_counter()
            stats = ppo_update(model, optimizer, trajectories, config, 1, 0.0, gradient)
            if i:  # the first is the warm-up (and starts the workers)
                times.append((time.perf_counter() - t0) / stats["losses/minibatches"])
    finally:
        runner.close()
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(Path(__file__).resolve().parent.parent / "configs" / "dahgnn.toml"))
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--only", nargs="+", choices=list(SETTINGS), help="time only these settings")
    parser.add_argument("--time", nargs=3, metavar=("FOLDER", "THREADS", "SHARDS"), help=argparse.SUPPRESS)
    parser.add_argument("--play", metavar="FOLDER", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.play:
        play(args.config, args.episodes, Path(args.play))
        return 0
    if args.time:
        times = time_updates(args.config, Path(args.time[0]), int(args.time[1]), int(args.time[2]), args.repeat)
        print(json.dumps(times))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        command = [sys.executable, __file__, "--config", args.config, "--episodes", str(args.episodes)]
        subprocess.run([*command, "--play", tmp], check=True, env=env)
        decisions = sum(json.loads(p.read_text())["decisions"] for p in folder.glob("episode*.json"))
        minibatch = min(decisions, load_config(args.config).ppo.minibatch_size)
        print(f"{args.config}: {args.episodes} episodes, {decisions} decisions, minibatches of {minibatch}")
        print(f"medians of {args.repeat} updates: seconds per minibatch (its forward, backward and step)")
        settings = {name: SETTINGS[name] for name in args.only or SETTINGS}
        results: dict[str, list[float]] = {name: [] for name in settings}
        for r in range(args.rounds):
            for name, (threads, shards, extra) in settings.items():
                command = [sys.executable, __file__, "--config", args.config, "--repeat", str(args.repeat)]
                done = subprocess.run(
                    [*command, "--time", str(folder), str(threads), str(shards)],
                    env={**os.environ, **extra}, capture_output=True, text=True, check=True,
                )  # fmt: skip
                times = json.loads(done.stdout.strip().splitlines()[-1])
                results[name].append(statistics.median(times))
                print(f"round {r + 1} {name:18s} {statistics.median(times):6.3f} s per minibatch", flush=True)
        base = statistics.median(next(iter(results.values())))
        for name, values in results.items():
            median = statistics.median(values)
            per = median / minibatch * 1e3
            print(f"{name:18s} median {median:6.3f} s per minibatch   {per:6.2f} ms/decision   x{median / base:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
