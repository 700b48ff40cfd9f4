"""Size and write time of an episode recorded as MCAP (:mod:`areasearch.harness.mcap`), per 1,000 steps.

One greedy episode per map (3 robots, seed 0, the paper's 3600-step horizon unless ``--steps``), a map
frame every decision (40 steps, the default of ``areasearch eval --record-mcap``), played twice in one
process: unrecorded, then recorded (the same episode). Prints, per map, the file's size and the time spent
recording (:attr:`Recorder.seconds <areasearch.harness.mcap.Recorder.seconds>`: building and writing the
messages, closing the file), both per 1,000 steps played, beside the unrecorded episode's time; and each
topic's share of the uncompressed message bytes (the file is zstd-compressed in chunks).

    python benchmarks/bench_mcap.py                      # a small, a medium and a large bundled map
    python benchmarks/bench_mcap.py --realism medium     # an imperfect world: the truth and the belief
    python benchmarks/bench_mcap.py --maps robotathome_sarmis --steps 1000
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from mcap.reader import make_reader

from areasearch.config import realism_settings, search_config
from areasearch.harness.episodes import make_env, play_episode
from areasearch.harness.mcap import recording
from areasearch.planners import make_planner
from areasearch.sim.scene import load_scene

MAPS = ["bormann_lab_c_rooms1", "bormann_lab_c_rooms3", "bormann_lab_ipa"]
"""A small, a medium and a large bundled map (113 x 116, 190 x 211 and 492 x 489 cells of 0.05 m)."""
ROBOTS, SEED, METHOD = 3, 0, "greedy"


def play(map_id: str, steps: int, realism: str, out: Path | None) -> tuple[int, float, float]:
    """(steps played, seconds playing, seconds recording) of one episode, recorded to ``out`` unless None."""
    settings = realism_settings(realism, {})
    env = make_env(map_id, ROBOTS, SEED, steps, search_config(settings) if settings else None)
    planner = make_planner(METHOD)
    if out is None:
        t0 = time.perf_counter()
        trace = play_episode(env, planner, SEED)
        return int(trace.info["steps"]), time.perf_counter() - t0, 0.0
    t0 = time.perf_counter()
    with recording(env, out) as recorder:
        trace = play_episode(env, planner, SEED)
        t1 = time.perf_counter()
    closing = time.perf_counter() - t1  # the last frame and the file's end
    spent = time.perf_counter() - t0
    return int(trace.info["steps"]), spent - recorder.seconds - closing, recorder.seconds + closing


def topic_bytes(path: Path) -> dict[str, int]:
    """Uncompressed message bytes per topic."""
    sizes: dict[str, int] = defaultdict(int)
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            sizes[channel.topic] += len(message.data)
    return dict(sizes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", nargs="+", default=MAPS, help="bundled map ids (default: small, medium, large)")
    parser.add_argument("--steps", type=int, default=3600, help="horizon, primitive steps (default 3600)")
    parser.add_argument("--realism", default="none", help="realism preset of the world (default none)")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench_mcap_"))
    play(args.maps[0], 80, args.realism, None)  # compile / warm up
    print(f"{METHOD}, {ROBOTS} robots, seed {SEED}, horizon {args.steps}, realism {args.realism}, a map frame every 40")
    print()
    print("| map | size | cells | steps | file (MB) | KB / 1,000 steps | recording s / 1,000 steps "
          "| playing s / 1,000 steps (unrecorded) | compressed / raw |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    shares: dict[str, dict[str, int]] = {}
    for map_id in args.maps:
        scene = load_scene(map_id)
        out = folder / f"{map_id}.mcap"
        steps, plain_s, _ = play(map_id, args.steps, args.realism, None)
        recorded_steps, _, record_s = play(map_id, args.steps, args.realism, out)
        assert recorded_steps == steps, (recorded_steps, steps)
        size = out.stat().st_size
        raw = topic_bytes(out)
        shares[map_id] = raw
        per = 1000 / steps
        print(
            f"| {map_id} | {scene.size_class} | {scene.shape[0]} x {scene.shape[1]} | {steps} | {size / 1e6:.2f} "
            f"| {size / 1e3 * per:.0f} | {record_s * per:.3f} | {plain_s * per:.3f} | {size / sum(raw.values()):.3f} |"
        )
    print()
    topics = sorted({t for raw in shares.values() for t in raw})
    print("| map | " + " | ".join(topics) + " |")
    print("|---|" + "---:|" * len(topics))
    for map_id, raw in shares.items():
        total = sum(raw.values())
        print(f"| {map_id} | " + " | ".join(f"{100 * raw.get(t, 0) / total:.1f} %" for t in topics) + " |")
    print(f"\nshare of the uncompressed message bytes per topic; files in {folder}")


if __name__ == "__main__":
    main()
