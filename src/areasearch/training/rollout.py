"""Training rollouts: the episodes of an iteration, played with the current weights.

An episode is chosen from (run seed, iteration, slot) only (:func:`iteration_episodes`): a map drawn
from ``rollout.maps`` (bundled training maps, procedural layouts of each size class, see
:func:`expand_maps`), a team size from ``rollout.robots``, an episode seed; :func:`play` samples the
policy's goals with a generator seeded from the episode seed, on one thread. So an episode's
:class:`~areasearch.training.trajectory.Trajectory` depends on its
:class:`~areasearch.training.trajectory.EpisodeSpec` and the weights alone: not on the number of
workers, the runner, or on a run having been killed and resumed. The validation episodes
(:func:`validation_episodes`) are seeded as the evaluation harness seeds its episodes and take
deterministic goals.

:func:`play_episodes` hands the episodes, in lockstep groups, to a :class:`~areasearch.runners.Runner`
(worker processes, Ray tasks or this process, chosen once by the caller). Nothing is pickled to disk:
the workers receive weights and return trajectories through multiprocessing pipes (or Ray's object
store).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import SearchConfig, realism_config
from ..errors import MapError
from ..runners import Runner
from .config import TrainConfig, training_realism
from .trajectory import EpisodeSpec, Trajectory


def episode_env(config: TrainConfig) -> SearchConfig:
    """The environment's config of a run's training and validation episodes: ``rollout.env`` applied
    to the defaults, its ``realism`` preset under its other settings (:func:`areasearch.config.realism_config`),
    the preset's communication left full (:func:`~areasearch.training.config.training_realism`)."""
    return realism_config(*training_realism(config.rollout.env))


def expand_maps(specs: Sequence[str]) -> list[str]:
    """``bundled:<split>`` -> its map ids; other specs (ids, files, procedural classes) as they are.
    Each single map is checked to load."""
    from ..sim.scene import scene_source
    from ..sim.splits import split_maps

    out: list[str] = []
    for spec in specs:
        if spec.startswith("bundled:"):
            out += split_maps(spec.split(":", 1)[1])
        elif spec == "bundled":
            raise MapError("bundled: name a split (bundled:train) so that no test map is trained on")
        else:
            scene_source(spec)  # validates
            out.append(spec)
    return out


def iteration_episodes(
    config: TrainConfig, maps: Sequence[str], iteration: int, env: SearchConfig | None = None
) -> list[EpisodeSpec]:
    """The training episodes of ``iteration``: from (run seed, iteration, slot) only; ``env`` is
    :func:`episode_env` of ``config`` (made here when not given)."""
    rng = np.random.default_rng([config.seed, iteration, 0])
    env = episode_env(config) if env is None else env
    specs = []
    for _ in range(config.rollout.episodes):
        map_spec = maps[int(rng.integers(len(maps)))]
        robots = config.rollout.robots[int(rng.integers(len(config.rollout.robots)))]
        specs.append(EpisodeSpec(map_spec, robots, int(rng.integers(2**62)), config.rollout.max_steps, env))
    return specs


def validation_episodes(
    config: TrainConfig,
    maps: Sequence[str],
    first: int = 0,
    count: int | None = None,
    env: SearchConfig | None = None,
) -> list[EpisodeSpec]:
    """The validation episodes (the same at every validation), seeded as the harness seeds them:
    episodes ``first`` .. ``first + count - 1`` (default: the ``evaluation.episodes`` of a
    validation) of each map and team size; the final selection plays the ones after them. The world
    rules are the training episodes' (``env``: :func:`episode_env` of ``config``, made here when not
    given)."""
    from ..harness.evaluate import episode_seed

    e = config.evaluation
    count = e.episodes if count is None else count
    env = episode_env(config) if env is None else env
    return [
        EpisodeSpec(m, n, episode_seed(config.seed, m, n, i), e.max_steps, env, deterministic=True)
        for m in maps
        for n in e.robots
        for i in range(first, first + count)
    ]


_WORKER: dict[str, Any] = {}


def worker_model(network: dict[str, Any], weights: Mapping[str, np.ndarray]) -> Any:
    """This process's copy of the network with ``weights`` (rebuilt only when the config changes)."""
    import torch

    from ..models.network import DAHGNN
    from ..models.network_config import config_from_dict as network_from_dict

    key = json.dumps(network, sort_keys=True)
    if _WORKER.get("key") != key:
        _WORKER["model"] = DAHGNN(network_from_dict(network, "network")).eval()
        _WORKER["key"] = key
    model = _WORKER["model"]
    model.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in weights.items()})
    return model


def play(network: dict[str, Any], weights: Mapping[str, np.ndarray], spec: EpisodeSpec) -> Trajectory:
    """Play one episode with the policy (in a worker process, a Ray task or here)."""
    return play_group(network, weights, [spec])[0]


def play_group(
    network: dict[str, Any], weights: Mapping[str, np.ndarray], specs: Sequence[EpisodeSpec]
) -> list[Trajectory]:
    """Play ``specs`` in lockstep with the policy (in a worker process, a Ray task or here): at each
    decision round one batched network forward for every episode still running, each episode's goals
    sampled with its own generator (seeded from its seed); returns the trajectories in order."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in a worker process: the same numbers with any number of workers
    try:
        return _play_group(network, weights, specs)
    finally:
        torch.set_num_threads(threads)


@dataclass
class _Episode:
    """An episode being played: its environment and what has been recorded of it so far."""

    spec: EpisodeSpec
    env: Any
    obs: dict[str, np.ndarray]
    info: dict[str, Any]
    generator: Any
    t0: float
    observations: list[dict[str, np.ndarray]] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    log_probs: list[np.ndarray] = field(default_factory=list)
    values: list[float] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    explored: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    covered: list[float] = field(default_factory=list)
    terminated: bool = False
    truncated: bool = False
    wall_s: float = 0.0


def _play_group(
    network: dict[str, Any], weights: Mapping[str, np.ndarray], specs: Sequence[EpisodeSpec]
) -> list[Trajectory]:
    import torch

    from ..envs.goal import AreaSearchEnv
    from ..models.dahgnn import act

    model = worker_model(network, weights)
    episodes = []
    for spec in specs:
        t0 = time.perf_counter()
        env = AreaSearchEnv(
            map=spec.map, num_robots=spec.robots, seed=spec.seed, config=spec.env, max_steps=spec.max_steps
        )
        obs, info = env.reset(seed=spec.seed)
        ep = _Episode(spec, env, obs, info, torch.Generator().manual_seed(spec.seed), t0)
        ep.steps.append(int(info["steps"]))
        ep.covered.append(float(info["covered_pct"]))
        ep.wall_s = time.perf_counter() - t0
        episodes.append(ep)
    running = list(episodes)
    # goals are deterministic for every episode of a group or for none (training or validation)
    deterministic = bool(specs) and specs[0].deterministic
    if any(s.deterministic != deterministic for s in specs):
        raise ValueError("a lockstep group mixes training and validation episodes")
    while running:
        t0 = time.perf_counter()
        result = act(
            model, [ep.obs for ep in running], deterministic=deterministic, generator=[ep.generator for ep in running]
        )
        share = (time.perf_counter() - t0) / len(running)
        for k, ep in enumerate(running):
            t1 = time.perf_counter()
            action = result.actions[k, : ep.spec.robots].cpu().numpy()
            stored = dict(ep.obs)
            stored["map"] = ep.obs["map"].astype(np.float16)
            ep.observations.append(stored)
            ep.actions.append(action.astype(np.int64))
            ep.log_probs.append(result.robot_log_prob[k, : ep.spec.robots].cpu().numpy().astype(np.float32))
            ep.values.append(float(result.value[k]))
            ep.explored.append(float(ep.info["explored_ratio"]))
            ep.obs, reward, terminated, truncated, ep.info = ep.env.step(action)
            ep.terminated, ep.truncated = bool(terminated), bool(truncated)
            ep.rewards.append(float(reward))
            ep.steps.append(int(ep.info["steps"]))
            ep.covered.append(float(ep.info["covered_pct"]))
            ep.wall_s += share + time.perf_counter() - t1
        running = [ep for ep in running if not (ep.terminated or ep.truncated)]
    return [
        Trajectory(
            ep.spec,
            ep.observations,
            ep.actions,
            np.array(ep.log_probs, dtype=np.float32).reshape(len(ep.actions), ep.spec.robots),
            np.array(ep.values, dtype=np.float32),
            np.array(ep.rewards, dtype=np.float32),
            np.array(ep.explored, dtype=np.float32),
            ep.terminated,
            0.0,
            dict(ep.info),
            ep.steps,
            ep.covered,
            ep.wall_s,
        )
        for ep in episodes
    ]


def lockstep_groups(specs: Sequence[EpisodeSpec], size: int) -> list[list[EpisodeSpec]]:
    """``specs`` cut, in order, into groups of ``size`` (the last may be smaller): the episodes each
    task plays in lockstep. Fixed by the config, not by the number of workers, so that the batched
    forwards (whose arithmetic depends on the batch) are the same whoever plays them."""
    return [list(specs[i : i + size]) for i in range(0, len(specs), size)]


def play_episodes(
    runner: Runner,
    network: dict[str, Any],
    weights: dict[str, np.ndarray],
    specs: Sequence[EpisodeSpec],
    lockstep: int = 1,
) -> Iterator[Trajectory]:
    """Trajectories of ``specs``, in order (each as soon as it and those before it are done), played
    by ``runner`` in lockstep groups of ``lockstep`` episodes (:func:`lockstep_groups`), a task each;
    the weights are sent once (:meth:`~areasearch.runners.Runner.put`)."""
    for trajectories in runner.imap(play_group, _group_tasks(runner, network, weights, specs, lockstep)):
        yield from trajectories


def play_groups(
    runner: Runner,
    network: dict[str, Any],
    weights: dict[str, np.ndarray],
    specs: Sequence[EpisodeSpec],
    lockstep: int = 1,
) -> Iterator[tuple[int, list[Trajectory]]]:
    """As :func:`play_episodes`, but each lockstep group's trajectories as soon as that group is done,
    whatever the order (:meth:`~areasearch.runners.Runner.as_completed`), with the index in ``specs`` of
    its first episode: the caller can work on a group while the others still play."""
    tasks = _group_tasks(runner, network, weights, specs, lockstep)
    for i, trajectories in runner.as_completed(play_group, tasks):
        yield i * lockstep, trajectories


def _group_tasks(
    runner: Runner, network: dict[str, Any], weights: dict[str, np.ndarray], specs: Sequence[EpisodeSpec], lockstep: int
) -> list[tuple[Any, ...]]:
    """One :func:`play_group` task per lockstep group of ``specs``, the weights sent once
    (:meth:`~areasearch.runners.Runner.put`)."""
    shared_weights = runner.put(weights)
    return [(network, shared_weights, group) for group in lockstep_groups(specs, lockstep)]
