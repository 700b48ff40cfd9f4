"""How much of an update's preparation the training loop hides behind the rollouts.

Before its first minibatch an update needs each decision's graph and the network's health numbers
(:class:`areasearch.training.ppo.UpdateInputs`). The training loop makes them in the learner as each
lockstep group of episodes comes back (:meth:`areasearch.runners.Runner.as_completed`), while the
other groups still play; what it makes after the last group came back is still on the iteration's
serial path. This script trains ``--iterations`` iterations of a config (``--workers`` processes, a
temporary folder), times each piece of that work and prints, per iteration after the first, the
iteration's wall time, the tail (from the first group back to the last), the preparation's time
and the part of it made after the last group came back; then the totals: the preparation's share
of the iterations' time (what the learner did before its first minibatch, serially, when it made
them after the rollouts) and the share it took off the serial path.

    python benchmarks/bench_update_inputs.py [--config configs/paper-budget/dahgnn-300k.toml]
        [--iterations 8] [--workers 2] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from areasearch.training import train as training
from areasearch.training.config import load_config
from areasearch.training.ppo import UpdateInputs


class Timeline:
    """Wraps the training loop's pieces (in this process) to time them: each group's arrival, each
    :meth:`UpdateInputs.add`, each update."""

    def __init__(self) -> None:
        self.iterations: list[dict[str, Any]] = []

    def install(self) -> None:
        add, play_groups, ppo_update = UpdateInputs.add, training.play_groups, training.ppo_update
        timeline = self

        def timed_add(inputs: UpdateInputs, index: int, trajectory: Any) -> None:
            t0 = time.perf_counter()
            add(inputs, index, trajectory)
            timeline.iterations[-1]["adds"].append((t0, time.perf_counter()))

        def timed_groups(*args: Any, **kwargs: Any) -> Iterator[Any]:
            timeline.iterations.append({"start": time.perf_counter(), "groups": [], "adds": []})
            for group in play_groups(*args, **kwargs):
                timeline.iterations[-1]["groups"].append(time.perf_counter())
                yield group

        def timed_update(*args: Any, **kwargs: Any) -> Any:
            out = ppo_update(*args, **kwargs)
            timeline.iterations[-1]["end"] = time.perf_counter()
            return out

        UpdateInputs.add = timed_add  # type: ignore[method-assign]
        training.play_groups = timed_groups  # type: ignore[assignment]
        training.ppo_update = timed_update  # type: ignore[assignment]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/paper-budget/dahgnn-300k.toml")
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = load_config(
        args.config, {key: json.loads(value) for key, _, value in (item.partition("=") for item in args.set)}
    )
    timeline = Timeline()
    timeline.install()
    with tempfile.TemporaryDirectory() as tmp:
        training.train(
            config, Path(tmp) / "run", workers=args.workers, log=None, progress=None, iterations=args.iterations
        )
    print(f"{args.config}: {args.workers} workers, iterations 2-{args.iterations} (the first warms up)")
    total = work = after = 0.0
    for it in timeline.iterations[1:]:  # validations play through play_episodes: not in the timeline
        last = it["groups"][-1]
        made = sum(b - a for a, b in it["adds"])
        late = sum(max(0.0, b - max(a, last)) for a, b in it["adds"])
        wall = it["end"] - it["start"]
        total, work, after = total + wall, work + made, after + late
        tail = last - it["groups"][0]
        line = f"  wall {wall:6.2f} s  tail {tail:5.2f} s  preparation {made * 1e3:5.0f} ms"
        print(f"{line}, after the last group {late * 1e3:5.0f} ms")
    print(f"preparation: {100 * work / total:.1f} % of the iterations' time; made while groups still played: "
          f"{100 * (work - after) / total:.1f} % (taken off the serial path)")  # fmt: skip


if __name__ == "__main__":
    main()
