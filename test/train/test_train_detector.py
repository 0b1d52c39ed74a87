"""The trainer bundles detector.json, selects without labels (after a warm-up), stops early (patience)
and restarts a collapsed initialisation (the restart rule)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.detect.choose import pick_online
from ompn_ros.detect.defaults import DURATION_GAIN, DURATION_LAG
from ompn_ros.detect.duration import fit_duration_model
from ompn_ros.detect.duration_tuning import DurationCalibration
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError, TrainStateError
from ompn_ros.train.restart import (
    RESTART_SEED_STRIDE,
    attempt_config,
    keep_attempt,
    kept_attempt,
    read_attempt,
    read_kept,
    rule_applies,
    start_score,
    weak_start,
)
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import (
    TrainResult,
    _patience_exhausted,
    effective_selection,
    eligible,
    evaluations_since_best,
    head_fit_episodes,
    train,
    train_val_episodes,
)

torch.set_num_threads(1)


def _model_config() -> OMPNConfig:
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    return OMPNConfig(
        obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2, slot_size=32
    )


def _cfg(tmp_path: Path, **overrides: object) -> TrainConfig:
    base = {
        "lr": 3e-3,
        "batch_size": 32,
        "iterations": 60,
        "eval_every": 30,
        "val_ratio": 0.25,
        "progress": False,
        "threads": 1,
        "out_dir": str(tmp_path),
    }
    return TrainConfig(**{**base, **overrides})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def episodes() -> list:
    return make_dataset("discrete", 96, seed=0)


def test_labelled_run_bundles_tuned_detectors(tmp_path: Path, episodes: list) -> None:
    result = train(episodes, _model_config(), _cfg(tmp_path))
    assert result.selection == "align" and set(result.detectors) == {"best", "last"}
    for name in ("best", "last"):
        stored = load_detector_settings(tmp_path / name)
        assert stored.source == "tuned_on_validation" and stored == result.detectors[name]
        assert "validation episodes" in stored.provenance
    best = result.detectors["best"]
    assert best.metrics["val_f1_tol1"] >= 0.8  # the learned boundaries are found online
    assert best.online.high != 0.5 or best.online.mode != "falling_edge"  # not the generic default
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert all(0.0 <= rec["agreement"] <= 1.0 for rec in log)
    # the duration decoder is fitted on the same labels, and chosen by the stated rule
    counts = {len(ep.boundaries) for ep in episodes}
    assert best.duration_model is not None and best.duration_model.subtasks in counts
    m = best.metrics
    gains = m["hsmm_val_align"] >= m["threshold_val_align"] + DURATION_GAIN
    keeps = m["hsmm_val_f1_tol1"] >= m["threshold_val_f1_tol1"] - DURATION_GAIN
    before_head = "hsmm" if gains and keeps else "threshold"
    # the boundary head is trained too, kept with the checkpoint, and runs when it aligns better
    assert best.head is not None and (tmp_path / "best" / "boundary_head.safetensors").is_file()
    assert best.head.rule is not None and 1 <= best.head.rule.lag <= best.head.max_lag
    head_wins = m["head_val_align"] > m[f"{before_head}_val_align"]
    before_both = "head" if head_wins else before_head
    # then the duration decoder over the head, its threshold tuned as the duration decoder's
    both_wins = m["head_hsmm_val_align"] > m[f"{before_both}_val_align"]
    assert (best.online.mode == "head_hsmm") == both_wins
    assert (best.online.mode == "head") == (head_wins and not both_wins)
    assert best.online.mode != "head" or best.online == best.head.rule
    if not head_wins and not both_wins:
        assert (best.online.mode == "hsmm") == (before_head == "hsmm")
    assert best.online.mode not in ("hsmm", "head_hsmm") or best.online.lag == DURATION_LAG


def test_the_head_is_fitted_on_episodes_spread_over_the_whole_training_split(episodes: list) -> None:
    many = [replace(ep, task=f"task{i // 300}") for i, ep in enumerate(episodes * 13)]  # 1 248, task blocks
    fit = head_fit_episodes(many)
    assert len(fit) == 416 and {ep.task for ep in fit} == {ep.task for ep in many}
    assert head_fit_episodes(episodes[:40]) == episodes[:40]


def test_the_boundary_head_can_be_turned_off(tmp_path: Path, episodes: list) -> None:
    result = train(episodes[:48], _model_config(), _cfg(tmp_path, iterations=4, eval_every=2,
                                                        boundary_head=False))
    assert result.detectors["best"].head is None and "head_val_align" not in result.detectors["best"].metrics
    assert not (tmp_path / "best" / "boundary_head.safetensors").exists()


def test_hidden_labels_select_and_calibrate_without_them(tmp_path: Path, episodes: list) -> None:
    result = train(episodes, _model_config(), _cfg(tmp_path, labels="none"))
    assert result.selection == "agreement"
    stored = load_detector_settings(tmp_path / "best")
    assert stored.source == "calibrated_label_free" and stored.offline_detector == "auto_threshold"
    assert stored.metrics["agreement_f1_tol1"] > 0.5
    assert "align" in result.best_metrics  # still scored and logged
    assert stored.duration_model is not None  # fitted on the pooled reference
    assert "hsmm_pooled_align" in stored.metrics


def test_the_hsmm_detector_is_chosen_only_when_it_gains_alignment_and_keeps_f1() -> None:
    threshold, base = DetectorConfig(high=0.3), {"align": 0.80, "f1_tol1": 0.90}
    model = fit_duration_model([np.array([0.0, 0.1, 0.8, 0.1, 0.1])] * 3, [np.array([2, 4])] * 3)

    def duration(align: float, f1: float) -> DurationCalibration:
        return DurationCalibration(model, DetectorConfig(mode="hsmm", high=0.5, lag=3),
                                   {"align": align, "f1_tol1": f1})

    assert pick_online(threshold, base, duration(0.85, 0.895))[0].mode == "hsmm"
    assert pick_online(threshold, base, duration(0.805, 0.95))[0] == threshold  # too little alignment gained
    assert pick_online(threshold, base, duration(0.95, 0.88))[0] == threshold  # F1 not kept
    figures = {"threshold_val_align": 0.8, "threshold_val_f1_tol1": 0.9}
    assert pick_online(threshold, base, None) == (threshold, figures)
    with pytest.raises(TrainConfigError, match="detector_lag must be an int in \\[0, 10\\]"):
        TrainConfig(detector_lag=11)
    with pytest.raises(TrainConfigError, match="detector_delay must be > 0"):
        TrainConfig(detector_delay=0)


def test_unlabelled_data_selects_by_agreement(tmp_path: Path, episodes: list) -> None:
    unlabelled = [replace(ep, subtask=None) for ep in episodes[:40]]
    result = train(unlabelled, _model_config(), _cfg(tmp_path, iterations=2, eval_every=1))
    assert result.selection == "agreement" and "align" not in result.best_metrics
    assert load_detector_settings(tmp_path / "best").source == "calibrated_label_free"


def test_patience_stops_when_the_criterion_stalls(tmp_path: Path, episodes: list) -> None:
    # a learning rate too small to change anything: the first evaluation stays the best
    stalled = _cfg(tmp_path / "a", lr=1e-12, iterations=40, eval_every=1, patience=3, selection="val_loss")
    result = train(episodes[:24], _model_config(), stalled)
    assert result.stopped_early and result.iterations == 4 and result.best_iteration == 1
    full = train(
        episodes[:24],
        _model_config(),
        replace(stalled, out_dir=str(tmp_path / "b"), iterations=6, patience=0),
    )
    assert not full.stopped_early and full.iterations == 6


def test_selection_fallback_and_patience_bookkeeping() -> None:
    assert effective_selection(TrainConfig(selection="align"), labelled=True) == "align"
    assert effective_selection(TrainConfig(selection="f1_tol1"), labelled=False) == "agreement"
    assert effective_selection(TrainConfig(selection="align", labels="none"), labelled=True) == "agreement"
    assert effective_selection(TrainConfig(selection="val_loss", labels="none"), labelled=True) == "val_loss"
    history = [{"iteration": float(i)} for i in (20, 40, 60, 80)]
    assert evaluations_since_best(history, 40) == 2 and evaluations_since_best(history, 80) == 0
    with pytest.raises(TrainConfigError, match="patience"):
        TrainConfig(patience=-1)
    with pytest.raises(TrainConfigError, match="labels"):
        TrainConfig(labels="some")  # type: ignore[arg-type]


def test_agreement_warmup_keeps_early_evaluations_out_of_best(tmp_path: Path, episodes: list) -> None:
    cfg = _cfg(tmp_path, labels="none", iterations=6, eval_every=1, agreement_warmup=4)
    result = train(episodes[:24], _model_config(), cfg)
    assert result.selection == "agreement" and result.best_iteration in (5, 6)
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [int(rec["iteration"]) for rec in log] == [1, 2, 3, 4, 5, 6]  # still evaluated and logged
    stored = json.loads((tmp_path / "best" / "meta.json").read_text())
    assert stored["extra"]["iteration"] == result.best_iteration


def test_agreement_warmup_bookkeeping() -> None:
    cfg = TrainConfig(iterations=300, patience=2, agreement_warmup=100)
    assert not eligible(cfg, "agreement", 100) and eligible(cfg, "agreement", 120)
    assert eligible(cfg, "align", 20)  # labelled selection: no warm-up
    assert eligible(replace(cfg, iterations=60), "agreement", 60)  # a run's last evaluation always may
    history = [{"iteration": float(i)} for i in (20, 40, 60, 80, 100)]
    # nothing selected yet: evaluations inside the warm-up do not use up the patience
    assert not _patience_exhausted(cfg, "agreement", history, 0)
    assert _patience_exhausted(cfg, "align", history, 20)
    later = [*history, {"iteration": 120.0}, {"iteration": 140.0}]
    assert _patience_exhausted(cfg, "agreement", later, 0)
    with pytest.raises(TrainConfigError, match="agreement_warmup"):
        TrainConfig(agreement_warmup=-5)


SMALL: dict[str, object] = {"batch_size": 16, "iterations": 4, "eval_every": 1, "seed": 3}
"""The restart tests' short runs."""


def _weights(path: Path) -> list[torch.Tensor]:
    return [t.clone() for t in load_checkpoint(path)[0].state_dict().values()]


def _iterations(log: Path) -> list[int]:
    return [json.loads(line)["iteration"] for line in log.read_text().splitlines()]


def test_a_weak_start_trains_a_second_initialisation_and_keeps_the_better(
    tmp_path: Path, episodes: list
) -> None:
    cfg = _cfg(tmp_path / "r", **SMALL, restart_at=2, restart_below=1.0, restarts=1)
    result = train(episodes[:32], _model_config(), cfg)
    assert result.restarts == 1 and result.iterations == 4  # the second attempt is never checked again
    record = json.loads((tmp_path / "r" / "attempt.json").read_text())
    assert record["attempt"] == 1 and record["seed"] == 3 + RESTART_SEED_STRIDE
    assert "below restart_below=1.0" in record["reason"]
    rows = record["attempts"]
    assert [r["attempt"] for r in rows] == [0, 1] and all(r["best_iteration"] > 0 for r in rows)
    kept = record["kept"]
    assert kept == kept_attempt(rows) and result.best_metrics["align"] == max(r["best"] for r in rows)
    assert _iterations(tmp_path / "r" / "attempts" / "1" / "log.jsonl") == [1, 2, 3, 4]
    first_log = tmp_path / "r" / ("log_attempt0.jsonl" if kept else "log.jsonl")
    assert _iterations(first_log) == [1, 2, 3, 4]  # the weak start trained to the end all the same
    # each attempt equals a run started with its config; the run directory holds the kept one
    direct = attempt_config(replace(cfg, out_dir=str(tmp_path / "d"), restart_at=0), kept)
    assert train(episodes[:32], _model_config(), direct).restarts == 0
    assert all(torch.equal(a, b) for a, b in zip(_weights(tmp_path / "r" / "last"),
                                                  _weights(Path(str(direct.out_dir)) / "last"), strict=True))
    assert (tmp_path / "r" / "best" / "detector.json").is_file()
    assert [e.seed for e in train_val_episodes(episodes[:32], cfg)[1]] == [
        e.seed for e in train_val_episodes(episodes[:32], attempt_config(cfg, 1))[1]
    ]
    # a fresh run in the same directory forgets the earlier attempts
    again = train(episodes[:32], _model_config(), replace(cfg, restart_at=0))
    assert again.restarts == 0 and not (tmp_path / "r" / "attempts").exists()
    assert not (tmp_path / "r" / "attempt.json").exists()


def test_the_kept_attempt_is_published_with_the_first_log_kept(tmp_path: Path) -> None:
    out = tmp_path / "out"
    (out / "best").mkdir(parents=True)
    (out / "best" / "w").write_text("first")
    (out / "log.jsonl").write_text("first log\n")
    second = out / "attempts" / "1"
    for name in ("best", "last"):
        (second / name).mkdir(parents=True)
        (second / name / "w").write_text(f"second {name}")
    (second / "log.jsonl").write_text("second log\n")
    rows = [{"attempt": 0, "best": 0.6}, {"attempt": 1, "best": 0.8}]
    record = {"attempt": 1, "seed": 9, "reason": "x", "attempts": rows[:1]}
    (out / "attempt.json").write_text(json.dumps(record))
    keep_attempt(out, kept_attempt(rows), rows)
    assert (out / "best" / "w").read_text() == "second best"
    assert (out / "last" / "w").read_text() == "second last"
    assert (out / "log.jsonl").read_text() == "second log\n"
    assert (out / "log_attempt0.jsonl").read_text() == "first log\n"
    doc = json.loads((out / "attempt.json").read_text())
    assert doc["kept"] == 1 and doc["attempts"] == rows and doc["reason"] == "x"
    equal = [{"attempt": 0, "best": 0.7}, {"attempt": 1, "best": 0.7}]
    assert kept_attempt(equal) == 0  # the first of equals


def test_a_reached_bound_or_hidden_labels_never_restart(tmp_path: Path, episodes: list) -> None:
    reached = _cfg(tmp_path / "a", **SMALL, restart_at=2, restart_below=0.0)
    kept = train(episodes[:32], _model_config(), reached)
    assert kept.restarts == 0 and not (tmp_path / "a" / "attempt.json").exists()
    hidden = _cfg(tmp_path / "b", **SMALL, restart_at=2, restart_below=1.0, labels="none")
    blind = train(episodes[:32], _model_config(), hidden)
    assert blind.restarts == 0 and blind.selection == "agreement"


def _killable_config(out: Path) -> TrainConfig:
    return _cfg(out, **{**SMALL, "iterations": 6}, restart_at=2, restart_below=1.0)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory, episodes: list) -> tuple[TrainResult, Path]:
    """The uninterrupted run both kill points are compared with (the output folder changes nothing else)."""
    out = tmp_path_factory.mktemp("uninterrupted") / "w"
    return train(episodes[:32], _model_config(), _killable_config(out)), out


@pytest.mark.parametrize("killed_in", ["attempts/1", "."])
def test_a_killed_restarted_run_resumes_its_attempt(tmp_path: Path, episodes: list, killed_in: str,
                                                    uninterrupted: tuple[TrainResult, Path]) -> None:
    """Killed in the second attempt, or in the first after its weak start was seen: the resumed run
    ends with the weights and record of an uninterrupted one."""
    cfg = _killable_config(tmp_path / "k")
    whole, w = uninterrupted

    def kill(iteration: int, _: dict) -> None:
        second = (tmp_path / "k" / "attempt.json").exists()
        if iteration == 5 and second == (killed_in != "."):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(episodes[:32], _model_config(), cfg, callback=kill)
    resumed = train(episodes[:32], _model_config(), replace(cfg, resume=True))
    assert resumed.restarts == whole.restarts == 1
    assert resumed.best_metrics == whole.best_metrics
    assert all(torch.equal(a, b) for a, b in zip(_weights(tmp_path / "k" / "last"),
                                                  _weights(w / "last"), strict=True))
    kept = read_kept(w)
    assert read_kept(tmp_path / "k") == kept
    source = w / ("attempts/1" if kept else ".")
    assert all(torch.equal(a, b) for a, b in zip(_weights(source / "best"), _weights(w / "best"),
                                                  strict=True))


def test_a_broken_restart_record_is_one_clear_error(tmp_path: Path) -> None:
    assert read_attempt(tmp_path) == 0 and read_attempt(None) == 0
    (tmp_path / "attempt.json").write_text("{not json")
    with pytest.raises(TrainStateError, match=r"attempt\.json is not a restart record"):
        read_attempt(tmp_path)
    (tmp_path / "attempt.json").write_text('{"attempt": -1}')
    with pytest.raises(TrainStateError, match="must be an int >= 0"):
        read_attempt(tmp_path)
    (tmp_path / "attempt.json").write_text('{"attempt": 1, "seed": 3, "reason": "x"}')
    assert read_kept(tmp_path) == 1  # a record from before the rule kept the better attempt
    record = {"attempt": 1, "attempts": [{"attempt": 0, "best": 0.5}], "kept": 0}
    (tmp_path / "attempt.json").write_text(json.dumps(record))
    assert read_kept(tmp_path) == 0 and read_attempt(tmp_path) == 1
    (tmp_path / "attempt.json").write_text('{"attempt": 1, "attempts": [{"best": 0.5}]}')
    with pytest.raises(TrainStateError, match="list of attempt records"):
        read_attempt(tmp_path)


def test_rule_bookkeeping_and_validation() -> None:
    cfg = TrainConfig(iterations=200, restart_at=120, restart_below=0.7, restarts=1)
    assert rule_applies(cfg, True, 0) and not rule_applies(cfg, True, 1)
    assert not rule_applies(cfg, False, 0) and not rule_applies(replace(cfg, restart_at=0), True, 0)
    assert weak_start(cfg, [(100, 0.5), (120, 0.61), (140, 0.9)])
    assert not weak_start(cfg, [(100, 0.5), (120, 0.93)]) and not weak_start(cfg, [(20, 0.1), (100, 0.1)])
    assert not weak_start(cfg, [(100, 0.75), (130, 0.1)])  # the best so far counts, checked once
    assert start_score(cfg, [(60, 0.615), (130, 0.6), (140, 0.95)]) == 0.615
    assert start_score(replace(cfg, restart_at=0), [(120, 0.1)]) is None
    odd = replace(cfg, eval_every=50)  # an eval_every that misses restart_at: checked at 150
    assert weak_start(odd, [(100, 0.8), (150, 0.5)]) is False and weak_start(odd, [(100, 0.5), (150, 0.6)])
    assert attempt_config(cfg, 0) is cfg and attempt_config(cfg, 2).split_seed == cfg.seed
    with pytest.raises(TrainConfigError, match="restart_at"):
        TrainConfig(restart_at=-20)
    with pytest.raises(TrainConfigError, match="restart_below"):
        TrainConfig(restart_below=1.5)
