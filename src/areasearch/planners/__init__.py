"""Pipeline stage "planner": the goal planners, classical baselines behind one interface.

A planner turns one observation of :class:`areasearch.envs.goal.AreaSearchEnv` into one candidate
index per robot: ``planner.reset(rng)`` at the start of an episode (all its randomness comes from
``rng``), then ``goals = planner.assign(obs)`` every decision, ``goals`` (R,) int64. A returned index
is one that ``obs["action_mask"]`` allows for that robot whenever the robot has any; a robot with
none gets 0 (the environment then gives it no goal). ``obs`` is never modified.

The baselines of DA-HGNN ("Baseline Methods"), each extended from exploration to area search as the
paper does (target nodes join the frontier nodes, or a frontier and a target option are weighed with
probability p_s, "Impact Analysis of Probability Setting"):

=================  =========================================================================
``random``         uniform among the allowed candidates (sanity floor)
``greedy``         nearest allowed frontier or target node (Visser et al. 2013)
``utility``        coordinated gain - lambda * distance over frontiers, nearest target with
                   p_s = 0.6 (Julia et al. 2012); ``utility-40/50/60`` the paper's Table 7
``voronoi``        nearest node of the robot's geodesic Voronoi cell (Bhattacharya et al. 2014)
``coscan``         balanced transport assignment + TSP tour per robot (Dong et al. 2019)
``hungarian``      one distinct candidate per robot at minimum total distance
``dahgnn``         the shipped, PPO-trained DA-HGNN policy (``areasearch/policies/dahgnn.*``);
                   ``dahgnn-no-type``, ``dahgnn-no-history`` (the paper's ablations) and ``ncm``
                   likewise, each registered when its weights are in the package
``dahgnn-untrained``  the DA-HGNN network with fresh weights (:mod:`.learned`);
                   ``ncm-untrained`` the NCM preset
=================  =========================================================================

``make_planner(name, **kwargs)`` builds one from the registry :data:`PLANNERS`; keyword arguments are
the planner's dataclass fields (e.g. ``make_planner("utility", p_s=0.5)``). Every learned planner takes
``weights`` of your own (``make_planner("dahgnn", weights="runs/x/policy")``); :func:`choose_planner`
is what the commands' ``--method`` / ``--weights`` pair means, weights without a method included.

Planners of other installed distributions join the registry through the entry-point group
``areasearch.planners`` (:mod:`.plugins`), found on the first look-up of a name that is not built
in; :func:`describe_planners` lists every planner with its origin (``areasearch methods``).
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable, Iterator, MutableMapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from ..errors import ConfigError
from .coscan import CoScanPlanner
from .greedy import GreedyPlanner
from .hungarian import HungarianPlanner
from .random import RandomPlanner
from .utility import UtilityPlanner
from .voronoi import VoronoiPlanner

if TYPE_CHECKING:
    from .plugins import Discovery, PlugIn


@runtime_checkable
class GoalPlanner(Protocol):
    """Chooses one long-term goal (a candidate index) per robot per decision."""

    name: str

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode; every random draw of the planner comes from ``rng``."""
        ...

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(R,) int64 candidate indices, one per robot, allowed by ``obs["action_mask"]`` (0 where a
        robot has no allowed candidate)."""
        ...


def _learned(**kwargs: Any) -> GoalPlanner:
    """A :class:`~areasearch.planners.learned.LearnedPlanner`; imported on use, so that PyTorch loads
    only when a learned planner is asked for."""
    from .learned import LearnedPlanner

    return LearnedPlanner(**kwargs)


class PlannerRegistry(MutableMapping[str, Callable[..., GoalPlanner]]):
    """Planner name -> factory: the built-in planners, then the plug-ins of other distributions
    (:mod:`.plugins`), read on the first look-up that needs them. A plug-in named like a built-in is
    not used (:attr:`shadowed`); a plug-in that fails raises its ConfigError only when built."""

    def __init__(self, builtins: dict[str, Callable[..., GoalPlanner]]) -> None:
        self.builtins = builtins
        """The built-in planners (changes to the registry go here)."""
        self._discovery: Discovery | None = None

    def discovery(self) -> Discovery:
        """The plug-ins found (:class:`.plugins.Discovery`), read on first use."""
        if self._discovery is None:
            from .plugins import discover

            self._discovery = discover(self.builtins.__contains__)
        return self._discovery

    def rediscover(self) -> None:
        """Forget the plug-ins found, so that the next look-up reads the entry points again (after
        a distribution was installed in this process's path)."""
        self._discovery = None

    def plugin(self, name: str) -> PlugIn | None:
        """The plug-in (:class:`.plugins.PlugIn`) registered as ``name``, None for a built-in or
        unknown name."""
        if not isinstance(name, str) or name in self.builtins:
            return None
        return self.discovery().plugins.get(name)

    def __getitem__(self, name: str) -> Callable[..., GoalPlanner]:
        if name in self.builtins:
            return self.builtins[name]
        plugin = self.plugin(name)
        if plugin is None:
            raise KeyError(name)
        return plugin.build

    def __contains__(self, name: object) -> bool:
        if not isinstance(name, str):
            return False
        return name in self.builtins or self.plugin(name) is not None

    def __iter__(self) -> Iterator[str]:
        yield from self.builtins
        yield from (n for n in self.discovery().plugins if n not in self.builtins)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __setitem__(self, name: str, factory: Callable[..., GoalPlanner]) -> None:
        self.builtins[name] = factory

    def __delitem__(self, name: str) -> None:
        del self.builtins[name]

    def __repr__(self) -> str:
        return f"PlannerRegistry({', '.join(self)})"


PLANNERS = PlannerRegistry(
    {
        "random": RandomPlanner,
        "greedy": GreedyPlanner,
        "utility": UtilityPlanner,
        "utility-40": partial(UtilityPlanner, p_s=0.4, name="utility-40"),
        "utility-50": partial(UtilityPlanner, p_s=0.5, name="utility-50"),
        "utility-60": partial(UtilityPlanner, p_s=0.6, name="utility-60"),
        "voronoi": VoronoiPlanner,
        "coscan": CoScanPlanner,
        "hungarian": HungarianPlanner,
        "dahgnn-untrained": lambda **kwargs: _learned(name="dahgnn-untrained", **kwargs),
        "ncm-untrained": lambda **kwargs: _learned(preset="ncm", name="ncm-untrained", **kwargs),
    }
)
"""Registry: planner name -> factory taking the planner's settings as keyword arguments; the
built-in planners first, then the plug-ins (:class:`PlannerRegistry`)."""

POLICY_DIR = Path(__file__).resolve().parent.parent / "policies"
"""Where the shipped policies live: ``<name>.safetensors`` + ``<name>.json`` (see ``configs/<name>.toml``)."""

SHIPPED_POLICIES = ("dahgnn", "dahgnn-no-type", "dahgnn-no-history", "ncm")
"""Trained policies registered under their own name when their files are in :data:`POLICY_DIR`."""


def shipped_policy(name: str) -> Path:
    """Path prefix of the shipped policy ``name`` (``prefix.safetensors`` + ``prefix.json``)."""
    return POLICY_DIR / name


UNTRAINED = ("dahgnn-untrained", "ncm-untrained")
"""The learned planners' networks with fresh weights (references for tests and comparisons)."""

LEARNED = (*SHIPPED_POLICIES, *UNTRAINED)
"""The built-in learned planners: each takes ``weights`` of your own."""

DEFAULT_METHOD = "greedy"
"""The planner of a command given neither ``--method`` nor ``--weights``."""

DESCRIPTIONS = {
    "random": "uniform among the allowed candidates (a sanity floor)",
    "greedy": "nearest allowed frontier or target node (Visser et al. 2013)",
    "utility": "coordinated information gain minus distance over frontiers, nearest target with p_s = 0.6 "
    "(Julia et al. 2012)",
    "utility-40": "utility with p_s = 0.4 (the paper's Table 7)",
    "utility-50": "utility with p_s = 0.5 (the paper's Table 7)",
    "utility-60": "utility with p_s = 0.6 (the paper's Table 7)",
    "voronoi": "nearest node of the robot's geodesic Voronoi cell (Bhattacharya et al. 2014)",
    "coscan": "balanced transport assignment and a TSP tour per robot (Dong et al. 2019)",
    "hungarian": "one distinct candidate per robot at minimum total distance",
    "dahgnn": "the shipped PPO-trained DA-HGNN policy",
    "dahgnn-no-type": "the shipped DA-HGNN ablation without node types",
    "dahgnn-no-history": "the shipped DA-HGNN ablation without the history",
    "ncm": "the shipped PPO-trained NCM policy (Ye et al., CVPR 2022)",
    "dahgnn-untrained": "the DA-HGNN network with fresh weights (a reference)",
    "ncm-untrained": "the NCM network with fresh weights (a reference)",
}
"""One line per built-in planner (``areasearch methods``, the service's ``GET /methods``)."""


def _shipped(name: str) -> Callable[..., GoalPlanner]:
    def factory(weights: str | os.PathLike[str] | None = None, **kwargs: Any) -> GoalPlanner:
        """The shipped policy ``name``, or the same method with ``weights`` of your own."""
        return _learned(weights=str(shipped_policy(name)) if weights is None else weights, name=name, **kwargs)

    return factory


for _name in SHIPPED_POLICIES:
    if shipped_policy(_name).with_suffix(".safetensors").is_file():
        PLANNERS[_name] = _shipped(_name)


def takes_weights(name: str) -> bool:
    """Whether the planner ``name`` takes ``weights``: the built-in learned planners, and any other
    planner whose factory has a ``weights`` parameter (a broken plug-in raises its ConfigError)."""
    if name in LEARNED:
        return True
    plugin = PLANNERS.plugin(name)
    if plugin is not None:
        return plugin.takes("weights")
    factory = PLANNERS.builtins.get(name)
    try:
        param = inspect.signature(factory).parameters.get("weights") if factory is not None else None
    except (TypeError, ValueError):  # a factory whose signature Python cannot tell
        return False
    return param is not None and param.kind in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY)


def check_takes_weights(name: str) -> None:
    """ConfigError unless the planner ``name`` takes ``weights`` (:func:`takes_weights`)."""
    if not takes_weights(name):
        raise _not_learned(name)


def _not_learned(name: str) -> ConfigError:
    return ConfigError(
        f"planner {name!r} takes no weights: --weights (weights=...) is for a learned planner "
        f"({', '.join(LEARNED)}, or a plug-in whose factory takes weights); give --weights without "
        "--method for the network the weights describe"
    )


def make_planner(name: str, **kwargs: object) -> GoalPlanner:
    """The planner registered as ``name``, built with ``kwargs``; ConfigError for an unknown name or
    setting, for ``weights`` given to a planner that is not learned, and for a plug-in that fails
    (naming it and its distribution). ``weights=None`` is the same as no weights."""
    if not isinstance(name, str):
        raise ConfigError(f"a planner name must be a string, got {type(name).__name__}")
    if kwargs.get("weights", "") is None:
        kwargs.pop("weights")
    if name not in PLANNERS and name in SHIPPED_POLICIES:
        if "weights" in kwargs:  # your own weights of a method this installation does not ship
            return _learned(name=name, **kwargs)
        raise ConfigError(
            f"planner {name!r} is a learned policy that this installation does not ship; train it with "
            f"'areasearch train --config configs/{name}.toml --out runs/{name}' and pass "
            f"weights='runs/{name}/policy' to the learned planner (--weights runs/{name}/policy)"
        )
    if name not in PLANNERS:
        raise ConfigError(
            f"unknown planner {name!r}; known planners: {', '.join(sorted(PLANNERS))} (areasearch methods lists them)"
        )
    if "weights" in kwargs:
        check_takes_weights(name)
    plugin = PLANNERS.plugin(name)
    if plugin is not None:
        return plugin.build(**kwargs)
    factory = PLANNERS[name]
    try:
        inspect.signature(factory).bind(**kwargs)
    except TypeError as err:
        raise ConfigError(f"planner {name!r}: {err}") from None
    try:
        return factory(**kwargs)
    except TypeError as err:  # a lazily built planner checks its settings only now
        raise ConfigError(f"planner {name!r}: {err}") from None


@dataclass(frozen=True)
class Choice:
    """A planner as a command's ``--method`` and ``--weights`` name it."""

    method: str
    """The method's name in answers and reports."""
    planner: GoalPlanner
    weights: str | None = None
    """The weights given (a path prefix), None for the method's own."""
    weights_sha256: str | None = None
    """SHA-256 of the weights given (``<weights>.safetensors``), when the planner names it."""

    def record(self) -> dict[str, str]:
        """``{"weights": ..., "weights_sha256": ...}`` for weights given, else empty: what an answer
        or summary adds after the method."""
        if self.weights is None:
            return {}
        return {"weights": self.weights, **({"weights_sha256": self.weights_sha256} if self.weights_sha256 else {})}


def choose_planner(method: str | None = None, weights: str | os.PathLike[str] | None = None, **settings: Any) -> Choice:
    """The planner of ``--method`` and ``--weights``: ``method`` (default :data:`DEFAULT_METHOD`);
    with ``weights``, that learned method playing them (a method that is not learned: ConfigError);
    ``weights`` without a method, the network they describe, named after its architecture
    (:func:`.learned.architecture_name`: ``dahgnn``, ``ncm``, ``dahgnn-no-type``...). Missing or
    damaged weights: ConfigError naming the file."""
    if weights is None:
        name = DEFAULT_METHOD if method is None else method
        return Choice(name, make_planner(name, **settings))
    if not isinstance(weights, (str, os.PathLike)) or not os.fspath(weights):
        raise ConfigError(f"weights must be a path prefix (PREFIX.safetensors + PREFIX.json), got {weights!r}")
    given = os.fspath(weights)
    if method is None:
        from .learned import LearnedPlanner, architecture_name

        try:
            learned = LearnedPlanner(weights=given, **settings)
        except TypeError as err:
            raise ConfigError(f"learned planner: {err}") from None
        learned.name = architecture_name(learned.config)
        return Choice(learned.name, learned, given, learned.weights_sha256)
    planner = make_planner(method, weights=given, **settings)
    sha = getattr(planner, "weights_sha256", None)
    return Choice(method, planner, given, sha if isinstance(sha, str) else None)


def describe_planners(check_plugins: bool = True) -> list[dict[str, Any]]:
    """Every planner with its origin, for ``areasearch methods`` and ``GET /methods``: ``name``,
    ``kind`` (classical, learned, plug-in), ``origin`` (built-in classical, shipped learned policy,
    untrained network, ``plug-in <distribution> <version>``), ``description``; a shipped policy's
    ``weights`` and ``weights_sha256``; a plug-in's ``entry_point`` and, with ``check_plugins`` (it is
    imported and built once), ``status`` ok or broken with its ``error``. A shipped policy whose files
    are missing, a plug-in shadowed by a built-in or not named as a planner, and entry points that
    cannot be read are listed too, with their ``error``."""
    from .learned import weights_sha256

    rows: list[dict[str, Any]] = []
    for name in PLANNERS.builtins:
        row: dict[str, Any] = {"name": name, "kind": "classical", "origin": "built-in classical"}
        if name in SHIPPED_POLICIES:
            row.update(kind="learned", origin="shipped learned policy", weights=str(shipped_policy(name)))
            row["weights_sha256"] = weights_sha256(shipped_policy(name))
        elif name in UNTRAINED:
            row.update(kind="learned", origin="untrained network")
        rows.append({**row, "description": DESCRIPTIONS.get(name, "a built-in goal planner"), "status": "ok"})
    for name in SHIPPED_POLICIES:
        if name not in PLANNERS.builtins:
            rows.append({
                "name": name, "kind": "learned", "origin": "shipped learned policy", "status": "not installed",
                "description": DESCRIPTIONS.get(name, ""),
                "error": f"not in this installation; train it (configs/{name}.toml) and give --weights",
            })  # fmt: skip
    found = PLANNERS.discovery()
    for plugin in found.plugins.values():
        row = {"name": plugin.name, "kind": "plug-in", "origin": plugin.origin, "entry_point": plugin.value}
        error = plugin.check() if check_plugins else plugin.problem
        doc = plugin.loaded_doc() if error is None else None
        row["description"] = doc.strip().splitlines()[0] if doc else f"a goal planner of {plugin.distribution}"
        row["status"] = "ok" if error is None else "broken"
        if error is not None:
            row["error"] = error
        elif not check_plugins:
            row["status"] = "not checked"
        rows.append(row)
    for plugin, why in [(p, "shadowed") for p in found.shadowed] + [(p, "invalid") for p in found.invalid]:
        error = (
            f"not used: {plugin.name!r} is a built-in planner, which wins"
            if why == "shadowed"
            else f"not used: {plugin.problem}"
        )
        rows.append({
            "name": plugin.name, "kind": "plug-in", "origin": plugin.origin, "entry_point": plugin.value,
            "description": "", "status": "ignored", "error": error,
        })  # fmt: skip
    if found.error is not None:
        rows.append({"name": "", "kind": "plug-in", "origin": "entry points", "status": "broken", "error": found.error})
    return rows


__all__ = [
    "DEFAULT_METHOD",
    "DESCRIPTIONS",
    "LEARNED",
    "PLANNERS",
    "POLICY_DIR",
    "SHIPPED_POLICIES",
    "UNTRAINED",
    "Choice",
    "CoScanPlanner",
    "GoalPlanner",
    "GreedyPlanner",
    "HungarianPlanner",
    "PlannerRegistry",
    "RandomPlanner",
    "UtilityPlanner",
    "VoronoiPlanner",
    "check_takes_weights",
    "choose_planner",
    "describe_planners",
    "make_planner",
    "shipped_policy",
    "takes_weights",
]
