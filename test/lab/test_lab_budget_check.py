"""The delay-budget check (lab.budget_check): each run's decoder is tuned on validation as ompn_train
tunes it, with the budget and without, its runs exist, and the transfer table checks it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from lab_cache import write_cache

from lab import budget_check as check
from lab import transfer
from lab.detector_selection import _bounds, cached_scores
from lab.own_data import ARMS
from ompn_ros.detect.duration_tuning import calibrate_duration
from ompn_ros.detect.grid import scores_from_p_hats


def test_every_run_is_an_arm_of_the_own_data_study() -> None:
    for _, _, runs in check.FAMILIES:
        assert len(runs) in (5, 10) and all(run in ARMS for run in runs)


def test_each_run_is_decoded_with_and_without_the_budget(tmp_path: Path) -> None:
    runs = ("toy_seed1", "toy_seed2")
    for run in runs:
        write_cache(tmp_path, run, sharp=True)
    row = check.family_row(tmp_path, "toy", "the family", runs)
    data = cached_scores("toy_seed1", tmp_path)
    free = calibrate_duration(scores_from_p_hats(data["val_p"]), _bounds(data["val_l"]), 1, "align")
    assert row["runs"][0]["none"]["threshold"] == free.config.high  # the trainer's own calibration
    assert row["seeds"] == [1, 2]
    for name in ("shipped", "none"):
        figures = [r[name]["online_align"] for r in row["runs"]]
        assert row["means"][name]["online_align"] == pytest.approx(np.mean(figures))
        assert all(0 <= f <= 1 for f in figures)
    (tmp_path / "own_data.json").write_text(json.dumps({"meta": {}, "rows": []}))
    (tmp_path / check.BUDGET).write_text(json.dumps({"meta": {}, "families": [row]}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = [r for r in json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
            if r["default"].startswith("delay budget")]
    gap = row["means"]["shipped"]["online_align"] - row["means"]["none"]["online_align"]
    assert len(rows) == 1 and rows[0]["gap"]["online_align"] == pytest.approx(gap)
    assert rows[0]["holds"] == (min(rows[0]["gap"].values()) >= -transfer.TOLERANCE)
