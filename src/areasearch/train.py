"""Pipeline stage "planner" (training): PPO for the DA-HGNN topological planner.

Implements the "Policy Optimization" of the DA-HGNN paper (Zhu et al., "Dual-Attention Heterogeneous
Graph Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning"): a
centralised actor-critic trained with PPO, the actor the DA-HGNN planner (:mod:`areasearch.dahgnn`),
the critic the map CNN, on the team reward r_t = alpha1 * explored gain + alpha2 * newly covered
targets + alpha3 per step, summed over the 40 primitive steps of each decision
(:class:`areasearch.goal_env.AreaSearchEnv`). The loss is

    L = L_CLIP + c1 L_KL + c2 L_VF - c3 L_E + c4(t) L_Acc

with L_CLIP the clipped surrogate (clip 0.2) on the joint log-probability of the team's goals,
L_KL the k3 estimate ``(ratio - 1) - log ratio`` of KL(pi_old || pi) as a penalty, L_VF the value
error (unclipped by default; ``ppo.clip_vloss`` clips it the way PPO2 does), L_E the entropy bonus
(the paper's "+ c3 L_E" read as a bonus, hence the minus sign of a minimised loss) and L_Acc the mean
squared error of the auxiliary explored-ratio prediction, whose weight c4 decays linearly from
``ppo.aux_coef`` to 0 over the first ``ppo.aux_decay`` of training, as the paper says. Advantages by
GAE (gamma 0.99 per decision, lambda 0.95), normalised per minibatch; gradients clipped to norm
``ppo.max_grad_norm``, the actor's and the critic's apart (one shared norm would be set by the
value error and shrink the policy's steps below Adam's epsilon); Adam at 5e-4, annealed linearly
to 0. Logged per iteration: the losses,
``approx_kl``, ``clipfrac``, ``explained_variance``, the learning rate, c4, returns and the episodes'
Explo% / Cover%, decisions/s and robot-steps/s.

**Iterations.** Each iteration plays ``rollout.episodes`` whole episodes with the current policy
(sampling goals from its per-robot categoricals), then runs ``ppo.epochs`` epochs of minibatch
updates over their decisions. An episode is chosen from (run seed, iteration, slot) only: a map
drawn from ``rollout.maps`` (bundled training maps, procedural layouts of each size class), a team
size from ``rollout.robots``, an episode seed; the policy samples with a generator seeded from the
episode seed. Minibatch order comes from (run seed, iteration). So a run's numbers depend on its
config alone: not on the number of workers, the backend, or on having been killed and resumed.
Episodes are played by worker processes (``--workers K``, default: one per core), or as Ray tasks
(``--backend ray``); ``--workers 0`` plays them in this process.

**Files** in the run folder (``areasearch train --out runs/NAME``):

* ``config.json``: the resolved config (resuming with another config is refused).
* ``checkpoint.json`` + ``checkpoint-<iteration>.safetensors``: weights, Adam state and counters,
  written atomically after every ``checkpoint_every`` iterations (the JSON, replaced last, names the
  weights file; older files are removed after). ``--resume`` continues from it and loses at most the
  iterations since; without ``--resume`` an existing run is never overwritten.
* ``policy.safetensors`` + ``policy.json``: the best policy so far on the validation maps (by the
  mean area under the Cover% curve, see :func:`coverage_auc`), in the format of
  :func:`areasearch.dahgnn.save_policy`: ``LearnedPlanner(weights="runs/NAME/policy")``.
  ``final.*``: the policy after the last iteration.
* ``progress.csv`` (one row per iteration: ``charts/*``, ``losses/*`` and ``perf/*`` columns),
  ``eval.csv`` (one row per validation episode), ``tb/`` (TensorBoard scalars under the same names,
  ``tensorboard --logdir runs``), ``curve.png`` (training curve: return, Cover% and Explo% by
  decisions, validation Cover% AUC).

Nothing is pickled to disk; the workers receive weights and return trajectories through
multiprocessing pipes (or Ray's object store) within one run.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import sys
import time
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from .errors import AreaSearchError, ConfigError, MapError
from .runlog import Progress
from .workers import worker_pool

TRAIN_FORMAT = "areasearch-train/1"
CONFIG_FILE, CHECKPOINT_FILE = "config.json", "checkpoint.json"
PROGRESS_FILE, EVAL_FILE = "progress.csv", "eval.csv"


# ---------------------------------------------------------------------------------------------- config


@dataclass(frozen=True)
class PPOConfig:
    """PPO settings (paper values where it gives them: lr 5e-4, clip 0.2, gamma 0.99, GAE)."""

    learning_rate: float = 5e-4
    anneal_lr: bool = True
    """Learning rate decays linearly to 0 over the run."""
    gamma: float = 0.99
    """Discount per decision (40 primitive steps)."""
    gae_lambda: float = 0.95
    clip_coef: float = 0.2
    clip_vloss: bool = False
    """Clip the value error around the old values (PPO2); off by default."""
    kl_coef: float = 0.1
    """c1: weight of the KL penalty (the paper gives none; a light one)."""
    vf_coef: float = 0.5
    """c2: weight of the value error."""
    ent_coef: float = 0.01
    """c3: weight of the entropy bonus (team entropy, summed over robots)."""
    aux_coef: float = 1.0
    """c4 at the start: weight of the explored-ratio prediction error."""
    aux_decay: float = 0.5
    """Fraction of the run over which c4 decays linearly to 0."""
    epochs: int = 4
    minibatch_size: int = 64
    """Decisions per minibatch."""
    max_grad_norm: float = 0.5
    norm_adv: bool = True
    target_kl: float = 0.0
    """Stop an iteration's epochs early when approx_kl exceeds this (0: never)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before GAE (returns of large maps are tens of units)."""


@dataclass(frozen=True)
class RolloutConfig:
    """Where and how training episodes are played."""

    maps: tuple[str, ...] = ("bundled:train", "procedural:small", "procedural:medium", "procedural:large")
    """Map specs, each episode draws one uniformly from their expansion (``bundled:train`` is every
    training map; a procedural class counts as one entry)."""
    robots: tuple[int, ...] = (3, 4, 5)
    """Team sizes, drawn uniformly per episode."""
    episodes: int = 4
    """Episodes per iteration."""
    max_steps: int = 3600
    """Horizon of a training episode in primitive steps (90 decisions)."""
    env: Mapping[str, Any] = field(default_factory=dict)
    """Overrides of the environment's config (``areasearch.config.override`` keys), for the training
    and the validation episodes; ``protocol`` (the coverage protocol, ``paper`` or ``passby``) is
    always recorded here, the default's when not given."""


@dataclass(frozen=True)
class EvalConfig:
    """Periodic validation with the evaluation harness's episodes (deterministic goals)."""

    maps: tuple[str, ...] = ("bundled:val",)
    robots: tuple[int, ...] = (3,)
    episodes: int = 1
    """Episodes per map and team size."""
    every: int = 10
    """Iterations between validations (and after the last one)."""
    max_steps: int = 3600


@dataclass(frozen=True)
class TrainConfig:
    """A training run. ``total_decisions`` bounds it: iterations run until that many decisions."""

    seed: int = 0
    total_decisions: int = 60_000
    checkpoint_every: int = 1
    network: Any = None
    """:class:`areasearch.dahgnn.NetworkConfig` (None: the default)."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    rollout: RolloutConfig = field(default_factory=RolloutConfig)
    evaluation: EvalConfig = field(default_factory=EvalConfig)

    def validate(self) -> TrainConfig:
        from .dahgnn import NetworkConfig

        if self.network is None:
            return dataclasses.replace(self, network=NetworkConfig().validate()).validate()
        if not isinstance(self.network, NetworkConfig):
            raise ConfigError("network must be a NetworkConfig")
        self.network.validate()
        _check_int("seed", self.seed, 0)
        _check_int("total_decisions", self.total_decisions, 1)
        _check_int("checkpoint_every", self.checkpoint_every, 1)
        p = self.ppo
        for name in ("learning_rate", "clip_coef", "max_grad_norm", "reward_scale"):
            _check_float(f"ppo.{name}", getattr(p, name), positive=True)
        for name in ("kl_coef", "vf_coef", "ent_coef", "aux_coef", "target_kl"):
            _check_float(f"ppo.{name}", getattr(p, name))
        for name in ("gamma", "gae_lambda", "aux_decay"):
            _check_float(f"ppo.{name}", getattr(p, name))
            if getattr(p, name) > 1:
                raise ConfigError(f"ppo.{name} must be in [0, 1], got {getattr(p, name)!r}")
        _check_int("ppo.epochs", p.epochs, 1)
        _check_int("ppo.minibatch_size", p.minibatch_size, 1)
        r, e = self.rollout, self.evaluation
        for prefix, maps, robots in (("rollout", r.maps, r.robots), ("evaluation", e.maps, e.robots)):
            if not maps:
                raise ConfigError(f"{prefix}.maps must name at least one map")
            if not robots:
                raise ConfigError(f"{prefix}.robots must name at least one team size")
            for n in robots:
                _check_int(f"{prefix}.robots", n, 1)
        _check_int("rollout.episodes", r.episodes, 1)
        _check_int("rollout.max_steps", r.max_steps, 40)
        _check_int("evaluation.episodes", e.episodes, 0)
        _check_int("evaluation.every", e.every, 1)
        _check_int("evaluation.max_steps", e.max_steps, 40)
        return self


def _check_int(name: str, value: object, low: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise ConfigError(f"{name} must be an integer >= {low}, got {value!r}")


def _check_float(name: str, value: object, positive: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (positive and value == 0):  # type: ignore[operator]
        raise ConfigError(f"{name} must be a {'positive' if positive else 'non-negative'} number, got {value!r}")


def _section(cls: type, data: object, name: str) -> Any:
    """A dataclass of ``cls`` from a dict: unknown keys and values of the wrong type are refused."""
    if not isinstance(data, dict):
        raise ConfigError(f"[{name}] must be a table of settings, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    default = cls()
    for key, value in data.items():
        if key not in fields:
            raise ConfigError(f"unknown setting {name}.{key} (known: {', '.join(fields)})")
        expected = getattr(default, key)
        if isinstance(expected, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{name}.{key} must be true or false, got {value!r}")
        elif isinstance(expected, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{name}.{key} must be a number, got {value!r}")
            value = float(value)
        elif isinstance(expected, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{name}.{key} must be an integer, got {value!r}")
        elif isinstance(expected, tuple):
            if not isinstance(value, list):
                raise ConfigError(f"{name}.{key} must be a list, got {value!r}")
            kind = type(expected[0])
            if any(isinstance(v, bool) or not isinstance(v, kind) for v in value):
                raise ConfigError(f"{name}.{key} must be a list of {kind.__name__}, got {value!r}")
            value = tuple(value)
        elif isinstance(expected, Mapping):
            if not isinstance(value, dict):
                raise ConfigError(f"{name}.{key} must be a table, got {value!r}")
        values[key] = value
    return cls(**values)


def config_from_dict(data: object, source: str = "config") -> TrainConfig:
    """A validated :class:`TrainConfig` from the dict of a TOML/JSON file (see ``configs/``)."""
    from .dahgnn import NetworkConfig
    from .dahgnn import config_from_dict as network_from_dict

    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a training config must be a table of settings")
    known = {"seed", "total_decisions", "checkpoint_every", "network", "ppo", "rollout", "evaluation"}
    try:
        for key in data:
            if key not in known:
                raise ConfigError(f"unknown setting {key!r} (known: {', '.join(sorted(known))})")
        top = _section(
            TrainConfig, {k: v for k, v in data.items() if k in ("seed", "total_decisions", "checkpoint_every")}, "top"
        )
        net_data = dict(data.get("network", {}))
        preset = net_data.pop("preset", "dahgnn")
        if preset not in ("dahgnn", "ncm"):
            raise ConfigError(f"network.preset must be 'dahgnn' or 'ncm', got {preset!r}")
        base = dataclasses.asdict(NetworkConfig.ncm() if preset == "ncm" else NetworkConfig())
        graph = {**base.pop("graph"), **net_data.pop("graph", {})}
        network = network_from_dict({**base, **net_data, "graph": graph}, "network")
        config = TrainConfig(
            seed=top.seed,
            total_decisions=top.total_decisions,
            checkpoint_every=top.checkpoint_every,
            network=network,
            ppo=_section(PPOConfig, data.get("ppo", {}), "ppo"),
            rollout=_with_protocol(_section(RolloutConfig, data.get("rollout", {}), "rollout")),
            evaluation=_section(EvalConfig, data.get("evaluation", {}), "evaluation"),
        )
        return config.validate()
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def _with_protocol(rollout: RolloutConfig) -> RolloutConfig:
    """The rollout config with the coverage protocol named in ``env`` (the default's, when not
    given), so that a run's ``config.json`` records it and a resume under another is refused."""
    from .config import WorldConfig, search_key

    if any(search_key(str(key)) == "world.protocol" for key in rollout.env):
        return rollout
    return dataclasses.replace(rollout, env={"protocol": WorldConfig().protocol, **rollout.env})


def load_config(path: str | Path, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Read a training config (TOML, or JSON such as a run's ``config.json``), apply dotted
    ``overrides`` (``{"ppo.learning_rate": 3e-4}``), validate."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: cannot read the training config: {error}") from None
    try:
        data = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as error:
        raise ConfigError(f"{path}: not valid {'JSON' if path.suffix == '.json' else 'TOML'}: {error}") from None
    if isinstance(data, dict) and data.get("format") == TRAIN_FORMAT:
        data = {k: v for k, v in data.items() if k != "format"}
    for key, value in (overrides or {}).items():
        _check_override(key, path)
        *parents, leaf = key.split(".")
        node = data
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{path}: cannot set {key}: {part} is not a table")
        node[leaf] = value
    return config_from_dict(data, str(path))


def _check_override(key: str, path: Path) -> None:
    """ConfigError naming an override key that no training setting has; ``network.*`` keys are
    checked with the network config, ``rollout.env.*`` keys by the environment."""
    top = ("seed", "total_decisions", "checkpoint_every")
    sections: dict[str, type] = {"ppo": PPOConfig, "rollout": RolloutConfig, "evaluation": EvalConfig}
    head, _, rest = key.partition(".")
    if head == "network" or (head in top and not rest):
        return
    if head in sections:
        names = [f.name for f in dataclasses.fields(sections[head])]
        field_name = rest.split(".", 1)[0]
        if field_name in names and ("." not in rest or field_name == "env"):
            return
        known = ", ".join(f"{head}.{name}" for name in names)
    else:
        known = ", ".join([*top, "network.*", *(f"{name}.*" for name in sections)])
    raise ConfigError(f"{path}: unknown setting {key} (known: {known})")


def config_to_dict(config: TrainConfig) -> dict[str, Any]:
    """The resolved config as written to ``config.json`` (reads back with :func:`load_config`)."""
    doc = dataclasses.asdict(config)
    doc["rollout"]["env"] = dict(config.rollout.env)
    return {"format": TRAIN_FORMAT, **json.loads(json.dumps(doc))}


# ---------------------------------------------------------------------------------------------- episodes


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
    from .scene import scene_source
    from .splits import split_maps

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


def validation_episodes(config: TrainConfig, maps: Sequence[str]) -> list[EpisodeSpec]:
    """The validation episodes (the same at every validation), seeded as the harness seeds them."""
    from .evaluate import episode_seed

    e = config.evaluation
    env = tuple(sorted(config.rollout.env.items()))  # the same world rules as the training episodes
    return [
        EpisodeSpec(m, n, episode_seed(config.seed, m, n, i), e.max_steps, env, deterministic=True)
        for m in maps
        for n in e.robots
        for i in range(e.episodes)
    ]


@dataclass
class Trajectory:
    """One played episode: per decision the observation (map as float16), the team's goals, their
    joint log-probability and the value under the acting policy, the reward, the explored-ratio label."""

    spec: EpisodeSpec
    observations: list[dict[str, np.ndarray]]
    actions: list[np.ndarray]
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    explored: np.ndarray
    terminated: bool
    last_value: float
    """Value of the final observation (bootstrap when truncated)."""
    info: dict[str, Any]
    steps: list[int]
    covered_curve: list[float]
    wall_s: float

    @property
    def robot_steps(self) -> int:
        return int(self.info["steps"]) * self.spec.robots


_WORKER: dict[str, Any] = {}


def _worker_model(network: dict[str, Any], weights: Mapping[str, np.ndarray]) -> Any:
    """This process's copy of the network with ``weights`` (rebuilt only when the config changes)."""
    import torch

    from .dahgnn import DAHGNN
    from .dahgnn import config_from_dict as network_from_dict

    key = json.dumps(network, sort_keys=True)
    if _WORKER.get("key") != key:
        _WORKER["model"] = DAHGNN(network_from_dict(network, "network")).eval()
        _WORKER["key"] = key
    model = _WORKER["model"]
    model.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in weights.items()})
    return model


def play(network: dict[str, Any], weights: Mapping[str, np.ndarray], spec: EpisodeSpec) -> Trajectory:
    """Play one episode with the policy (in a worker process, a Ray task or here)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in a worker process: the same numbers with any number of workers
    try:
        return _play(network, weights, spec)
    finally:
        torch.set_num_threads(threads)


def _play(network: dict[str, Any], weights: Mapping[str, np.ndarray], spec: EpisodeSpec) -> Trajectory:
    import torch

    from .dahgnn import act
    from .goal_env import AreaSearchEnv

    t0 = time.perf_counter()
    model = _worker_model(network, weights)
    env = AreaSearchEnv(
        map=spec.map, num_robots=spec.robots, seed=spec.seed, max_steps=spec.max_steps, **dict(spec.env)
    )
    obs, info = env.reset(seed=spec.seed)
    generator = torch.Generator().manual_seed(spec.seed)
    observations, actions, log_probs, values, rewards, explored = [], [], [], [], [], []
    steps, covered = [int(info["steps"])], [float(info["covered_pct"])]
    terminated = truncated = False
    while not (terminated or truncated):
        result = act(model, obs, deterministic=spec.deterministic, generator=generator)
        action = result.actions[0].cpu().numpy()
        stored = dict(obs)
        stored["map"] = obs["map"].astype(np.float16)
        observations.append(stored)
        actions.append(action.astype(np.int64))
        log_probs.append(float(result.log_prob[0]))
        values.append(float(result.value[0]))
        explored.append(float(info["explored_ratio"]))
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(float(reward))
        steps.append(int(info["steps"]))
        covered.append(float(info["covered_pct"]))
    last_value = 0.0
    if truncated and not spec.deterministic:
        last_value = float(act(model, obs, deterministic=True).value[0])
    return Trajectory(
        spec,
        observations,
        actions,
        np.array(log_probs, dtype=np.float32),
        np.array(values, dtype=np.float32),
        np.array(rewards, dtype=np.float32),
        np.array(explored, dtype=np.float32),
        bool(terminated),
        last_value,
        dict(info),
        steps,
        covered,
        time.perf_counter() - t0,
    )


def coverage_auc(steps: Sequence[int], covered: Sequence[float], horizon: int) -> float:
    """Mean Cover% over the horizon (the area under the step-wise Cover% curve / horizon): higher
    when more targets are covered and when they are covered sooner."""
    area, last_step, last_value = 0.0, 0, 0.0
    for s, c in zip(steps, covered, strict=True):
        area += last_value * (min(s, horizon) - last_step)
        last_step, last_value = min(s, horizon), c
    area += last_value * (horizon - last_step)
    return area / horizon


class Backend:
    """Plays episodes: in this process (``workers=0``), in worker processes, or as Ray tasks."""

    def __init__(self, kind: str, workers: int, address: str | None = None) -> None:
        self.kind, self.workers = kind, workers
        self._pool: ProcessPoolExecutor | None = None
        self._ray: Any = None
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
            self._play = ray.remote(num_cpus=1)(play)
        elif kind == "local":
            if workers > 0:
                self._pool = worker_pool(workers)
        else:
            raise ConfigError(f"backend must be 'local' or 'ray', got {kind!r}")

    def map(
        self, network: dict[str, Any], weights: dict[str, np.ndarray], specs: Sequence[EpisodeSpec]
    ) -> Iterator[Trajectory]:
        """Trajectories of ``specs``, in order (each as soon as it and those before it are done)."""
        if self._ray is not None:
            ref = self._ray.put(weights)
            futures = [self._play.remote(network, ref, s) for s in specs]
            for f in futures:
                yield self._ray.get(f)
        elif self._pool is not None:
            jobs = [self._pool.submit(play, network, weights, s) for s in specs]
            for job in jobs:
                yield job.result()
        else:
            for s in specs:
                yield play(network, weights, s)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
        if self._ray is not None and self._ray.is_initialized():
            self._ray.shutdown()


# ---------------------------------------------------------------------------------------------- PPO


def gae(traj: Trajectory, gamma: float, lam: float, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(advantages, returns) of one episode by GAE; the value after the last decision is 0 when the
    episode terminated and the bootstrap value when it was truncated."""
    rewards, values = traj.rewards * scale, traj.values
    next_values = np.append(values[1:], 0.0 if traj.terminated else traj.last_value)
    advantages = np.zeros_like(rewards)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        delta = rewards[t] + gamma * next_values[t] - values[t]
        running = delta + gamma * lam * running
        advantages[t] = running
    return advantages, advantages + values


def _pad_actions(actions: Sequence[np.ndarray]) -> np.ndarray:
    width = max(len(a) for a in actions)
    out = np.zeros((len(actions), width), dtype=np.int64)
    for i, a in enumerate(actions):
        out[i, : len(a)] = a
    return out


def _observation32(obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = dict(obs)
    out["map"] = obs["map"].astype(np.float32)
    return out


def ppo_update(
    model: Any,
    optimizer: Any,
    trajectories: Sequence[Trajectory],
    config: TrainConfig,
    iteration: int,
    aux_coef: float,
) -> dict[str, float]:
    """PPO epochs over the decisions of ``trajectories``; returns the iteration's loss statistics."""
    import torch

    from .dahgnn import evaluate_actions
    from .graph import build_graph

    p = config.ppo
    observations = [o for t in trajectories for o in t.observations]
    actions = _pad_actions([a for t in trajectories for a in t.actions])
    parts = [gae(t, p.gamma, p.gae_lambda, p.reward_scale) for t in trajectories]
    advantages = np.concatenate([a for a, _ in parts]).astype(np.float32)
    returns = np.concatenate([r for _, r in parts]).astype(np.float32)
    old_log_probs = np.concatenate([t.log_probs for t in trajectories])
    old_values = np.concatenate([t.values for t in trajectories])
    labels = np.concatenate([t.explored for t in trajectories])
    n = len(observations)
    rng = np.random.default_rng([config.seed, iteration, 1])
    critic_params = list(model.critic.parameters())
    critic_ids = {id(t) for t in critic_params}
    actor_params = [t for t in model.parameters() if id(t) not in critic_ids]
    whole = build_graph([_observation32(o) for o in observations], config.network.graph)  # built once, sliced below
    model.train()
    stats: dict[str, list[float]] = {}
    stop = False
    for _ in range(p.epochs):
        order = rng.permutation(n)
        for start in range(0, n, p.minibatch_size):
            idx = order[start : start + p.minibatch_size]
            batch = whole.index(torch.from_numpy(idx)).trim()
            res = evaluate_actions(model, batch, torch.from_numpy(actions[idx, : batch.action_mask.shape[1]]))
            old_lp = torch.from_numpy(old_log_probs[idx])
            log_ratio = res.log_prob - old_lp
            ratio = log_ratio.exp()
            adv = torch.from_numpy(advantages[idx])
            if p.norm_adv and len(idx) > 1:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - p.clip_coef, 1 + p.clip_coef)).mean()
            kl = ((ratio - 1) - log_ratio).mean()
            ret = torch.from_numpy(returns[idx])
            if p.clip_vloss:
                old_v = torch.from_numpy(old_values[idx])
                clipped = old_v + (res.value - old_v).clamp(-p.clip_coef, p.clip_coef)
                v_loss = 0.5 * torch.max((res.value - ret) ** 2, (clipped - ret) ** 2).mean()
            else:
                v_loss = 0.5 * ((res.value - ret) ** 2).mean()
            entropy = res.entropy.mean()
            aux_loss = ((res.explored_ratio - torch.from_numpy(labels[idx])) ** 2).mean()
            loss = pg_loss + p.kl_coef * kl + p.vf_coef * v_loss - p.ent_coef * entropy + aux_coef * aux_loss
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            # actor and critic clipped apart: the value error's gradient (returns of tens of units)
            # would otherwise set the shared norm and shrink the policy's steps to nothing
            grad_norm = torch.nn.utils.clip_grad_norm_(actor_params, p.max_grad_norm)
            critic_grad_norm = torch.nn.utils.clip_grad_norm_(critic_params, p.max_grad_norm)
            optimizer.step()
            with torch.no_grad():
                clipfrac = ((ratio - 1).abs() > p.clip_coef).float().mean()
            for key, value in (
                ("losses/policy_loss", pg_loss),
                ("losses/kl_penalty", kl),
                ("losses/value_loss", v_loss),
                ("losses/entropy", entropy),
                ("losses/aux_loss", aux_loss),
                ("losses/approx_kl", kl),
                ("losses/clipfrac", clipfrac),
                ("losses/grad_norm", grad_norm),
                ("losses/critic_grad_norm", critic_grad_norm),
            ):
                stats.setdefault(key, []).append(float(value.detach()))
            if p.target_kl and float(kl) > p.target_kl:
                stop = True
                break
        if stop:
            break
    model.eval()
    var = float(np.var(returns))
    explained = float("nan") if var == 0 else 1.0 - float(np.var(returns - old_values)) / var
    out = {k: float(np.mean(v)) for k, v in stats.items()}
    out["losses/explained_variance"] = explained
    out["losses/advantage_mean"] = float(advantages.mean())
    return out


# ---------------------------------------------------------------------------------------------- checkpoints


def _atomic_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _atomic_text(path: Path, text: str) -> None:
    _atomic_bytes(path, text.encode("utf-8"))


def save_checkpoint(run: Path, model: Any, optimizer: Any, state: dict[str, Any]) -> Path:
    """Weights + Adam state in ``checkpoint-<iteration>.safetensors``, counters in ``checkpoint.json``
    (written last, atomically); then older checkpoint files are removed."""
    from safetensors.torch import save

    tensors = {f"model/{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    opt = optimizer.state_dict()
    for index, entry in opt["state"].items():
        for key, value in entry.items():
            tensors[f"optim/{index}/{key}"] = value.detach().cpu().contiguous().reshape(value.shape)
    name = f"checkpoint-{state['iteration']:06d}.safetensors"
    _atomic_bytes(run / name, save(tensors))
    doc = {"format": TRAIN_FORMAT, "weights": name, "param_groups": opt["param_groups"], **state}
    _atomic_text(run / CHECKPOINT_FILE, json.dumps(doc, indent=1) + "\n")
    for old in run.glob("checkpoint-*.safetensors"):
        if old.name != name:
            old.unlink(missing_ok=True)
    return run / name


def load_checkpoint(run: Path, model: Any, optimizer: Any) -> dict[str, Any]:
    """Restore what :func:`save_checkpoint` wrote; returns the counters. ConfigError names a bad file."""
    import torch
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    meta = run / CHECKPOINT_FILE
    try:
        doc = json.loads(meta.read_text())
        weights = run / str(doc["weights"])
        tensors = load_file(str(weights))
    except (OSError, ValueError, KeyError, TypeError, SafetensorError, json.JSONDecodeError) as error:
        raise ConfigError(f"{meta}: cannot read the checkpoint: {error}") from None
    prefix = "model/"
    state = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
    expected = model.state_dict()
    if set(state) != set(expected) or any(state[k].shape != expected[k].shape for k in expected):
        raise ConfigError(f"{weights}: the weights do not match the run's network config")
    model.load_state_dict(state)
    opt_state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith("optim/"):
            _, index, name = key.split("/", 2)
            opt_state.setdefault(int(index), {})[name] = value
    try:
        optimizer.load_state_dict({"state": opt_state, "param_groups": doc["param_groups"]})
    except (ValueError, KeyError) as error:
        raise ConfigError(f"{meta}: the optimizer state does not match the network: {error}") from None
    return {k: v for k, v in doc.items() if k not in ("format", "weights", "param_groups")}


# ---------------------------------------------------------------------------------------------- logs


PROGRESS_FIELDS = (
    "iteration",
    "decisions",
    "episodes",
    "wall_s",
    "charts/episodic_return",
    "charts/explored_pct",
    "charts/covered_pct",
    "charts/episode_decisions",
    "charts/learning_rate",
    "charts/aux_coef",
    "losses/policy_loss",
    "losses/kl_penalty",
    "losses/value_loss",
    "losses/entropy",
    "losses/aux_loss",
    "losses/approx_kl",
    "losses/clipfrac",
    "losses/grad_norm",
    "losses/critic_grad_norm",
    "losses/explained_variance",
    "losses/advantage_mean",
    "perf/decisions_per_s",
    "perf/robot_steps_per_s",
    "perf/rollout_s",
    "perf/update_s",
)
EVAL_FIELDS = (
    "iteration",
    "decisions",
    "map",
    "robots",
    "seed",
    "explored_pct",
    "covered_pct",
    "time_e",
    "time_c",
    "coverage_auc",
)


class CsvLog:
    """A CSV log, appended one fsync'ed line at a time; opening keeps only rows up to ``keep_until``
    (the checkpoint's iteration) and a complete header, so a resumed run has no duplicated row."""

    def __init__(self, path: Path, fields: Sequence[str], keep_until: int) -> None:
        self.path, self.fields = path, list(fields)
        rows: list[dict[str, str]] = []
        if path.exists():
            with open(path, newline="", encoding="utf-8") as f:
                text = f.read()
            if not text.endswith("\n"):
                text = text[: text.rfind("\n") + 1]
            reader = csv.DictReader(io.StringIO(text))
            if reader.fieldnames == self.fields:
                rows = [r for r in reader if r.get("iteration", "").isdigit() and int(r["iteration"]) <= keep_until]
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, self.fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        _atomic_text(path, buffer.getvalue())

    def append(self, row: Mapping[str, Any]) -> None:
        buffer = io.StringIO()
        csv.DictWriter(buffer, self.fields, lineterminator="\n").writerow(
            {k: _fmt(row.get(k, "")) for k in self.fields}
        )
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(buffer.getvalue())
            f.flush()
            os.fsync(f.fileno())


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


class Scalars:
    """TensorBoard scalars (``tb/`` of the run folder): every numeric ``charts/``, ``losses/``,
    ``perf/`` and ``eval/`` value of a row, by decisions."""

    def __init__(self, folder: Path, purge_step: int | None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self._writer = SummaryWriter(str(folder), purge_step=purge_step)

    def add(self, values: Mapping[str, Any], step: int) -> None:
        for key, value in values.items():
            if isinstance(value, (int, float)) and "/" in key and math.isfinite(value):
                self._writer.add_scalar(key, value, step)

    def close(self) -> None:
        self._writer.close()


def _duration(seconds: float) -> str:
    seconds = int(round(max(0.0, seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s"


def draw_training_curve(run: Path) -> Path | None:
    """``curve.png``: training return, Cover% and Explo% by decisions, and the validation score."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    progress = _read_csv(run / PROGRESS_FILE)
    if not progress:
        return None
    evals = _read_csv(run / EVAL_FILE)
    x = [float(r["decisions"]) for r in progress]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot(x, _smooth([float(r["charts/episodic_return"]) for r in progress]))
    axes[0].set_title("training episodic return")
    axes[1].plot(x, _smooth([float(r["charts/covered_pct"]) for r in progress]), label="Cover%")
    axes[1].plot(x, _smooth([float(r["charts/explored_pct"]) for r in progress]), label="Explo%")
    axes[1].set_title("training episodes (end of episode)")
    axes[1].legend()
    if evals:
        by: dict[float, list[float]] = {}
        for r in evals:
            by.setdefault(float(r["decisions"]), []).append(float(r["coverage_auc"]))
        xs = sorted(by)
        axes[2].plot(xs, [float(np.mean(by[k])) for k in xs], marker="o")
    axes[2].set_title("validation: mean Cover% over the horizon")
    for ax in axes:
        ax.set_xlabel("decisions")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    _atomic_bytes(run / "curve.png", buffer.getvalue())
    return run / "curve.png"


def _smooth(values: Sequence[float], k: int = 10) -> list[float]:
    out, acc = [], []
    for v in values:
        acc.append(v)
        acc = acc[-k:]
        out.append(float(np.mean(acc)))
    return out


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


# ---------------------------------------------------------------------------------------------- the run


@dataclass
class RunResult:
    iterations: int
    decisions: int
    best_score: float
    wall_s: float


def _weights(model: Any) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}


def _prepare_run(out: Path, config: TrainConfig, resume: bool) -> bool:
    """Check the run folder; returns True when a checkpoint should be loaded."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: the run folder is a file")
    saved = out / CONFIG_FILE
    has_checkpoint = (out / CHECKPOINT_FILE).exists()
    if saved.exists():
        if not resume:
            raise ConfigError(f"{out}: a run is already there; pass --resume to continue it (nothing was changed)")
        try:
            previous = json.loads(saved.read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ConfigError(f"{saved}: cannot read the run's config: {error}") from None
        if previous != config_to_dict(config):
            raise ConfigError(f"{out}: the run was started with another config ({saved}); use a new --out")
        return has_checkpoint
    out.mkdir(parents=True, exist_ok=True)
    _atomic_text(saved, json.dumps(config_to_dict(config), indent=1) + "\n")
    return False


def train(
    config: TrainConfig,
    out: str | Path,
    *,
    resume: bool = False,
    device: str = "cpu",
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    log: TextIO | str | None = "stdout",
    progress: TextIO | str | None = "stderr",
    stop_after: int | None = None,
) -> RunResult:
    """Run (or resume) PPO training into ``out``; see the module docstring. ``stop_after`` ends the
    call after that many iterations of this call (tests, time-boxed sessions); the run can be resumed.
    ``log`` takes the plain line per iteration (default: the current ``sys.stdout``), ``progress`` the
    progress report (default: the current ``sys.stderr``; :class:`areasearch.runlog.Progress`: a bar
    on a terminal, a plain line at most every 10 s and at the end otherwise); None: nothing."""
    import torch

    from .dahgnn import DAHGNN, save_policy

    log = sys.stdout if log == "stdout" else log
    progress = sys.stderr if progress == "stderr" else progress
    assert not isinstance(log, str) and not isinstance(progress, str)
    config = config.validate()
    if device not in ("cpu", "cuda"):
        raise ConfigError(f"device must be 'cpu' or 'cuda', got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' asked for, but PyTorch sees no CUDA device")
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 0:
        raise ConfigError(f"workers must be >= 0, got {workers}")
    train_maps = expand_maps(config.rollout.maps)
    val_maps = expand_maps(config.evaluation.maps)
    run = Path(out)
    load = _prepare_run(run, config, resume)

    torch.manual_seed(config.seed)
    model = DAHGNN(config.network).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5)
    state: dict[str, Any] = {"iteration": 0, "decisions": 0, "episodes": 0, "wall_s": 0.0, "best_score": -1.0}
    if load:
        state.update(load_checkpoint(run, model, optimizer))
    model.eval()
    network = dataclasses.asdict(config.network)
    progress_log = CsvLog(run / PROGRESS_FILE, PROGRESS_FIELDS, state["iteration"])
    eval_log = CsvLog(run / EVAL_FILE, EVAL_FIELDS, state["iteration"])
    scalars = Scalars(run / "tb", purge_step=state["decisions"] + 1 if load else None)
    pool = Backend(backend, workers, address)
    bar = Progress("train", config.total_decisions, "decisions", progress, done=state["decisions"], rate_unit="dec/s")
    threads = max(1, os.cpu_count() or 1)
    torch.set_num_threads(threads)
    ran = 0
    t_start = time.perf_counter() - float(state["wall_s"])
    try:
        if load and log is not None:
            bar.clear()
            print(f"resumed {run} at iteration {state['iteration']} ({state['decisions']:,} decisions)", file=log)
        while state["decisions"] < config.total_decisions and (stop_after is None or ran < stop_after):
            iteration = state["iteration"] + 1
            fraction = state["decisions"] / config.total_decisions
            lr = config.ppo.learning_rate * (1.0 - fraction if config.ppo.anneal_lr else 1.0)
            for group in optimizer.param_groups:
                group["lr"] = lr
            aux = config.ppo.aux_coef * max(0.0, 1.0 - fraction / config.ppo.aux_decay) if config.ppo.aux_decay else 0.0
            t0 = time.perf_counter()
            weights = _weights(model)
            trajectories: list[Trajectory] = []
            for traj in pool.map(network, weights, iteration_episodes(config, train_maps, iteration)):
                trajectories.append(traj)
                bar.update(state["decisions"] + sum(len(t.rewards) for t in trajectories))
            t1 = time.perf_counter()
            stats = ppo_update(model, optimizer, trajectories, config, iteration, aux)
            t2 = time.perf_counter()
            decisions = sum(len(t.rewards) for t in trajectories)
            state["iteration"] = iteration
            state["decisions"] += decisions
            state["episodes"] += len(trajectories)
            state["wall_s"] = time.perf_counter() - t_start
            row: dict[str, Any] = {
                "iteration": iteration,
                "decisions": state["decisions"],
                "episodes": state["episodes"],
                "wall_s": state["wall_s"],
                "charts/episodic_return": float(np.mean([t.rewards.sum() for t in trajectories])),
                "charts/explored_pct": float(np.mean([t.info["explored_pct"] for t in trajectories])),
                "charts/covered_pct": float(np.mean([t.info["covered_pct"] for t in trajectories])),
                "charts/episode_decisions": float(np.mean([len(t.rewards) for t in trajectories])),
                "charts/learning_rate": lr,
                "charts/aux_coef": aux,
                **stats,
                "perf/decisions_per_s": decisions / (t2 - t0),
                "perf/robot_steps_per_s": sum(t.robot_steps for t in trajectories) / (t2 - t0),
                "perf/rollout_s": t1 - t0,
                "perf/update_s": t2 - t1,
            }
            last = state["decisions"] >= config.total_decisions
            if config.evaluation.episodes and (iteration % config.evaluation.every == 0 or last):
                score = _validate(pool, network, _weights(model), config, val_maps, state, eval_log, scalars)
                row["eval/coverage_auc"] = score
                if score > state["best_score"]:
                    state["best_score"] = score
                    _save_policy_atomic(save_policy, run / "policy", model)
            progress_log.append(row)
            scalars.add(row, state["decisions"])
            bar.clear()
            if log is not None:
                print(_line(row, config.total_decisions), file=log, flush=True)
            if iteration % config.checkpoint_every == 0 or last:
                save_checkpoint(run, model, optimizer, state)
            ran += 1
        if state["decisions"] >= config.total_decisions:
            _save_policy_atomic(save_policy, run / "final", model)
            if not (run / "policy.json").exists():
                _save_policy_atomic(save_policy, run / "policy", model)
            draw_training_curve(run)
    finally:
        bar.update(state["decisions"])
        bar.close()
        pool.close()
        scalars.close()
    return RunResult(state["iteration"], state["decisions"], state["best_score"], state["wall_s"])


def _save_policy_atomic(save_policy: Callable[..., Any], prefix: Path, model: Any) -> None:
    """save_policy into temporary names, then rename both (JSON last)."""
    tmp = prefix.with_name(f".{prefix.name}.tmp")
    weights, meta = save_policy(tmp, model)
    os.replace(weights, prefix.with_name(prefix.name + ".safetensors"))
    os.replace(meta, prefix.with_name(prefix.name + ".json"))


def _validate(
    pool: Backend,
    network: dict[str, Any],
    weights: dict[str, np.ndarray],
    config: TrainConfig,
    maps: Sequence[str],
    state: Mapping[str, Any],
    log: CsvLog,
    scalars: Scalars,
) -> float:
    """Play the validation episodes with deterministic goals; log them; return the mean coverage AUC."""
    scores, explored, covered = [], [], []
    for traj in pool.map(network, weights, validation_episodes(config, maps)):
        auc = coverage_auc(traj.steps, traj.covered_curve, traj.spec.max_steps)
        scores.append(auc)
        explored.append(float(traj.info["explored_pct"]))
        covered.append(float(traj.info["covered_pct"]))
        log.append(
            {
                "iteration": state["iteration"],
                "decisions": state["decisions"],
                "map": traj.spec.map,
                "robots": traj.spec.robots,
                "seed": traj.spec.seed,
                "explored_pct": float(traj.info["explored_pct"]),
                "covered_pct": float(traj.info["covered_pct"]),
                "time_e": int(traj.info["time_e"]),
                "time_c": int(traj.info["time_c"]),
                "coverage_auc": auc,
            }
        )
    score = float(np.mean(scores))
    scalars.add(
        {
            "eval/coverage_auc": score,
            "eval/explored_pct": float(np.mean(explored)),
            "eval/covered_pct": float(np.mean(covered)),
        },
        int(state["decisions"]),
    )
    return score


def _line(row: Mapping[str, Any], total: int) -> str:
    text = (
        f"iter {row['iteration']:4d}  decisions {row['decisions']:>7,}/{total:,}  "
        f"return {row['charts/episodic_return']:6.2f}  Explo {row['charts/explored_pct']:5.1f}%  "
        f"Cover {row['charts/covered_pct']:5.1f}%  "
        f"vloss {row.get('losses/value_loss', float('nan')):.3f}  "
        f"kl {row.get('losses/approx_kl', float('nan')):.4f}  clip {row.get('losses/clipfrac', float('nan')):.2f}  "
        f"ev {row.get('losses/explained_variance', float('nan')):.2f}  "
        f"{row['perf/decisions_per_s']:.1f} dec/s  {row['perf/robot_steps_per_s']:,.0f} r-st/s  "
        f"elapsed {_duration(row['wall_s'])}"
    )
    if "eval/coverage_auc" in row:
        text += f"  val AUC {row['eval/coverage_auc']:.2f}"
    return text


__all__ = [
    "AreaSearchError",
    "EpisodeSpec",
    "EvalConfig",
    "PPOConfig",
    "RolloutConfig",
    "TrainConfig",
    "Trajectory",
    "coverage_auc",
    "gae",
    "load_config",
    "play",
    "train",
]
