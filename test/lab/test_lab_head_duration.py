"""The study of mode 'head_hsmm' on the own-data runs (lab.head_duration): its families, their means
from the cached per-run rows, and the README section."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lab import head_duration as hd
from lab import transfer
from lab.own_data import ARMS
from lab.report import render_readme


def test_every_family_names_arms_of_the_own_data_study_and_the_design_runs_are_apart() -> None:
    for _, role, arms in hd.FAMILIES:
        assert role in ("design", "held out", "kept out")
        assert arms and all(arm in ARMS for arm in arms)
    design = {a for _, role, arms in hd.FAMILIES if role == "design" for a in arms}
    others = {a for _, role, arms in hd.FAMILIES if role != "design" for a in arms}
    assert design and others and not design & others


def _figures(f1: float, align: float, delay: float = 3.0) -> dict[str, float]:
    return {"f1_tol1": f1, "align": align, "delay_mean": delay, "at_end_share": 0.1,
            "false_alarms_per_episode": 0.2}


def _cache(work: Path, arm: str, now: str, align: float) -> None:
    row = {"arm": arm, "modes": {"previous": "hsmm", "head_hsmm": "head_hsmm", "now": now},
           "offline": {"f1_tol1": 0.9, "align": 0.85}, "previous": _figures(0.9, 0.8),
           "head_hsmm": _figures(0.92, align), "now": _figures(0.92, align if now == "head_hsmm" else 0.8)}
    trained = {"arm": arm, "online_f1_1": 0.91, "online_align": 0.7}
    for folder, doc in (("head_check", row), ("arms", trained)):
        (work / folder).mkdir(parents=True, exist_ok=True)
        (work / folder / f"{arm}.json").write_text(json.dumps(doc))


def test_families_average_their_cached_runs_and_the_readme_shows_them(tmp_path: Path) -> None:
    family, role, arms = hd.FAMILIES[1]
    for arm, now, align in zip(arms, ("head_hsmm", "hsmm", "head_hsmm"), (0.9, 0.78, 0.87), strict=True):
        _cache(tmp_path, arm, now, align)
    rows = hd.family_rows(tmp_path)
    assert [r["family"] for r in rows] == [family]  # the others have no trained runs here
    means = rows[0]["means"]
    assert means["head_hsmm"]["align"] == pytest.approx(0.85)
    assert means["now"]["align"] == pytest.approx((0.9 + 0.8 + 0.87) / 3)
    assert means["now_head_hsmm_runs"] == {"runs": 2}
    meta = {"command": ["x"], "date": "d", **hd.META}
    (tmp_path / hd.RESULTS).write_text(json.dumps({"meta": meta, "families": rows}))
    text = render_readme(tmp_path)
    assert means["threshold"] == {"f1_tol1": pytest.approx(0.91), "align": pytest.approx(0.7)}
    assert means["head_hsmm_any_delay"] is None  # not in these rows
    assert (f"| {family} | {role} | 3 | 90.0 / 85.0 | 91.0 / 70.0 | 90.0 / 80.0, 3.0 steps, 10.0 % at end | "
            "92.0 / 85.0, 3.0 steps, 10.0 % at end | – | 92.0 / 85.7, 3.0 steps, 10.0 % at end "
            "(head_hsmm in 2) |") in text


def test_the_transfer_table_weighs_the_delay_budget_of_the_mode_where_it_runs(tmp_path: Path) -> None:
    def family(name: str, role: str, runs: int, budget: float, none: float) -> dict:
        means = {"head_hsmm": _figures(0.9, budget, 3.0), "head_hsmm_any_delay": _figures(0.9, none, 9.0),
                 "now_head_hsmm_runs": {"runs": runs}}
        return {"family": name, "role": role, "seeds": [12, 13, 14], "means": means}

    families = [family("design", "design", 2, 0.8, 0.9), family("a", "held out", 3, 0.85, 0.86),
                family("b", "kept out", 2, 0.7, 0.75), family("c", "kept out", 0, 0.5, 0.9)]
    doc = {"meta": {}, "families": families}
    (tmp_path / hd.RESULTS).write_text(json.dumps(doc))
    rows = transfer.head_budget_rows(tmp_path)
    assert [r["family"] for r in rows] == ["a", "b"]  # not the design runs, not where it never runs
    assert rows[0]["kept_out_of_tuning"] == "seeds 12–14" and rows[1]["kept_out_of_tuning"] == "the family"
    assert rows[0]["gap"]["online_align"] == pytest.approx(-0.01) and rows[0]["holds"]
    assert rows[1]["gap"]["online_align"] == pytest.approx(-0.05) and not rows[1]["holds"]
    assert "no budget (mean delay 9.0 steps, 10 % at the end; 3.0 steps" in rows[0]["reference"]
