"""What a played episode is: the records the rollouts write and the PPO update reads.

An :class:`EpisodeSpec` says which episode to play (map, team size, seed, horizon, the world's
:class:`~areasearch.config.SearchConfig`); a :class:`Trajectory` is what playing it with the policy
recorded. The rollouts (:mod:`areasearch.training.rollout`) make them and the update
(:mod:`areasearch.training.ppo`) consumes them, so they live here, below both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import SearchConfig


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: everything its outcome depends on besides the weights."""

    map: str
    robots: int
    seed: int
    max_steps: int
    env: SearchConfig = field(default_factory=SearchConfig)
    """The environment's config (the training config's ``rollout.env`` applied to the defaults by
    :func:`areasearch.config.search_config`); the team size and the horizon are the fields above."""
    deterministic: bool = False
    """Evaluation-time goals (assignment on S) instead of sampling."""


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
