"""Fixtures of the training tests: trajectories written by hand, to check the returns and advantages
computed from them."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from areasearch.training.trajectory import EpisodeSpec, Trajectory

HandTrajectory = Callable[..., Trajectory]


@pytest.fixture
def hand_trajectory() -> HandTrajectory:
    """A function that makes a trajectory of 2 robots from its rewards, values, end and last value:
    ``hand_trajectory(rewards, values, terminated, last_value, spec, steps, covered_curve)``; its
    ``info["steps"]`` is the spec's horizon, every other per-decision array zeros."""

    def make(
        rewards: list[float],
        values: list[float],
        terminated: bool,
        last_value: float,
        spec: EpisodeSpec,
        steps: list[int],
        covered_curve: list[float],
    ) -> Trajectory:
        n = len(rewards)
        return Trajectory(
            spec,
            [{}] * n,
            [np.zeros(2, np.int64)] * n,
            np.zeros(n, np.float32),
            np.array(values, np.float32),
            np.array(rewards, np.float32),
            np.zeros(n, np.float32),
            terminated,
            last_value,
            {"steps": spec.max_steps},
            steps,
            covered_curve,
            0.0,
        )

    return make
