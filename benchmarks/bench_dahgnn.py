"""Speed of the DA-HGNN planner network and its parameter count.

* one decision, one CPU thread: graph construction from the observation + forward of the actor + the
  evaluation assignment (:func:`areasearch.models.dahgnn.decide`), for 5 robots and 200 candidates
  (target <= 10 ms), and for 3 robots and 64 candidates (the environment's typical size). The FMM
  distances are part of the observation; what the environment spends on candidates and their FMM
  distances is reported apart (a real map, 5 robots).
* a PPO minibatch of 256 decisions, two CPU threads: forward + backward of a PPO-style loss
  (log-probabilities, entropy, value, auxiliary head) (target <= 250 ms), on decisions drawn from
  training rollouts (the episodes of the first training iterations of the default training config,
  played by the benchmark's network: mixed team sizes and candidate counts, padded into one batch
  as PPO sees them), and on synthetic decisions of fixed team size: 3 robots x 32-64 candidates and
  5 robots x 100-200; collation of the 256 observations into one graph batch is reported apart.

Synthetic observations are shaped like :class:`areasearch.envs.goal.AreaSearchEnv`'s (128 x 128
map, 8 history decisions, real-valued distances, a few masked actions).

    python benchmarks/bench_dahgnn.py [--repeat 30] [--config default|ncm] [--rounds N] [--norm pre-ln|none]
                                      [--skip-env] [--skip-rollouts] [--profile]

``--profile`` adds, for each minibatch, its time by part of the network (torch.profiler's self time
of each operation, as the calling thread sees it: dense layers, the attention kernels, the affinity
and Sinkhorn, the critic's CNN, the rest).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from collections.abc import Callable

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import torch

from areasearch.models.dahgnn import decide, evaluate_actions
from areasearch.models.graph import build_graph
from areasearch.models.network import DAHGNN
from areasearch.models.network_config import NetworkConfig


def synthetic_observation(rng: np.random.Generator, robots: int, candidates: int, history: int = 8) -> dict:
    """An observation shaped like the goal environment's, with ``candidates`` real candidates."""
    s, scale = 128, 4.0
    grid = np.zeros((7, s, s), dtype=np.float32)
    grid[5, 16:112, 16:112] = rng.random((96, 96)) > 0.2  # explored
    grid[4] = (rng.random((s, s)) > 0.9) * grid[5]  # obstacles
    cells = rng.integers(64, 448, size=(candidates + robots, 2)).astype(np.float32)
    grid[2, (cells[:candidates, 0] // scale).astype(int), (cells[:candidates, 1] // scale).astype(int)] = 1.0
    cand = np.zeros((candidates, 5), dtype=np.float32)
    cand[:, :2] = cells[:candidates]
    cand[:, 2] = rng.random(candidates) < 0.3
    cand[:, 3] = np.where(cand[:, 2] == 1, 1, rng.integers(3, 100, candidates))
    cand[:, 4] = np.where(cand[:, 2] == 1, 0, rng.integers(0, 8000, candidates))
    dist = (rng.random((robots, candidates)) * 20.0).astype(np.float32)
    dist[rng.random((robots, candidates)) < 0.05] = np.inf
    hist = rng.integers(64, 448, size=(history, robots, 2)).astype(np.float32)
    return {
        "map": grid,
        "map_scale": np.array([scale], dtype=np.float32),
        "robots": np.concatenate([cells[candidates:], rng.uniform(-3, 3, (robots, 1))], axis=1).astype(np.float32),
        "candidates": cand,
        "candidate_mask": np.ones(candidates, dtype=np.int8),
        "distances": dist,
        "action_mask": np.isfinite(dist).astype(np.int8),
        "history_robots": hist,
        "history_goals": hist[:, ::-1].copy(),
        "history_mask": np.ones(history, dtype=np.int8),
        "progress": np.array([0.3], dtype=np.float32),
    }


def median_ms(fn: Callable[[], object], repeat: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def one_decision(model: DAHGNN, robots: int, candidates: int, repeat: int) -> dict[str, float]:
    torch.set_num_threads(1)
    obs = synthetic_observation(np.random.default_rng(0), robots=robots, candidates=candidates)
    graph_ms = median_ms(lambda: build_graph([obs], model.config.graph, critic=False), repeat)  # as decide builds it
    return {"graph_ms": graph_ms, "decision_ms": median_ms(lambda: decide(model, [obs]), repeat)}


def rollout_observations(model: DAHGNN, count: int = 512) -> list[dict]:
    """At least ``count`` decisions of training rollouts: the episodes of the default training config's
    first iterations (its maps and team sizes), played by ``model`` as a rollout worker plays them."""
    from areasearch.models.network_config import config_to_dict
    from areasearch.training.train import TrainConfig, expand_maps, iteration_episodes, play

    config = TrainConfig().validate()
    maps = expand_maps(config.rollout.maps)
    weights = {k: v.detach().numpy() for k, v in model.state_dict().items()}
    observations: list[dict] = []
    for iteration in range(1, 1000):
        for spec in iteration_episodes(config, maps, iteration):
            observations += play(config_to_dict(model.config), weights, spec).observations
        if len(observations) >= count:
            return observations
    return observations


_PARTS = {
    "dense layers": ("aten::mm", "aten::addmm", "aten::bmm"),
    "MLP-attention cross-graph kernels": ("_CrossAttention", "_CrossAttentionBackward"),
    "sparse self-graph attention kernels": ("_SparseAttention", "_SparseAttentionBackward"),
    "affinity MLP + Sinkhorn kernels": ("_PairMLP", "_PairMLPBackward", "_Sinkhorn", "_SinkhornBackward"),
    "critic CNN": ("aten::mkldnn_convolution", "aten::convolution_backward"),
}


def profile_parts(step: Callable[[], object]) -> dict[str, float]:
    """Self time (ms, under the profiler, as the calling thread sees it) of one call of ``step``, by part
    of the network."""
    from torch.profiler import profile

    with profile() as prof:
        step()
    parts = dict.fromkeys([*_PARTS, "other operations"], 0.0)
    for event in prof.key_averages():
        name = next((part for part, ops in _PARTS.items() if event.key in ops), "other operations")
        parts[name] += event.self_cpu_time_total / 1000
    return parts


def ppo_minibatch(model: DAHGNN, obs: list[dict], repeat: int, profile: bool = False) -> dict[str, float]:
    torch.set_num_threads(2)
    collate_ms = median_ms(lambda: build_graph(obs, model.config.graph), max(3, repeat // 5), warmup=1)
    batch = build_graph(obs, model.config.graph)
    r = batch.robot_mask.shape[1]
    actions = torch.from_numpy(
        np.stack([np.pad(np.argmax(o["action_mask"], axis=1), (0, r - len(o["robots"]))) for o in obs])
    )
    model.train()

    def step() -> None:
        model.zero_grad(set_to_none=True)
        res = evaluate_actions(model, batch, actions)
        loss = -res.log_prob.mean() - 1e-4 * res.entropy.mean() + res.value.pow(2).mean() + res.explored_ratio.mean()
        loss.backward()

    fwd_bwd_ms = median_ms(step, max(3, repeat // 5), warmup=1)
    parts = profile_parts(step) if profile else {}
    model.eval()
    return {"collate_ms": collate_ms, "fwd_bwd_ms": fwd_bwd_ms, **parts}


def synthetic_minibatch(robots: int, candidates: int) -> list[dict]:
    """256 synthetic decisions of ``robots`` robots and candidates // 2 to candidates candidates."""
    rng = np.random.default_rng(1)
    return [synthetic_observation(rng, robots, int(rng.integers(candidates // 2, candidates + 1))) for _ in range(256)]


def env_candidates_ms(repeat: int) -> float:
    """Candidates with their FMM distances, as the environment computes them every decision."""
    from areasearch.envs.goal import AreaSearchEnv

    torch.set_num_threads(1)
    env = AreaSearchEnv(map="bormann_lab_ipa", num_robots=5, seed=0)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(np.argmax(obs["action_mask"], axis=1))
    return median_ms(env._refresh_candidates, repeat)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--config", choices=("default", "ncm"), default="default")
    parser.add_argument("--rounds", type=int, default=None, help="override the number of rounds")
    parser.add_argument("--norm", choices=("pre-ln", "none"), default=None, help="override network.norm")
    parser.add_argument("--skip-env", action="store_true", help="do not time the environment's FMM distances")
    parser.add_argument("--skip-rollouts", action="store_true", help="no minibatch of training-rollout decisions")
    parser.add_argument("--profile", action="store_true", help="where a minibatch's time goes, by part of the network")
    args = parser.parse_args()
    torch.manual_seed(0)
    config = NetworkConfig() if args.config == "default" else NetworkConfig.ncm()
    if args.rounds is not None:
        config = dataclasses.replace(config, rounds=args.rounds)
    if args.norm is not None:
        config = dataclasses.replace(config, norm=args.norm)
    model = DAHGNN(config).eval()
    params = sum(p.numel() for p in model.parameters())
    actor = params - sum(p.numel() for p in model.critic.parameters())
    print(f"config {args.config}: {params:,} parameters ({actor:,} actor, {params - actor:,} critic + auxiliary head)")
    for robots, candidates in ((5, 200), (3, 64)):
        single = one_decision(model, robots, candidates, args.repeat)
        print(
            f"one decision, {robots} robots x {candidates} candidates, 1 thread: {single['decision_ms']:.1f} ms "
            f"(graph construction {single['graph_ms']:.1f} ms of it; target <= 10 ms at 5 x 200)"
        )
    minibatches = []
    if not args.skip_rollouts:
        played = rollout_observations(model)
        pick = np.random.default_rng(0).choice(len(played), 256, replace=False)
        obs = [played[i] for i in pick]
        cands = np.array([int(o["candidate_mask"].sum()) for o in obs])
        teams = np.array([len(o["robots"]) for o in obs])
        what = (
            f"from training rollouts ({len(played)} decisions played, 256 drawn: {teams.min()}-{teams.max()} robots, "
            f"mean {teams.mean():.1f}; {cands.min()}-{cands.max()} candidates, mean {cands.mean():.0f})"
        )
        minibatches.append((what, obs))
    for robots, candidates in ((3, 64), (5, 200)):
        minibatches.append(
            (f"{robots} robots x {candidates // 2}-{candidates} candidates", synthetic_minibatch(robots, candidates))
        )
    for what, obs in minibatches:
        ppo = ppo_minibatch(model, obs, args.repeat, args.profile)
        print(
            f"PPO minibatch 256 decisions {what}, 2 threads: forward+backward {ppo['fwd_bwd_ms']:.0f} ms "
            f"(target <= 250 ms), collation {ppo['collate_ms']:.0f} ms"
        )
        if args.profile:
            parts = {k: v for k, v in ppo.items() if not k.endswith("_ms")}
            total = sum(parts.values())
            print(f"  profiled (time in each operation itself, under the profiler: {total:.0f} ms in all):")
            for part, ms in parts.items():
                print(f"    {part:38s} {ms:6.0f} ms  {100 * ms / total:4.1f} %")
    if not args.skip_env:
        print(f"environment: candidates + FMM distances, 5 robots, bormann_lab_ipa: {env_candidates_ms(10):.1f} ms")


if __name__ == "__main__":
    main()
