"""The import paths users write keep working wherever the code lives (the README's and the docs')."""

from __future__ import annotations

import importlib.metadata

import gymnasium

import areasearch


def test_public_shims_are_the_real_objects() -> None:
    from areasearch.assign import assign_goals, load_occupancy
    from areasearch.envs.goal import AreaSearchEnv as RealEnv
    from areasearch.envs.goal import nearest_candidate as real_nearest
    from areasearch.goal_env import AreaSearchEnv, nearest_candidate
    from areasearch.service import assign as service_assign

    assert assign_goals is service_assign.assign_goals
    assert load_occupancy is service_assign.load_occupancy
    assert AreaSearchEnv is RealEnv and nearest_candidate is real_nearest


def test_root_api_and_gymnasium_id() -> None:
    from areasearch.envs.goal import AreaSearchEnv

    spec = gymnasium.spec(areasearch.GOAL_ENV_ID)
    assert spec.entry_point == "areasearch.envs.goal:AreaSearchEnv"
    env = gymnasium.make(areasearch.GOAL_ENV_ID, map="robotathome_sarmis", num_robots=2)
    assert isinstance(env.unwrapped, AreaSearchEnv)
    env.close()
    assert callable(areasearch.parallel_env) and callable(areasearch.env)


def test_one_version_source() -> None:
    assert areasearch.__version__ == importlib.metadata.version("areasearch")
