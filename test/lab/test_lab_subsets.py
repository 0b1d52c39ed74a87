"""The best-of-N analysis keeps, in every subset of seeds, the run validation prefers, and averages
that run's held-out figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lab.subsets import Run, SubsetError, best_of, main, read_run


def _write(work: Path, arm: str, vals: list[float], test_align: float) -> None:
    (work / "runs" / arm).mkdir(parents=True)
    lines = [json.dumps({"iteration": 20 * (i + 1), "align": v, "loss": 1.0}) for i, v in enumerate(vals)]
    (work / "runs" / arm / "log.jsonl").write_text("\n".join(lines) + "\n")
    (work / "arms").mkdir(exist_ok=True)
    row = {"online_f1_1": 0.9, "online_align": 0.7, "offline_f1_1": 0.95, "offline_align": test_align}
    (work / "arms" / f"{arm}.json").write_text(json.dumps(row))


def test_validation_not_test_decides_which_run_stands_for_a_subset(tmp_path: Path) -> None:
    _write(tmp_path, "blank", [0.5, 0.9], test_align=0.80)  # best validation, worse test
    _write(tmp_path, "blank_seed1", [0.6, 0.7], test_align=0.99)
    _write(tmp_path, "blank_seed2", [0.85], test_align=0.60)
    runs = [read_run(tmp_path, "blank", s) for s in range(3)]
    assert [r.best_val for r in runs] == [0.9, 0.7, 0.85]
    assert best_of(runs, 1)["offline_align"] == pytest.approx((0.80 + 0.99 + 0.60) / 3)
    # subsets {0,1} -> 0, {0,2} -> 0, {1,2} -> 2
    assert best_of(runs, 2)["offline_align"] == pytest.approx((0.80 + 0.80 + 0.60) / 3)
    assert best_of(runs, 3)["offline_align"] == pytest.approx(0.80)
    rest = dict.fromkeys(("online_f1_1", "online_align", "offline_f1_1"), 0.0)
    tie = [Run(4, 0.9, {"offline_align": 0.1, **rest}), Run(3, 0.9, {"offline_align": 0.7, **rest})]
    assert best_of(tie, 2)["offline_align"] == pytest.approx(0.7)  # ties: the lower seed
    with pytest.raises(SubsetError, match="N=4"):
        best_of(runs, 4)


def test_a_missing_run_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _write(tmp_path, "blank", [0.9], test_align=0.8)
    _write(tmp_path, "complete", [0.9], test_align=0.8)
    assert main(["--work", str(tmp_path), "--arm", "blank", "--against", "complete", "--seeds", "0",
                 "--n", "1"]) == 0
    assert "| 1 | 90.0 / 70.0 | 95.0 / 80.0 | 90.0 / 70.0 | 95.0 / 80.0 | +0.0 / +0.0 | +0.0 / +0.0 |" in \
        capsys.readouterr().out
    assert main(["--work", str(tmp_path), "--arm", "blank", "--against", "complete", "--seeds", "0-1"]) == 2
    err = capsys.readouterr().err
    assert "blank_seed1" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
