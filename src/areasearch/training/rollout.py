"""Training rollouts: the episodes of an iteration, played with the current weights.

An episode is chosen from (run seed, iteration, slot) only (:func:`iteration_episodes`): a map drawn
from ``rollout.maps`` (bundled training maps, procedural layouts of each size class, see
:func:`expand_maps`), a team size from ``rollout.robots``, an episode seed; :func:`play` samples the
policy's goals with a generator seeded from the episode seed, on one thread. So an episode's
:class:`Trajectory` depends on its :class:`EpisodeSpec` and the weights alone: not on the number of
workers, the backend, or on a run having been killed and resumed. The validation episodes
(:func:`validation_episodes`) are seeded as the evaluation harness seeds its episodes and take
deterministic goals.

A :class:`Backend` plays the episodes in worker processes (``--workers K``), as Ray tasks
(``--backend ray``), or in this process (``--workers 0``). Nothing is pickled to disk: the workers
receive weights and return trajectories through multiprocessing pipes (or Ray's object store).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..errors import ConfigError, MapError
from ..workers import worker_pool
from .config import TrainConfig


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: everything its outcome depends on besides the weights."""

    map: str
    robots: int
    seed: int
    max_steps: int
    env: tuple[tuple[str, Any], ...] = ()
    deterministic: bool = False
    """Evaluation-time goals (assignment on S) instead of sampling."""


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


def iteration_episodes(config: TrainConfig, maps: Sequence[str], iteration: int) -> list[EpisodeSpec]:
    """The training episodes of ``iteration``: from (run seed, iteration, slot) only."""
    rng = np.random.default_rng([config.seed, iteration, 0])
    env = tuple(sorted(config.rollout.env.items()))
    specs = []
    for _ in range(config.rollout.episodes):
        map_spec = maps[int(rng.integers(len(maps)))]
        robots = config.rollout.robots[int(rng.integers(len(config.rollout.robots)))]
        specs.append(EpisodeSpec(map_spec, robots, int(rng.integers(2**62)), config.rollout.max_steps, env))
    return specs


def validation_episodes(
    config: TrainConfig, maps: Sequence[str], first: int = 0, count: int | None = None
) -> list[EpisodeSpec]:
    """The validation episodes (the same at every validation), seeded as the harness seeds them:
    episodes ``first`` .. ``first + count - 1`` (default: the ``evaluation.episodes`` of a
    validation) of each map and team size; the final selection plays the ones after them."""
    from ..harness.evaluate import episode_seed

    e = config.evaluation
    count = e.episodes if count is None else count
    env = tuple(sorted(config.rollout.env.items()))  # the same world rules as the training episodes
    return [
        EpisodeSpec(m, n, episode_seed(config.seed, m, n, i), e.max_steps, env, deterministic=True)
        for m in maps
        for n in e.robots
        for i in range(first, first + count)
    ]


@dataclass
class Trajectory:
    """One played episode: per decision the observation (map as float16), the team's goals, each
    robot's log-probability of its goal (the sequential draw's conditionals, (T, R); 0 for a robot
    without a choice) and the value under the acting policy, the reward, the explored-ratio label."""

    spec: EpisodeSpec
    observations: list[dict[str, np.ndarray]]
    actions: list[np.ndarray]
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    explored: np.ndarray
    terminated: bool
    last_value: float
    """Value after the last decision: 0, the horizon is terminal (:func:`areasearch.training.ppo.episode_gae`);
    kept for code that builds trajectories by hand."""
    info: dict[str, Any]
    steps: list[int]
    covered_curve: list[float]
    wall_s: float

    @property
    def robot_steps(self) -> int:
        return int(self.info["steps"]) * self.spec.robots


_WORKER: dict[str, Any] = {}


def worker_model(network: dict[str, Any], weights: Mapping[str, np.ndarray]) -> Any:
    """This process's copy of the network with ``weights`` (rebuilt only when the config changes)."""
    import torch

    from ..models.dahgnn import DAHGNN
    from ..models.dahgnn import config_from_dict as network_from_dict

    key = json.dumps(network, sort_keys=True)
    if _WORKER.get("key") != key:
        _WORKER["model"] = DAHGNN(network_from_dict(network, "network")).eval()
        _WORKER["key"] = key
    model = _WORKER["model"]
    model.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in weights.items()})
    return model


def shared(handle: Any) -> Mapping[str, np.ndarray]:
    """The arrays behind a handle of :meth:`Backend.share` (in a worker: a folder of ``.npy`` files,
    mapped copy-on-write and kept for the next task with the same handle; from Ray or this process:
    the arrays themselves)."""
    if not isinstance(handle, str):
        return cast(Mapping[str, np.ndarray], handle)
    cached = _WORKER.get("shared")
    if cached is None or cached[0] != handle:
        arrays = {p.stem: np.load(p, mmap_mode="c", allow_pickle=False) for p in sorted(Path(handle).glob("*.npy"))}
        cached = _WORKER["shared"] = (handle, arrays)
    return cast(Mapping[str, np.ndarray], cached[1])


def _shared_memory_dir(nbytes: int) -> str | None:
    """Where :meth:`Backend.share` writes ``nbytes``: the RAM-backed ``/dev/shm`` where there is one
    with room to spare (a container's is often 64 MB), else the temporary folder (its pages stay in
    the page cache all the same)."""
    shm = Path("/dev/shm")
    try:
        room = shm.is_dir() and os.access(shm, os.W_OK) and shutil.disk_usage(shm).free > 2 * nbytes + (64 << 20)
    except OSError:
        room = False
    return str(shm) if room else None


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
            map=spec.map, num_robots=spec.robots, seed=spec.seed, max_steps=spec.max_steps, **dict(spec.env)
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


class Backend:
    """Plays episodes: in this process (``workers=0``), in worker processes, or as Ray tasks."""

    def __init__(self, kind: str, workers: int, address: str | None = None) -> None:
        self.kind, self.workers = kind, workers
        self._pool: ProcessPoolExecutor | None = None
        self._ray: Any = None
        self._remote: dict[Callable[..., Any], Any] = {}
        if kind == "ray":
            try:
                import ray
            except ImportError:
                raise ConfigError("--backend ray needs Ray: pip install 'areasearch[ray]'") from None
            if not ray.is_initialized():
                if address:
                    ray.init(address=address, log_to_driver=False)
                else:
                    ray.init(num_cpus=max(1, workers), log_to_driver=False, include_dashboard=False)
            self._ray = ray
            self._play = ray.remote(num_cpus=1)(play_group)
        elif kind == "local":
            if workers > 0:
                self._pool = worker_pool(workers)
        else:
            raise ConfigError(f"backend must be 'local' or 'ray', got {kind!r}")

    def map(
        self,
        network: dict[str, Any],
        weights: dict[str, np.ndarray],
        specs: Sequence[EpisodeSpec],
        lockstep: int = 1,
    ) -> Iterator[Trajectory]:
        """Trajectories of ``specs``, in order (each as soon as it and those before it are done),
        played in lockstep groups of ``lockstep`` episodes (:func:`lockstep_groups`), a task each."""
        groups = lockstep_groups(specs, lockstep)
        if self._ray is not None:
            ref = self._ray.put(weights)
            futures = [self._play.remote(network, ref, g) for g in groups]
            for f in futures:
                yield from self._ray.get(f)
        elif self._pool is not None:
            jobs = [self._pool.submit(play_group, network, weights, g) for g in groups]
            for job in jobs:
                yield from job.result()
        else:
            for g in groups:
                yield from play_group(network, weights, g)

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        """``fn(*args)`` for each of ``tasks``, in the worker processes, as Ray tasks or here; the results
        in order (the sharded PPO update's :class:`areasearch.training.ppo_shards.Runner`)."""
        if self._ray is not None:
            remote = self._remote.get(fn)
            if remote is None:
                remote = self._remote[fn] = self._ray.remote(num_cpus=1)(fn)
            return list(self._ray.get([remote.remote(*args) for args in tasks]))
        if self._pool is not None:
            jobs = [self._pool.submit(fn, *args) for args in tasks]
            return [job.result() for job in jobs]
        return [fn(*args) for args in tasks]

    @contextlib.contextmanager
    def share(self, arrays: dict[str, np.ndarray]) -> Iterator[Any]:
        """A handle to ``arrays`` for tasks of :meth:`call` (resolved there by :func:`shared`), valid in
        the ``with`` block: the arrays themselves here, an object in Ray's store, or for worker
        processes ``.npy`` files in a temporary folder (in ``/dev/shm`` where it has room) that
        each worker maps once, removed at the end of the block. (Pipes would carry the same
        megabytes once per task and cost more than the shards' arithmetic saves.)"""
        if self._ray is not None:
            yield self._ray.put(arrays)
        elif self._pool is None:
            yield arrays
        else:
            nbytes = sum(a.nbytes for a in arrays.values())
            folder = Path(tempfile.mkdtemp(prefix="areasearch-update-", dir=_shared_memory_dir(nbytes)))
            try:
                for name, array in arrays.items():
                    np.save(folder / f"{name}.npy", array, allow_pickle=False)
                yield str(folder)
            finally:
                shutil.rmtree(folder, ignore_errors=True)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
        if self._ray is not None and self._ray.is_initialized():
            self._ray.shutdown()
