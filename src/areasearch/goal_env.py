"""The Gymnasium goal environment: the public import path of :mod:`areasearch.envs.goal`.

``gymnasium.make("areasearch/AreaSearch-v0", ...)`` builds :class:`AreaSearchEnv`;
``from areasearch.goal_env import nearest_candidate`` is what the README uses.
"""

from __future__ import annotations

from .envs.goal import AreaSearchEnv, nearest_candidate

__all__ = ["AreaSearchEnv", "nearest_candidate"]
