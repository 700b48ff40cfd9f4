"""What an evaluation is asked to do: :class:`EvalPlan`, one frozen object built at the edge (the
command line's ``areasearch eval``, or a Python caller) and handed to
:func:`areasearch.harness.evaluate.evaluate`; the checks of its arguments (:func:`check_plan`) and
the record of the settings its episodes depend on (:func:`run_config`, a results folder's
``config.json``).

The world of every episode travels as a typed :class:`~areasearch.config.SearchConfig`
(:attr:`EvalPlan.config`, the coverage protocol one of its fields); :attr:`EvalPlan.settings` keeps the
settings as they were given and :attr:`EvalPlan.realism` the name of the realism preset under them, which
is what ``config.json`` and the summary record.
"""

from __future__ import annotations

import dataclasses
import json
import socket
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..config import (
    MAX_ROBOTS,
    NO_REALISM,
    SearchConfig,
    WorldConfig,
    override,
    realism_settings,
    search_config,
    search_settings,
)
from ..errors import AreaSearchError, ConfigError
from ..planners import PLANNERS, SHIPPED_POLICIES, make_planner
from ..runners import BACKENDS
from ..sim.scene import SIZE_CLASSES

RUN_FORMAT = "areasearch-eval/2"

FIELDS_RECORDED_WHEN_SET = (("candidates", "distance_cell_m"),)
"""Settings added after the results format: ``config.json`` holds them only when they differ from their
defaults, so that a folder written before they existed resumes under the defaults (same episodes)."""

RESERVED_SETTINGS = {"world.num_robots": "robots", "world.max_steps": "max_steps"}
"""World settings that an evaluation takes as arguments of their own, not as ``settings``."""


@dataclass(frozen=True)
class EvalPlan:
    """An evaluation as asked for: every (map, team size, episode index) played by every method.

    Built once at the edge; :func:`areasearch.harness.evaluate.evaluate` checks it
    (:func:`check_plan`) before anything is written."""

    methods: Sequence[str]
    """Planner names (:data:`areasearch.planners.PLANNERS`, or a name of :attr:`policies`)."""
    robots: Sequence[int]
    """Team sizes, 1 to :data:`~areasearch.config.MAX_ROBOTS`."""
    maps: Sequence[str]
    """Map specs (:func:`areasearch.harness.episodes.resolve_maps`)."""
    episodes: int
    """Episodes per (map, team size)."""
    seed: int
    """The run seed; episode seeds derive from it (:func:`areasearch.harness.episodes.episode_seed`)."""
    max_steps: int
    """Horizon of every episode, primitive steps."""
    out: str | Path
    """The results folder (created; an existing one is resumed)."""
    config: SearchConfig = field(default_factory=SearchConfig)
    """The world of every episode (its team size and horizon are set per episode): the :attr:`realism`
    preset and :attr:`settings` over it applied."""
    settings: tuple[tuple[str, Any], ...] = ()
    """The world settings as given (:func:`areasearch.config.search_settings` keys and values, sorted),
    recorded in ``config.json`` and the summary; :meth:`with_settings` sets both them and :attr:`config`."""
    realism: str = NO_REALISM
    """The realism preset of every episode (:data:`areasearch.config.REALISM_PRESETS`), under
    :attr:`settings` (a setting given wins over the preset's value); recorded in ``config.json`` unless
    ``none``."""
    policies: Mapping[str, str] = field(default_factory=dict)
    """Learned methods given by their weights: name -> path prefix (``--policy NAME=PREFIX``)."""
    sizes: Sequence[str] | None = None
    """Only the maps of these size classes."""
    maps_per_size: int | None = None
    """That many maps per size class, evenly spaced in id order."""
    workers: int = 1
    """Worker processes (``local``), or CPUs of a local Ray instance (``ray``)."""
    backend: str = "local"
    """:data:`areasearch.runners.BACKENDS`: local processes or Ray tasks."""
    address: str | None = None
    """With the ``ray`` backend: the address of an existing Ray cluster (None: start a local one)."""
    replace: Sequence[str] = ()
    """Methods with weights (a shipped policy, or a name of :attr:`policies`) to play again where
    :attr:`out` holds their episodes played with other weights than now, or with weights it has no
    record of: their old episodes move to ``out/replaced/N/`` (:func:`areasearch.harness.records.set_aside`)."""

    def with_settings(self, settings: Mapping[str, Any] | None, realism: str = NO_REALISM) -> EvalPlan:
        """This plan with the world ``settings`` of every episode (``--set``; keys as
        :func:`areasearch.config.search_settings` takes them) over the preset ``realism``: recorded as
        given and applied to :attr:`config`. ConfigError names an unknown key or preset, or a key that the
        plan takes as an argument of its own (``robots``, ``max_steps``); a bad value is refused by
        :func:`evaluate`, after the other arguments are checked."""
        given = search_settings(settings or {})
        for key, argument in RESERVED_SETTINGS.items():
            if key in given:
                raise ConfigError(f"setting {key} is set by the {argument} argument, not among the settings")
        # its values are checked with the other arguments (run_config)
        config = override(SearchConfig(), **realism_settings(realism, given))
        return dataclasses.replace(self, settings=tuple(given.items()), realism=realism, config=config)


def check_plan(plan: EvalPlan) -> None:
    """ConfigError (one message) for an argument of ``plan`` that no evaluation takes, in the order
    the command line lists them; nothing is read from the output folder or the maps here."""
    _check_methods(plan.methods, plan.policies)
    robots = plan.robots
    if not robots:
        raise ConfigError("no team sizes given")
    for r in robots:
        if isinstance(r, bool) or not isinstance(r, int) or not 1 <= r <= MAX_ROBOTS:
            raise ConfigError(f"robots must be from 1 to {MAX_ROBOTS}, got {r!r}")
    if len(set(robots)) != len(robots):
        raise ConfigError(f"a team size is listed twice: {' '.join(map(str, robots))}")
    counts = (("episodes", plan.episodes), ("max-steps", plan.max_steps), ("workers", plan.workers))
    for name, value in counts:
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    seed = plan.seed
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    per_size = plan.maps_per_size
    if per_size is not None and (isinstance(per_size, bool) or per_size < 1):
        raise ConfigError(f"maps-per-size must be an integer >= 1, got {per_size!r}")
    for size in plan.sizes or ():
        if size not in SIZE_CLASSES:
            raise ConfigError(f"unknown size class {size!r}; use {', '.join(SIZE_CLASSES)}")
    _check_backend(plan.backend, plan.address)
    _check_replace(plan.replace, plan.methods, plan.policies)


def _check_replace(replace: Sequence[str], methods: Sequence[str], policies: Mapping[str, str]) -> None:
    for name in replace:
        if name not in methods:
            raise ConfigError(f"--replace {name}: add {name} to --methods to play it again")
        if name not in policies and name not in SHIPPED_POLICIES:
            raise ConfigError(
                f"--replace {name}: only a method with weights (a shipped policy or a --policy name) is played "
                f"again in a results folder; {name} has none: evaluate it into another --out folder"
            )
    if len(set(replace)) != len(replace):
        raise ConfigError(f"a method is listed twice in --replace: {' '.join(replace)}")


def _check_methods(methods: Sequence[str], policies: Mapping[str, str]) -> None:
    if not methods:
        raise ConfigError("no methods given")
    unknown = [m for m in methods if m not in PLANNERS and m not in policies]
    if unknown:
        raise ConfigError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(PLANNERS)}")
    for method in methods:
        if method not in policies and PLANNERS.plugin(method) is not None:
            make_planner(method)  # a plug-in that fails: its one error now, before any episode
    if len(set(methods)) != len(methods):
        raise ConfigError(f"a method is listed twice: {' '.join(methods)}")


def _check_backend(backend: str, address: str | None) -> None:
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if address is not None and backend != "ray":
        raise ConfigError("--address is for --backend ray (the address of a Ray cluster)")
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ConfigError(f"address must be a Ray cluster address such as 10.0.0.5:6379, got {address!r}")
    if backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError("--backend ray needs Ray: pip install 'areasearch[ray]'") from None
        if address is not None:
            check_ray_address(address)


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """AreaSearchError unless a TCP connection to the ``host:port`` of a Ray address (``host:port`` or
    ``ray://host:port``; ``auto`` is left to Ray) opens within ``timeout_s``: Ray itself keeps retrying
    an unreachable address for minutes."""
    if address == "auto":
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--address must be host:port or ray://host:port (or auto), got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise AreaSearchError(f"--address {address}: no Ray cluster reachable there ({exc})") from None


def run_config(plan: EvalPlan) -> dict[str, Any]:
    """What ``config.json`` holds: the settings every episode's numbers depend on besides its key:
    the run seed, the horizon, the realism preset (``realism``, only when not ``none``), the world
    settings given (``settings``, only when there are any), the resolved configuration (its ``noise``,
    ``detection``, ``comm`` and ``mapping`` groups and the :data:`FIELDS_RECORDED_WHEN_SET` only when
    they differ from the defaults: the record of a noise-free run with full communication holds none of
    them). ConfigError names a bad value of the settings or preset, or says that :attr:`EvalPlan.config`
    is not its settings applied (the record would not say what was played)."""
    given = dict(plan.settings)
    for key, argument in RESERVED_SETTINGS.items():
        if key in given:
            raise ConfigError(f"setting {key} is set by the {argument} argument, not among the settings")
    played = realism_settings(plan.realism, given)  # ConfigError naming the presets for an unknown one
    recorded = search_config({**played, "world.max_steps": plan.max_steps})  # ConfigError naming a bad value
    world = dataclasses.replace(plan.config.world, max_steps=plan.max_steps)
    if dataclasses.replace(plan.config, world=world) != recorded:
        raise ConfigError("the plan's config is not its settings applied; build both with EvalPlan.with_settings")
    config = dataclasses.asdict(recorded)
    del config["world"]["num_robots"]  # set per episode
    for group in ("noise", "detection", "comm", "mapping"):  # recorded only when set
        if getattr(recorded.world, group) == getattr(WorldConfig(), group):
            del config["world"][group]
    for section, name in FIELDS_RECORDED_WHEN_SET:
        if config[section][name] == getattr(getattr(SearchConfig(), section), name):
            del config[section][name]
    record = {
        "format": RUN_FORMAT,
        "seed": plan.seed,
        "max_steps": plan.max_steps,
        **({"realism": plan.realism} if plan.realism != NO_REALISM else {}),
        **({"settings": given} if given else {}),
    }
    record["config"] = config
    return dict(json.loads(json.dumps(record)))  # as it reads back from config.json
