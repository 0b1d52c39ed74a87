"""The agreement warm-up check (lab.warmup_check): the label-free pick replayed from a run's log is the
trainer's (warm-up, the last evaluation always eligible, the first of equal keys), its runs exist in
the own-data study, the family's own best warm-up is ranked in the domain's order, and the transfer
table checks the shipped warm-up against that best, naming no warm-up's figures."""

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


def test_the_family_best_ranks_in_the_domain_order_and_keeps_the_smallest_of_equals() -> None:
    grid = {str(w): {"offline_f1_1": 0.5, "offline_align": 0.5} for w in check.GRID}
    grid["40"] = {"offline_f1_1": 0.9, "offline_align": 0.4}  # Craft ranks F1@1 first
    grid["120"] = {"offline_f1_1": 0.1, "offline_align": 0.8}  # Dial ranks alignment first
    assert check.family_best(grid, "craft") == 40
    assert check.family_best(grid, "dial") == 120
    flat = {str(w): {"offline_f1_1": 0.5, "offline_align": 0.5} for w in check.GRID}
    assert check.family_best(flat, "dial") == 0


def _work(tmp_path: Path, logs: dict[str, list[float]]) -> Path:
    work = tmp_path / "work"
    for run, agreements in logs.items():
        (work / "runs" / run).mkdir(parents=True)
        lines = [json.dumps(r) for r in _log(agreements)]
        (work / "runs" / run / "log.jsonl").write_text("\n".join(lines) + "\n")
    return work


def test_the_transfer_table_checks_the_warm_up_against_the_family_best(tmp_path: Path) -> None:
    # run a's early peak (iteration 20) is kept without a warm-up; figures grow with the iteration
    work = _work(tmp_path, {"a_seed1": [0.9, 0.1, 0.2, 0.3, 0.4, 0.5],
                            "b_seed2": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]})
    row = check.family_row(check.Family("toy", ("a_seed1", "b_seed2"), "craft", "the family"), work)
    assert row["changed"] == 1 and row["seeds"] == [1, 2] and row["family_warmup"] == 20
    assert row["means"]["none"]["offline_align"] == pytest.approx((0.0 + 5 / 20) / 2)
    assert row["means"]["shipped"]["offline_align"] == pytest.approx(5 / 20)
    assert row["means"]["family"] == row["grid_means"]["20"] == row["means"]["shipped"]
    (tmp_path / "own_data.json").write_text(json.dumps({"meta": {}, "rows": []}))
    (tmp_path / check.WARMUP).write_text(json.dumps({"meta": {}, "families": [row]}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = [r for r in json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
            if r["default"].startswith("agreement_warmup")]
    assert len(rows) == 1 and rows[0]["holds"] and rows[0]["gap"]["offline_align"] == 0
    assert row["family_ties"] == list(range(20, 201, 20))  # every later warm-up keeps the last: ties
    assert rows[0]["reference"].startswith("the family's own best warm-up (20–200)")
    assert rows[0]["reference"].endswith("none: 25.0 / 12.5")


def test_a_warm_up_past_the_family_best_loses(tmp_path: Path) -> None:
    # the best evaluation (60) lies inside the shipped warm-up: the default keeps a worse one
    work = _work(tmp_path, {"a_seed1": [0.1, 0.2, 0.9, 0.3, 0.4, 0.5, 0.45]})
    history = [json.loads(line) for line in (work / "runs/a_seed1/log.jsonl").read_text().splitlines()]
    for r in history:
        r["align"] = 0.9 if r["iteration"] == 60 else 0.2
    (work / "runs/a_seed1/log.jsonl").write_text("\n".join(json.dumps(r) for r in history) + "\n")
    row = check.family_row(check.Family("toy", ("a_seed1",), "dial", "the family"), work)
    assert row["family_warmup"] == 0 and row["means"]["family"]["offline_align"] == pytest.approx(0.9)
    assert row["means"]["shipped"]["offline_align"] == pytest.approx(0.2)
    (tmp_path / "own_data.json").write_text(json.dumps({"meta": {}, "rows": []}))
    (tmp_path / check.WARMUP).write_text(json.dumps({"meta": {}, "families": [row]}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
    assert len(rows) == 1 and not rows[0]["holds"]
    assert rows[0]["gap"]["offline_align"] == pytest.approx(-0.7)
