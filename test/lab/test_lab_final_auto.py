"""The final_observation: auto study (lab.final_auto): its families name real arms, each seed keeps the
option the product's rule keeps and reports that run's test figures, and the transfer table and README
show it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lab_cache import write_cache

from lab import final_auto as study
from lab import transfer
from lab.own_data import ARMS


def test_every_family_names_arms_of_the_own_data_study() -> None:
    for family in study.FAMILIES:
        patterns = [p for _, p in family.options] + [family.reference]
        names = [study.arm_name(p, s) for p in patterns for s in family.seeds]
        assert all(name in ARMS for name in names), [n for n in names if n not in ARMS]
        assert [o for o, _ in family.options] == ["extrapolate", "duplicate"]  # the preset's first


def test_each_seed_keeps_the_run_validation_prefers_and_reports_its_test_figures(tmp_path: Path) -> None:
    family = study.FAMILIES[0]
    write_cache(tmp_path, "human_dial_extrapolate_seed5", sharp=False)
    write_cache(tmp_path, "human_dial_duplicate_seed5", sharp=True)
    write_cache(tmp_path, "human_dial_complete_seed5", sharp=True)
    row = study.seed_row(family, 5, tmp_path)
    assert row["kept"] == "duplicate"
    assert row["options"]["duplicate"]["val_align"] > row["options"]["extrapolate"]["val_align"]
    kept = row["options"]["duplicate"]
    assert row["auto"] == {k: kept[k] for k in study.FIGURES}
    assert row["auto"]["online_f1_1"] > row["options"]["extrapolate"]["online_f1_1"]
    assert row["complete"] == study.score_run("human_dial_complete_seed5", tmp_path)["test"]


def _family_doc(auto: float, complete: float) -> dict:
    means = {k: dict.fromkeys(study.FIGURES, v) for k, v in
             (("auto", auto), ("complete", complete), ("extrapolate", 0.5), ("duplicate", 0.6))}
    return {"family": "Dial, human-like", "role": "kept out", "kept_out_of_tuning": "the family",
            "seeds": [5, 6], "kept": {"extrapolate": 1, "duplicate": 1}, "means": means, "per_seed": []}


@pytest.mark.parametrize(("auto", "holds"), [(0.79, True), (0.77, False)])
def test_the_transfer_table_checks_auto_against_complete_bags(tmp_path: Path, auto: float,
                                                              holds: bool) -> None:
    (tmp_path / "own_data.json").write_text(json.dumps({"meta": {}, "rows": []}))
    (tmp_path / "final_auto.json").write_text(json.dumps(
        {"meta": {"command": ["x"], "date": "d", "held_out": "h", "detector": "one SE"},
         "families": [_family_doc(auto, 0.8)]}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
    assert [r["holds"] for r in rows if r["default"].startswith("final_observation: auto")] == [holds]
    lines = (tmp_path / "README.md").read_text().splitlines()
    shown = f"{100 * auto:.1f} / {100 * auto:.1f}"
    assert f"| Dial, human-like (seeds 5–6; kept out) | auto | – | {shown} | {shown} |" in lines
    assert "|  | duplicate alone | 1 of 2 | 60.0 / 60.0 | 60.0 / 60.0 |" in lines
