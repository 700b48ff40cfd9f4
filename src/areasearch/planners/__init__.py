"""Pipeline stage "planner": the goal planners, classical baselines behind one interface.

A planner turns one observation of :class:`areasearch.goal_env.AreaSearchEnv` into one candidate
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
the planner's dataclass fields (e.g. ``make_planner("utility", p_s=0.5)``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..errors import ConfigError
from .coscan import CoScanPlanner
from .greedy import GreedyPlanner
from .hungarian import HungarianPlanner
from .random import RandomPlanner
from .utility import UtilityPlanner
from .voronoi import VoronoiPlanner


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


PLANNERS: dict[str, Callable[..., GoalPlanner]] = {
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
"""Registry: planner name -> factory taking the planner's settings as keyword arguments."""

POLICY_DIR = Path(__file__).resolve().parent.parent / "policies"
"""Where the shipped policies live: ``<name>.safetensors`` + ``<name>.json`` (see ``configs/<name>.toml``)."""

SHIPPED_POLICIES = ("dahgnn", "dahgnn-no-type", "dahgnn-no-history", "ncm")
"""Trained policies registered under their own name when their files are in :data:`POLICY_DIR`."""


def shipped_policy(name: str) -> Path:
    """Path prefix of the shipped policy ``name`` (``prefix.safetensors`` + ``prefix.json``)."""
    return POLICY_DIR / name


def _shipped(name: str) -> Callable[..., GoalPlanner]:
    def factory(**kwargs: Any) -> GoalPlanner:
        return _learned(weights=str(shipped_policy(name)), name=name, **kwargs)

    return factory


for _name in SHIPPED_POLICIES:
    if shipped_policy(_name).with_suffix(".safetensors").is_file():
        PLANNERS[_name] = _shipped(_name)


def make_planner(name: str, **kwargs: object) -> GoalPlanner:
    """The planner registered as ``name``, built with ``kwargs``; ConfigError for an unknown name or
    setting."""
    if name not in PLANNERS and name in SHIPPED_POLICIES:
        raise ConfigError(
            f"planner {name!r} is a learned policy that this installation does not ship; train it with "
            f"'areasearch train --config configs/{name}.toml --out runs/{name}' and pass "
            f"weights='runs/{name}/policy' to the learned planner (--weights runs/{name}/policy)"
        )
    if name not in PLANNERS:
        raise ConfigError(f"unknown planner {name!r}; known planners: {', '.join(sorted(PLANNERS))}")
    factory = PLANNERS[name]
    try:
        inspect.signature(factory).bind(**kwargs)
    except TypeError as err:
        raise ConfigError(f"planner {name!r}: {err}") from None
    try:
        return factory(**kwargs)
    except TypeError as err:  # a lazily built planner checks its settings only now
        raise ConfigError(f"planner {name!r}: {err}") from None


__all__ = [
    "PLANNERS",
    "POLICY_DIR",
    "SHIPPED_POLICIES",
    "CoScanPlanner",
    "GoalPlanner",
    "GreedyPlanner",
    "HungarianPlanner",
    "RandomPlanner",
    "UtilityPlanner",
    "VoronoiPlanner",
    "make_planner",
    "shipped_policy",
]
