"""The restart rule: a collapsed attempt starts again from a new initialisation on the same split."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train.restart import RESTART_SEED_STRIDE, attempt_config, collapsed, rule_applies
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import TrainConfig, TrainConfigError, train, train_val_episodes

torch.set_num_threads(1)


def _model_config() -> OMPNConfig:
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    return OMPNConfig(
        obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2, slot_size=16
    )


def _cfg(out: Path, **overrides: object) -> TrainConfig:
    base = {"lr": 3e-3, "batch_size": 16, "iterations": 4, "eval_every": 1, "val_ratio": 0.25,
            "progress": False, "threads": 1, "out_dir": str(out), "seed": 3}
    return TrainConfig(**{**base, **overrides})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def episodes() -> list:
    return make_dataset("discrete", 32, seed=0)


def _weights(path: Path) -> list[torch.Tensor]:
    return [t.clone() for t in load_checkpoint(path)[0].state_dict().values()]


def test_an_unreachable_bound_restarts_once_on_the_same_split(tmp_path: Path, episodes: list) -> None:
    cfg = _cfg(tmp_path / "r", restart_at=2, restart_below=1.0, restarts=1)
    result = train(episodes, _model_config(), cfg)
    assert result.restarts == 1 and result.iterations == 4  # the second attempt is never checked again
    record = json.loads((tmp_path / "r" / "attempt.json").read_text())
    assert record["attempt"] == 1 and record["seed"] == 3 + RESTART_SEED_STRIDE
    assert "below restart_below=1.0" in record["reason"]
    old_log = (tmp_path / "r" / "log_attempt0.jsonl").read_text().splitlines()
    assert [json.loads(line)["iteration"] for line in old_log] == [1, 2]  # stopped at restart_at
    # the same split, another initialisation: equal to a run started with the attempt's config
    direct_cfg = attempt_config(replace(cfg, out_dir=str(tmp_path / "d"), restart_at=0), 1)
    assert train(episodes, _model_config(), direct_cfg).restarts == 0
    assert all(torch.equal(a, b) for a, b in zip(_weights(tmp_path / "r" / "last"),
                                                  _weights(tmp_path / "d" / "last"), strict=True))
    assert [e.seed for e in train_val_episodes(episodes, cfg)[1]] == [
        e.seed for e in train_val_episodes(episodes, attempt_config(cfg, 1))[1]
    ]


def test_a_reached_bound_or_hidden_labels_never_restart(tmp_path: Path, episodes: list) -> None:
    kept = train(episodes, _model_config(), _cfg(tmp_path / "a", restart_at=2, restart_below=0.0))
    assert kept.restarts == 0 and not (tmp_path / "a" / "attempt.json").exists()
    hidden = _cfg(tmp_path / "b", restart_at=2, restart_below=1.0, labels="none")
    blind = train(episodes, _model_config(), hidden)
    assert blind.restarts == 0 and blind.selection == "agreement"


def test_a_killed_restarted_run_resumes_its_attempt(tmp_path: Path, episodes: list) -> None:
    cfg = _cfg(tmp_path / "k", iterations=6, restart_at=2, restart_below=1.0)
    whole = train(episodes, _model_config(), replace(cfg, out_dir=str(tmp_path / "w")))

    def kill(iteration: int, _: dict) -> None:
        if (tmp_path / "k" / "attempt.json").exists() and iteration == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(episodes, _model_config(), cfg, callback=kill)
    resumed = train(episodes, _model_config(), replace(cfg, resume=True))
    assert resumed.restarts == whole.restarts == 1
    assert all(torch.equal(a, b) for a, b in zip(_weights(tmp_path / "k" / "last"),
                                                  _weights(tmp_path / "w" / "last"), strict=True))


def test_rule_bookkeeping_and_validation() -> None:
    cfg = TrainConfig(iterations=200, restart_at=120, restart_below=0.7, restarts=1)
    assert rule_applies(cfg, "align", 0) and not rule_applies(cfg, "align", 1)
    assert not rule_applies(cfg, "agreement", 0) and not rule_applies(replace(cfg, restart_at=0), "align", 0)
    assert collapsed(cfg, 120, 0.61) and not collapsed(cfg, 120, 0.93) and not collapsed(cfg, 100, 0.1)
    assert not collapsed(cfg, 140, 0.1)  # checked once, at the first evaluation at or after restart_at
    odd = replace(cfg, eval_every=50)  # an eval_every that misses restart_at: checked at 150
    assert collapsed(odd, 150, 0.5) and not collapsed(odd, 100, 0.5) and not collapsed(odd, 200, 0.5)
    assert attempt_config(cfg, 0) is cfg and attempt_config(cfg, 2).split_seed == cfg.seed
    with pytest.raises(TrainConfigError, match="restart_at"):
        TrainConfig(restart_at=-20)
    with pytest.raises(TrainConfigError, match="restart_below"):
        TrainConfig(restart_below=1.5)
