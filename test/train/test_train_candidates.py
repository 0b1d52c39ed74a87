"""Best of N initialisations (train.candidates): each candidate is the single run of its seed on one
split, the best by validation is published into the run directory, and ompn_train trains two only
for bags whose final observation the reader guessed."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from ompn_ros.data.reader import BagReport, ReadReport, final_row_guessed
from ompn_ros.data.reader.report import BLANK_LAST, DROPPED_LAST
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train.candidates import (
    CANDIDATE_SEED_STRIDE,
    CANDIDATES_FILE,
    candidate_config,
    resolve_candidates,
)
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import TrainResult, train, train_val_episodes

torch.set_num_threads(1)


def _model_config() -> OMPNConfig:
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    return OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2,
                      slot_size=32)


def _cfg(out: Path, **overrides: object) -> TrainConfig:
    base = {"lr": 3e-3, "batch_size": 16, "iterations": 6, "eval_every": 2, "val_ratio": 0.25, "seed": 5,
            "progress": False, "threads": 1, "out_dir": str(out)}
    return TrainConfig(**{**base, **overrides})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def episodes() -> list:
    return make_dataset("discrete", 48, seed=1)


def _weights(path: Path) -> list[torch.Tensor]:
    return list(load_checkpoint(path)[0].state_dict().values())


def _same(a: Path, b: Path) -> bool:
    return all(torch.equal(x, y) for x, y in zip(_weights(a), _weights(b), strict=True))


def test_the_best_candidate_by_validation_is_published(tmp_path: Path, episodes: list) -> None:
    out = tmp_path / "run"
    result = train(episodes, _model_config(), _cfg(out, candidates=3, seed=1))
    doc = json.loads((out / CANDIDATES_FILE).read_text())
    scores = [row["best"] for row in doc["candidates"]]
    assert [row["seed"] for row in doc["candidates"]] == [1 + CANDIDATE_SEED_STRIDE * k for k in range(3)]
    assert doc["winner"] == scores.index(max(scores)) and doc["selection"] == "align"
    assert doc["winner"] != 0  # this seed's later candidate wins: the copy is not candidate 0's by default
    assert result.best_metrics["align"] == max(scores) and result.candidates == doc["candidates"]
    won = out / "candidates" / str(doc["winner"])
    for name in ("best", "last"):
        assert _same(out / name, won / name) and (out / name / "detector.json").is_file()
    assert (out / "log.jsonl").read_text() == (won / "log.jsonl").read_text()
    runs = [out / "candidates" / str(k) / "last" for k in range(3)]
    assert not any(_same(runs[a], runs[b]) for a, b in ((0, 1), (0, 2), (1, 2)))  # three initialisations


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory, episodes: list) -> tuple[TrainResult, TrainConfig]:
    """Two candidates of seed 0, trained once for the tests that compare runs with them."""
    cfg = _cfg(tmp_path_factory.mktemp("pair") / "whole", candidates=2, seed=0)
    return train(episodes, _model_config(), cfg), cfg


def test_candidate_zero_is_the_single_run_and_all_share_its_split(
        tmp_path: Path, episodes: list, pair: tuple[TrainResult, TrainConfig]) -> None:
    _, cfg = pair
    single = train(episodes, _model_config(), _cfg(tmp_path / "single", seed=0))
    assert _same(Path(str(cfg.out_dir)) / "candidates" / "0" / "last", tmp_path / "single" / "last")
    assert single.candidates == [] and not (tmp_path / "single" / CANDIDATES_FILE).exists()
    split = [e.seed for e in train_val_episodes(episodes, cfg)[1]]
    assert [e.seed for e in train_val_episodes(episodes, candidate_config(cfg, 1))[1]] == split


def test_a_resumed_pair_trains_only_what_is_missing(tmp_path: Path, episodes: list,
                                                    pair: tuple[TrainResult, TrainConfig]) -> None:
    whole, whole_cfg = pair
    assert json.loads((Path(str(whole_cfg.out_dir)) / CANDIDATES_FILE).read_text())["winner"] == 1
    out = tmp_path / "resumed"
    train(episodes, _model_config(), _cfg(out / "candidates" / "0", seed=0))  # candidate 0, trained before

    counted: list[int] = []
    resumed = train(episodes, _model_config(), _cfg(out, candidates=2, seed=0, resume=True),
                    callback=lambda it, _: counted.append(it))
    assert counted == list(range(1, 7))  # candidate 1 only; candidate 0 was finished
    assert resumed.best_metrics == whole.best_metrics
    assert _same(out / "best", Path(str(whole_cfg.out_dir)) / "best")


def test_candidates_are_raised_only_for_guessed_final_rows_with_labels() -> None:
    cfg = TrainConfig(candidates=1, candidates_no_final=2)
    assert resolve_candidates(cfg, final_guessed=True, labelled=True).candidates == 2
    assert resolve_candidates(cfg, final_guessed=False, labelled=True).candidates == 1
    assert resolve_candidates(cfg, final_guessed=True, labelled=False).candidates == 1
    assert resolve_candidates(replace(cfg, candidates=3), True, True).candidates == 3  # never lowered
    for name in ("candidates", "candidates_no_final"):
        with pytest.raises(TrainConfigError, match=name):
            TrainConfig(**{name: 0})  # type: ignore[arg-type]


def test_the_read_facts_say_whether_row_t_was_guessed() -> None:
    bag = BagReport(path="robot_bag", episodes=3, steps=30, split="time_gap")
    assert not final_row_guessed(ReadReport([bag]).facts())
    bag.guessed.append("topic 'cmd' = '/arm/cmd' (unique suffix match)")
    bag.adjusted[DROPPED_LAST] = [0]  # dropped, not guessed
    assert not final_row_guessed(ReadReport([bag]).facts())
    bag.adjusted[BLANK_LAST] = [1, 2]
    assert final_row_guessed(ReadReport([bag]).facts()) and ReadReport([bag]).facts()[0].final_guessed == 2
