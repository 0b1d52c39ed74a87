"""The agreement warm-up check (lab.warmup_check): the label-free pick replayed from a run's log is the
trainer's (warm-up, the last evaluation always eligible, the first of equal keys), its runs exist in
the own-data study, and the transfer table checks it against no warm-up."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lab import transfer
from lab import warmup_check as check
from lab.own_data import ARMS


def _log(agreements: list[float], loss: float = 1.0) -> list[dict[str, float]]:
    return [{"iteration": 20 * (i + 1), "agreement": a, "loss": loss, "f1_tol1": i / 10, "align": i / 20}
            for i, a in enumerate(agreements)]


def test_the_label_free_pick_skips_the_warm_up_and_keeps_the_first_of_equal_keys() -> None:
    history = _log([0.9, 0.5, 0.6, 0.8, 0.7, 0.8, 0.4])  # evaluations at 20 … 140
    assert check.label_free_pick(history, 0)["iteration"] == 20
    assert check.label_free_pick(history, 60)["iteration"] == 80  # 80 and 120 tie: the first
    assert check.label_free_pick(history, 1000)["iteration"] == 140  # the last evaluation always may


def test_every_family_names_runs_of_the_own_data_study() -> None:
    runs = [r for f in check.FAMILIES for r in f.runs]
    assert runs and all(r in ARMS for r in runs)


def test_the_transfer_table_checks_the_warm_up_against_none(tmp_path: Path) -> None:
    work = tmp_path / "work"
    logs = {"a_seed1": [0.9, 0.1, 0.2, 0.3, 0.4, 0.5], "b_seed2": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]}
    for run, agreements in logs.items():
        (work / "runs" / run).mkdir(parents=True)
        lines = [json.dumps(r) for r in _log(agreements)]
        (work / "runs" / run / "log.jsonl").write_text("\n".join(lines) + "\n")
    row = check.family_row(check.Family("toy", ("a_seed1", "b_seed2")), work)
    assert row["changed"] == 1 and row["seeds"] == [1, 2]
    assert row["means"]["none"]["offline_align"] == pytest.approx((0.0 + 5 / 20) / 2)
    assert row["means"]["shipped"]["offline_align"] == pytest.approx(5 / 20)
    (tmp_path / "own_data.json").write_text(json.dumps({"meta": {}, "rows": []}))
    (tmp_path / check.WARMUP).write_text(json.dumps({"meta": {}, "families": [row]}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = [r for r in json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
            if r["default"].startswith("agreement_warmup")]
    assert len(rows) == 1 and rows[0]["holds"]  # run a's early peak is skipped: both figures gain
    assert rows[0]["gap"]["offline_align"] == pytest.approx(5 / 40)
