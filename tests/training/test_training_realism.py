"""A realism preset in training: its noise, detection and mapping apply to the training episodes, its
limited communication does not (centralised training), and an explicit ``comm`` setting is refused."""

from __future__ import annotations

import pytest

from areasearch.config import REALISM_NAMES, realism_config
from areasearch.errors import ConfigError
from areasearch.training.config import TrainConfig, config_from_dict, training_comm_note, training_realism
from areasearch.training.rollout import episode_env


def _config(env: dict[str, object]) -> TrainConfig:
    return config_from_dict({"rollout": {"env": env}}, "test")


@pytest.mark.parametrize("preset", [name for name in REALISM_NAMES if name != "none"])
def test_a_presets_noise_applies_and_its_communication_stays_full(preset: str) -> None:
    env = episode_env(_config({"realism": preset}))
    world = realism_config(preset).world
    assert world.comm.active  # every preset but none limits communication...
    assert not env.world.comm.active and env.world.comm.model == "full"  # ...which training leaves full
    assert env.world.noise == world.noise
    assert env.world.detection == world.detection
    assert env.world.mapping == world.mapping
    note = training_comm_note(_config({"realism": preset}))
    assert note is not None and note.startswith(f"realism {preset!r}: its noise, detection and mapping apply")


def test_no_preset_and_no_change_without_one() -> None:
    assert training_realism({"noise.forward": 0.1}) == ("none", {"noise.forward": 0.1})
    assert training_comm_note(_config({"noise.forward": 0.1})) is None
    assert training_comm_note(_config({"realism": "none"})) is None
    assert episode_env(_config({})) == realism_config("none")


@pytest.mark.parametrize("key", ["comm.model", "comm__model"])
def test_an_explicit_comm_setting_is_refused_not_replaced(key: str) -> None:
    with pytest.raises(ConfigError, match=r"training under limited communication \(comm.model 'disc'\)"):
        _config({"realism": "high", key: "disc"})
    assert training_realism({"realism": "high", key: "full"}) == ("high", {key: "full"})
