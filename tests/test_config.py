"""``--set KEY=VALUE`` settings (:func:`areasearch.config.parse_settings`) and the world settings they
make (:func:`areasearch.config.search_settings`, :func:`areasearch.config.search_config`)."""

from __future__ import annotations

import re

import pytest

from areasearch.config import SearchConfig, parse_settings, search_config, search_key, search_settings
from areasearch.errors import ConfigError


def test_values_are_read_as_json_else_as_text() -> None:
    pairs = ["a=1", "b=0.5", "c=true", "d=[3, 4]", "e=passby", "f=null", "g= 2 ", "a=2", "h=x=y"]
    assert parse_settings(pairs) == {"a": 2, "b": 0.5, "c": True, "d": [3, 4], "e": "passby", "f": None, "g": 2,
                                     "h": "x=y"}  # fmt: skip


@pytest.mark.parametrize("pair", ["robot.radius_m", "=0.2", "robot.radius_m=", "robot.radius_m=  ", "a b=1"])
def test_a_malformed_pair_is_refused_naming_it(pair: str) -> None:
    with pytest.raises(ConfigError, match="^" + re.escape(f"--set {pair!r}: expected KEY=VALUE")):
        parse_settings([pair])


@pytest.mark.parametrize("text", ["nan", "NaN", "-inf", "+Infinity", "inf", "1e999", "[1, NaN]", "Infinity"])
def test_a_non_finite_number_is_refused_naming_the_pair(text: str) -> None:
    with pytest.raises(ConfigError, match="^" + re.escape(f"--set 'x.y={text}': x.y must be a finite number")):
        parse_settings([f"x.y={text}"])


def test_keys_take_every_form_of_the_world_and_search_settings() -> None:
    assert search_key("robot.radius_m") == search_key("world.robot.radius_m") == "world.robot.radius_m"
    assert search_key("robot__radius_m") == "world.robot.radius_m"
    assert search_key("paths.max_bumps") == "paths.max_bumps"
    given = {"targets.count": 5, "world.robot.radius_m": 1, "paths.max_bumps": 3, "camera__width_px": 32}
    assert search_settings(given) == {
        "paths.max_bumps": 3,
        "world.camera.width_px": 32,
        "world.robot.radius_m": 1.0,  # a float field: as a float, so that config.json reads the same
        "world.targets.count": 5,
    }
    config = search_config(given)
    assert config.world.targets.count == 5 and config.world.robot.radius_m == 1.0 and config.paths.max_bumps == 3
    assert search_config() == SearchConfig().validate()


@pytest.mark.parametrize(
    ("key", "message"),
    [
        ("robot.wheels", "unknown setting 'robot.wheels'; known settings: robot.radius_m, robot.height_m"),
        ("wheels", "unknown setting 'wheels'; known settings: num_robots, max_steps"),
        ("paths.speed", "unknown setting 'paths.speed'; known settings: paths.goal_tolerance_m"),
        ("max_steps.x", "unknown setting 'max_steps.x': max_steps is a single setting, with no fields"),
        ("robot", "setting 'robot' is a group of settings; set one of its fields: robot.radius_m"),
    ],
)
def test_an_unknown_key_is_one_error_naming_it(key: str, message: str) -> None:
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        search_settings({key: 1})


def test_a_bad_value_is_refused_by_the_config() -> None:
    with pytest.raises(ConfigError, match=r"robot\.radius_m must be a positive number"):
        search_config({"robot.radius_m": -1})
    with pytest.raises(ConfigError, match=r"targets\.count must be an integer"):
        search_config({"targets.count": "many"})


def test_env_config_turns_both_environments_keyword_forms_into_one_typed_config() -> None:
    from areasearch.config import SearchConfig, WorldConfig, env_config

    dotted = env_config(WorldConfig(), 2, {"protocol": "passby", "camera.width_px": 96})
    dunder = env_config(WorldConfig(), 2, {"protocol": "passby", "camera__width_px": 96})
    assert dotted == dunder and dotted.num_robots == 2 and dotted.camera.width_px == 96
    assert dotted.protocol == "passby"
    search = env_config(SearchConfig(), 4, {"protocol": "passby", "decisions.period_steps": 20, "max_steps": 80})
    assert search.world.num_robots == 4 and search.world.max_steps == 80 and search.world.protocol == "passby"
    assert search.decisions.period_steps == 20
    with pytest.raises(ConfigError, match=re.escape("unknown setting 'decisions.period_steps' for WorldConfig")):
        env_config(WorldConfig(), 2, {"decisions.period_steps": 20})  # the PettingZoo world has no decisions
    with pytest.raises(ConfigError, match="protocol must be one of 'paper', 'passby'"):
        env_config(SearchConfig(), 2, {"protocol": "nope"})
