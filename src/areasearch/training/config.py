"""The training config: what a run of :mod:`areasearch.training.train` is, read from ``configs/*.toml``.

A :class:`TrainConfig` (seed, budget, network, :class:`PPOConfig`, :class:`RolloutConfig`,
:class:`EvalConfig`) is the whole input of a run: with the same config a run plays the same
episodes and takes the same steps. :func:`load_config` reads one from TOML (or from a run's
``config.json``) with dotted overrides; unknown settings and values of the wrong type are refused
with a :class:`~areasearch.errors.ConfigError` that names the setting. :func:`config_to_dict` is the
resolved config a run folder records, and that a resume must match.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..config import MAX_ROBOTS, REALISM_NAMES
from ..errors import ConfigError
from ..inputs import clip, regular_file, short

TRAIN_FORMAT = "areasearch-train/1"
"""The ``format`` of a run's ``config.json`` and ``checkpoint.json``."""


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
    target_kl: float = 0.02
    """Stop an iteration's epochs early after the first minibatch whose approx_kl (per robot with
    ``ratio = "robot"``) exceeds this (0: never)."""
    ratio: str = "robot"
    """``robot``: one ratio per robot that chose, pi(a_r | a_<r) / pi_old(a_r | a_<r) of the sequential
    draw, each with the team's advantage, clipped and averaged over robots (MAPPO-style; Yu et al.
    2022); the entropy bonus is the mean per robot. ``team``: one ratio per decision on the joint
    log-probability (its KL is the sum of the robots', so a per-robot KL of 0.01 becomes a joint one
    of 0.04-0.05 and a clip fraction near 0.3, and a clipped decision loses the gradient of all its
    robots); the entropy bonus is the team's sum."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before GAE (returns of large maps are tens of units)."""
    threads: int = 1
    """PyTorch threads of the update (the rollouts always run on one thread per worker). Part of the
    config because the result depends on it: a reduction split over more threads adds up in another
    order, so a run set to the machine's core count would give other numbers on another machine.
    One thread is also the faster on a 2-core machine (docs/performance.md#training-throughput)."""
    shards: int = 1
    """Data-parallel update: each minibatch is cut, in order, into this many shards whose gradients
    are computed apart (on one PyTorch thread each, in the rollout workers when there are any) and
    summed in shard order before the optimizer's step. 1: the whole minibatch in this process on
    ``ppo.threads`` threads. A run's numbers depend on it (a shard's sums are added in another order
    than the whole minibatch's), not on the number of workers that compute the shards
    (:func:`areasearch.training.ppo_shards.shard_gradient`)."""


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
    lockstep: int = 1
    """Episodes a worker task plays in lockstep, with one batched network forward per decision round
    for all of them (a batch of 4 costs about 40 % of 4 single forwards); an iteration's episodes
    are cut into such groups in order. A run's numbers depend on it (batched arithmetic differs in
    its last bits), not on the number of workers; 1 plays each episode alone."""
    max_steps: int = 3600
    """Horizon of a training episode in primitive steps (90 decisions)."""
    env: Mapping[str, Any] = field(default_factory=dict)
    """Overrides of the environment's config (``areasearch.config.override`` keys), for the training
    and the validation episodes; ``protocol`` (the coverage protocol, ``paper`` or ``passby``) is
    always recorded here, the default's when not given. ``realism`` names a preset of the world's
    imperfections (:data:`areasearch.config.REALISM_PRESETS`, ``train --realism``), applied under the
    other settings here (they win over its values); ``none`` is the same as no preset, and not recorded."""


@dataclass(frozen=True)
class EvalConfig:
    """Periodic validation with the evaluation harness's episodes (deterministic goals)."""

    maps: tuple[str, ...] = ("bundled:val",)
    robots: tuple[int, ...] = (3,)
    episodes: int = 3
    """Episodes per map and team size (10 validation maps x 3: the score's standard error is about a
    third of a point; one episode per map had a standard deviation of about 1 point, as large as
    the differences between checkpoints)."""
    every: int = 10
    """Iterations between validations (and after the last one). Each validation's policy is kept
    in ``snapshots/`` for the final selection."""
    max_steps: int = 3600
    finalists: int = 3
    """At the end of the run, the validations with the best smoothed score (the mean of a validation
    and its neighbours) are played again on ``final_episodes`` fresh episodes per map, the same
    episodes for each (paired); the best of them is the shipped ``policy`` (``selection.json``).
    0: ``policy`` is the best single validation."""
    final_episodes: int = 5
    """Episodes per map and team size of the final comparison (seeds after the validation's)."""


@dataclass(frozen=True)
class TrainConfig:
    """A training run. ``total_decisions`` bounds it: iterations run until that many decisions."""

    seed: int = 0
    total_decisions: int = 60_000
    checkpoint_every: int = 1
    network: Any = None
    """:class:`areasearch.models.dahgnn.NetworkConfig` (None: the default)."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    rollout: RolloutConfig = field(default_factory=RolloutConfig)
    evaluation: EvalConfig = field(default_factory=EvalConfig)

    def validate(self) -> TrainConfig:
        from ..models.network_config import NetworkConfig

        if self.network is None:
            return dataclasses.replace(self, network=NetworkConfig().validate()).validate()
        if not isinstance(self.network, NetworkConfig):
            raise ConfigError("network must be a NetworkConfig")
        self.network.validate()  # every size bounded (dahgnn.NETWORK_SIZES), as for a policy file
        _check_int("seed", self.seed, 0, MAX_SEED)
        _check_int("total_decisions", self.total_decisions, 1, MAX_DECISIONS)
        _check_int("checkpoint_every", self.checkpoint_every, 1, MAX_ITERATIONS)
        p = self.ppo
        for name in ("learning_rate", "clip_coef", "max_grad_norm", "reward_scale"):
            _check_float(f"ppo.{name}", getattr(p, name), positive=True)
        for name in ("kl_coef", "vf_coef", "ent_coef", "aux_coef", "target_kl"):
            _check_float(f"ppo.{name}", getattr(p, name))
        for name in ("gamma", "gae_lambda", "aux_decay"):
            _check_float(f"ppo.{name}", getattr(p, name))
            if getattr(p, name) > 1:
                raise ConfigError(f"ppo.{name} must be in [0, 1], got {getattr(p, name)!r}")
        _check_int("ppo.epochs", p.epochs, 1, 1_000)
        _check_int("ppo.minibatch_size", p.minibatch_size, 1, 1_000_000)
        _check_int("ppo.threads", p.threads, 1, 256)
        _check_int("ppo.shards", p.shards, 1, 256)
        if p.ratio not in ("robot", "team"):
            raise ConfigError(f"ppo.ratio must be 'robot' or 'team', got {short(p.ratio)}")
        r, e = self.rollout, self.evaluation
        for prefix, maps, robots in (("rollout", r.maps, r.robots), ("evaluation", e.maps, e.robots)):
            if not maps:
                raise ConfigError(f"{prefix}.maps must name at least one map")
            if len(maps) > MAX_LIST:
                raise ConfigError(f"{prefix}.maps must name at most {MAX_LIST:,} maps, got {len(maps):,}")
            if not robots:
                raise ConfigError(f"{prefix}.robots must name at least one team size")
            if len(robots) > MAX_LIST:
                raise ConfigError(f"{prefix}.robots must name at most {MAX_LIST:,} team sizes, got {len(robots):,}")
            for n in robots:
                _check_int(f"{prefix}.robots", n, 1, MAX_ROBOTS)
        _check_int("rollout.episodes", r.episodes, 1, 10_000)
        _check_int("rollout.lockstep", r.lockstep, 1, 256)
        _check_int("rollout.max_steps", r.max_steps, 40, MAX_TRAIN_STEPS)
        _check_env(r.env)
        _check_int("evaluation.episodes", e.episodes, 0, 10_000)
        _check_int("evaluation.every", e.every, 1, MAX_ITERATIONS)
        _check_int("evaluation.max_steps", e.max_steps, 40, MAX_STEPS)
        _check_int("evaluation.finalists", e.finalists, 0, 100)
        _check_int("evaluation.final_episodes", e.final_episodes, 1, 10_000)
        return self


MAX_SEED = 2**63 - 1
"""Largest run seed: a non-negative int64 (PyTorch's generator takes at most 64 bits)."""
MAX_DECISIONS = 1_000_000_000
"""Largest ``total_decisions``: about a year of training at 30 decisions/s."""
MAX_ITERATIONS = 1_000_000
"""Largest ``checkpoint_every`` and ``evaluation.every``, iterations."""
MAX_TRAIN_STEPS = 100_000
"""Largest ``rollout.max_steps``: a training episode's decisions (one per 40 steps, 2,500 here) are
held in memory with their observations until the update."""
MAX_STEPS = 10_000_000
"""Largest ``evaluation.max_steps``: the world's own bound on a horizon."""
MAX_LIST = 1_000
"""Most entries of a list of maps or team sizes."""


def _check_int(name: str, value: object, low: int, high: int | None = None) -> None:
    """ConfigError unless ``value`` is an integer in [low, high] (no bool)."""
    ok = isinstance(value, int) and not isinstance(value, bool) and value >= low and (high is None or value <= high)
    if not ok:
        bound = f">= {low}" if high is None else f"from {low} to {high:,}"
        raise ConfigError(f"{name} must be an integer {bound}, got {short(value)}")


def _check_float(name: str, value: object, positive: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (positive and value == 0):  # type: ignore[operator]
        raise ConfigError(f"{name} must be a {'positive' if positive else 'non-negative'} number, got {short(value)}")


def _check_env(env: Mapping[str, Any]) -> None:
    """ConfigError naming a ``rollout.env`` setting the episodes' environment would refuse: checked
    here, as the environment reads it (world keys, or ``candidates.`` / ``paths.`` / ``decisions.``
    keys), before a run folder is made; the team size and horizon come from the rollout settings."""
    from ..config import SearchConfig, override, realism_keywords, search_key

    world: dict[str, Any] = {}
    search: dict[str, Any] = {}
    realism, others = training_realism(env)
    try:
        env = realism_keywords(realism, others)  # the preset's settings checked with the others over them
    except ConfigError as error:
        raise ConfigError(f"rollout.env: {error}") from None
    for key, value in env.items():
        if not isinstance(key, str):
            raise ConfigError(f"rollout.env: a setting name must be text, got {short(key)}")
        if search_key(key) in ("world.num_robots", "world.max_steps"):
            given = "rollout.robots" if key.endswith("num_robots") else "rollout.max_steps"
            raise ConfigError(f"rollout.env.{short(key)[1:-1]} is not allowed here; use {given}")
        head = key.replace("__", ".").split(".", 1)[0]
        (search if head in ("candidates", "paths", "decisions") else world)[key] = value
    base = SearchConfig()
    try:
        checked = override(base, world=override(base.world, **world), **search)
        checked.validate()
    except (TypeError, ValueError, AttributeError) as error:
        raise ConfigError(f"rollout.env: {clip(str(error))}") from None
    except ConfigError as error:
        raise ConfigError(f"rollout.env: {error}") from None
    if checked.world.comm.active:
        # a rollout decides for the whole team from one observation; under limited communication each
        # connected group decides from its own (areasearch.envs.goal.decide), which PPO's samples do not hold
        raise ConfigError(
            f"rollout.env: training under limited communication (comm.model {checked.world.comm.model!r}) is not "
            "supported: PPO's rollouts decide for the whole team from one observation; leave comm.model 'full' "
            "(a realism preset's communication is not applied to training) and evaluate under any communication"
        )


def training_realism(env: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The realism preset named among ``rollout.env`` and the other settings, as the training episodes
    apply them: a preset's noise, detection and mapping, but not its limited communication, unless a
    ``comm`` setting is given (which :func:`_check_env` then refuses). Centralised training: PPO's
    samples hold one observation of the team per decision, so the team shares one map while it learns;
    the policy then runs under any communication, one connected group at a time
    (:func:`areasearch.envs.goal.decide`)."""
    from ..config import realism_preset, search_key, split_realism

    realism, others = split_realism(env)
    if not isinstance(realism, str) or realism not in REALISM_NAMES:
        return realism, others  # refused by the preset's own check, naming the names
    preset_comm = realism_preset(realism).get("world.comm.model", "full")
    given = any(search_key(str(key)).startswith("world.comm") for key in others)
    if preset_comm != "full" and not given:
        others = {**others, "comm.model": "full"}
    return realism, others


def training_comm_note(config: TrainConfig) -> str | None:
    """One line saying that a preset's limited communication is not applied to the training episodes
    (:func:`training_realism`), or None when it is not the case."""
    from ..config import realism_preset, split_realism

    realism, others = split_realism(config.rollout.env)
    if training_realism(config.rollout.env)[1] == others:
        return None
    model = realism_preset(realism)["world.comm.model"]
    return (
        f"realism {realism!r}: its noise, detection and mapping apply to the training episodes, its communication "
        f"({model}) does not: the team learns with one shared map (centralised training) and the policy decides "
        "per connected group wherever it is evaluated"
    )


def _section(cls: type, data: object, name: str) -> Any:
    """A dataclass of ``cls`` from a dict: unknown keys and values of the wrong type are refused."""
    if not isinstance(data, dict):
        raise ConfigError(f"[{name}] must be a table of settings, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    default = cls()
    for key, value in data.items():
        if key not in fields:
            raise ConfigError(f"unknown setting {name}.{short(key)[1:-1]} (known: {', '.join(fields)})")
        expected = getattr(default, key)
        if isinstance(expected, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{name}.{key} must be true or false, got {short(value)}")
        elif isinstance(expected, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{name}.{key} must be a number, got {short(value)}")
            value = float(value)
        elif isinstance(expected, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{name}.{key} must be an integer, got {short(value)}")
        elif isinstance(expected, tuple):
            if not isinstance(value, list):
                raise ConfigError(f"{name}.{key} must be a list, got {short(value)}")
            kind = type(expected[0])
            if any(isinstance(v, bool) or not isinstance(v, kind) for v in value):
                raise ConfigError(f"{name}.{key} must be a list of {kind.__name__}, got {short(value)}")
            value = tuple(value)
        elif isinstance(expected, Mapping):
            if not isinstance(value, dict):
                raise ConfigError(f"{name}.{key} must be a table, got {short(value)}")
        values[key] = value
    return cls(**values)


def config_from_dict(data: object, source: str = "config") -> TrainConfig:
    """A validated :class:`TrainConfig` from the dict of a TOML/JSON file (see ``configs/``)."""
    from ..models.network_config import NetworkConfig
    from ..models.network_config import config_from_dict as network_from_dict

    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a training config must be a table of settings")
    known = {"seed", "total_decisions", "checkpoint_every", "network", "ppo", "rollout", "evaluation"}
    try:
        for key in data:
            if key not in known:
                raise ConfigError(f"unknown setting {short(key)} (known: {', '.join(sorted(known))})")
        top = _section(
            TrainConfig, {k: v for k, v in data.items() if k in ("seed", "total_decisions", "checkpoint_every")}, "top"
        )
        net_data = data.get("network", {})
        if not isinstance(net_data, dict) or not isinstance(net_data.get("graph", {}), dict):
            what = "network" if not isinstance(net_data, dict) else "network.graph"
            raise ConfigError(f"[{what}] must be a table of settings, got {short(net_data)}")
        net_data = dict(net_data)
        preset = net_data.pop("preset", "dahgnn")
        if preset not in ("dahgnn", "ncm"):
            raise ConfigError(f"network.preset must be 'dahgnn' or 'ncm', got {short(preset)}")
        base = dataclasses.asdict(NetworkConfig.ncm() if preset == "ncm" else NetworkConfig())
        graph = {**base.pop("graph"), **net_data.pop("graph", {})}
        network = network_from_dict({**base, **net_data, "graph": graph}, "network")
        config = TrainConfig(
            seed=top.seed,
            total_decisions=top.total_decisions,
            checkpoint_every=top.checkpoint_every,
            network=network,
            ppo=_section(PPOConfig, data.get("ppo", {}), "ppo"),
            rollout=_with_protocol(_without_no_realism(_section(RolloutConfig, data.get("rollout", {}), "rollout"))),
            evaluation=_section(EvalConfig, data.get("evaluation", {}), "evaluation"),
        )
        return config.validate()
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def _with_protocol(rollout: RolloutConfig) -> RolloutConfig:
    """The rollout config with the coverage protocol named in ``env`` (the default's, when not
    given), so that a run's ``config.json`` records it and a resume under another is refused."""
    from ..config import WorldConfig, search_key

    if any(search_key(str(key)) == "world.protocol" for key in rollout.env):
        return rollout
    return dataclasses.replace(rollout, env={"protocol": WorldConfig().protocol, **rollout.env})


def _without_no_realism(rollout: RolloutConfig) -> RolloutConfig:
    """The rollout config without a ``realism`` of ``none`` in ``env`` (no preset: a run's ``config.json``
    is the same with it or without it, and a resume under another preset is refused either way)."""
    from ..config import NO_REALISM, REALISM_KEY

    if rollout.env.get(REALISM_KEY) != NO_REALISM:
        return rollout
    return dataclasses.replace(rollout, env={k: v for k, v in rollout.env.items() if k != REALISM_KEY})


MAX_CONFIG_BYTES = 2**20
"""Largest training config file (TOML or JSON) read, bytes (a config is a few dozen lines)."""


def read_table(path: str | Path, what: str = "training config", max_bytes: int = MAX_CONFIG_BYTES) -> dict[str, Any]:
    """The table of a TOML file (JSON when its name ends in ``.json``: a run's ``config.json`` and
    ``checkpoint.json``). ConfigError naming the file for a path that is not a regular file (a folder,
    a named pipe: never opened), one over ``max_bytes``, bytes that are not UTF-8, text that does not
    parse, an integer longer than Python reads (4,300 digits), or a document that is not a table."""
    path = Path(path)
    if not os.path.lexists(path):
        raise ConfigError(f"{path}: cannot read the {what}: no such file")
    info = regular_file(path, what, ConfigError)
    too_big = f"{path}: {what} is larger than {max_bytes:,} bytes, the limit"
    if info.st_size > max_bytes:
        raise ConfigError(too_big)
    try:
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise ConfigError(too_big)
        text = raw.decode("utf-8")
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the {what}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: cannot read the {what}: not UTF-8 text (byte {error.start})") from None
    kind = "JSON" if path.suffix == ".json" else "TOML"
    try:
        data = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as error:
        raise ConfigError(f"{path}: not valid {kind}: {clip(str(error))}") from None
    except ValueError:  # int(): a literal over sys.get_int_max_str_digits()
        raise ConfigError(
            f"{path}: not valid {kind}: an integer longer than {sys.get_int_max_str_digits():,} digits; "
            "no setting takes one"
        ) from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a {what} must be a table of settings, got {type(data).__name__}")
    return data


def load_config(path: str | Path, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Read a training config (TOML, or JSON such as a run's ``config.json``: :func:`read_table`),
    apply dotted ``overrides`` (``{"ppo.learning_rate": 3e-4}``; ``rollout.env.<key>`` sets the
    environment setting ``<key>``, dots and all), validate."""
    path = Path(path)
    data = read_table(path)
    if data.get("format") == TRAIN_FORMAT:
        data = {k: v for k, v in data.items() if k != "format"}
    for key, value in (overrides or {}).items():
        _check_override(key, path)
        env = "rollout.env."
        *parents, leaf = ["rollout", "env", key[len(env) :]] if key.startswith(env) else key.split(".")
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


def config_differences(recorded: Mapping[str, Any], given: Mapping[str, Any]) -> list[str]:
    """The settings that differ between two configs in the form of :func:`config_to_dict` (a run's
    ``config.json`` and a config given to resume it), each as ``key (run: X, given: Y)``, in key order;
    a setting only one of them has shows ``absent`` on the other side."""

    def flat(doc: Any, prefix: str = "") -> dict[str, Any]:
        if not isinstance(doc, Mapping):
            return {prefix: doc}
        out: dict[str, Any] = {}
        for key, value in doc.items():
            name = f"{prefix}.{key}" if prefix else str(key)
            out.update(flat(value, name) if isinstance(value, Mapping) and value else {name: value})
        return out

    a, b = flat(recorded), flat(given)
    absent = object()
    keys = sorted(k for k in a.keys() | b.keys() if a.get(k, absent) != b.get(k, absent))

    def show(value: Any) -> str:
        return "absent" if value is absent else short(value, 40)

    return [f"{k} (run: {show(a.get(k, absent))}, given: {show(b.get(k, absent))})" for k in keys]
