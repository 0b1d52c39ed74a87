"""OMPNConfig validation and JSON round trip."""

from __future__ import annotations

import json

import pytest

from ompn_ros.model.config import CONFIG_VERSION, OMPNConfig
from ompn_ros.model.errors import ConfigError


def test_round_trip_dict_and_json() -> None:
    cfg = OMPNConfig(
        obs_dim=39,
        action_type="continuous",
        action_dim=9,
        n_slots=2,
        slot_size=64,
        sketch_mode="sum",
        sketch_vocab=10,
        memory_update="code",
        no_top_down=True,
    )
    assert OMPNConfig.from_dict(cfg.to_dict()) == cfg
    assert OMPNConfig.from_json(cfg.to_json()) == cfg
    assert json.loads(cfg.to_json())["version"] == CONFIG_VERSION


def test_defaults_follow_the_paper() -> None:
    cfg = OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5)
    assert (cfg.n_slots, cfg.slot_size, cfg.memory_update, cfg.action_variance) == (3, 128, "paper", 0.6)
    assert cfg.n_actions_with_done == 6


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"obs_dim": 0}, "obs_dim must be a positive int"),
        ({"action_dim": -1}, "action_dim must be a positive int"),
        ({"n_slots": 2.5}, "n_slots must be a positive int"),
        ({"action_type": "multi"}, "action_type must be 'discrete' or 'continuous'"),
        ({"sketch_mode": "gru"}, "sketch_mode must be 'none' or 'sum'"),
        ({"sketch_mode": "sum"}, "needs sketch_vocab > 0"),
        ({"sketch_vocab": 3}, "only meaningful with sketch_mode='sum'"),
        ({"memory_update": "buggy"}, "memory_update must be 'paper' or 'code'"),
        ({"no_top_down": 1}, "no_top_down must be a bool"),
        ({"action_variance": 0.0}, "action_variance must be > 0"),
        ({"version": 99}, "version 99 is not supported"),
    ],
)
def test_invalid_fields_raise_actionable_errors(kwargs: dict, message: str) -> None:
    base = {"obs_dim": 10, "action_type": "discrete", "action_dim": 5}
    with pytest.raises(ConfigError, match=message):
        OMPNConfig(**{**base, **kwargs})


def test_from_dict_rejects_unknown_missing_and_wrong_version() -> None:
    good = OMPNConfig(obs_dim=10, action_type="discrete", action_dim=5).to_dict()
    with pytest.raises(ConfigError, match=r"unknown OMPNConfig keys \['hidden'\]"):
        OMPNConfig.from_dict({**good, "hidden": 3})
    with pytest.raises(ConfigError, match=r"missing required keys \['obs_dim'\]"):
        OMPNConfig.from_dict({k: v for k, v in good.items() if k != "obs_dim"})
    with pytest.raises(ConfigError, match="version 2 is not supported"):
        OMPNConfig.from_dict({**good, "version": 2})
    with pytest.raises(ConfigError, match="not valid JSON"):
        OMPNConfig.from_json("{broken")
