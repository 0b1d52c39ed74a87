"""The transfer table (lab.transfer): each default against its reference over the same seeds, the
verdict at 2 points, and its section of results/README.md."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from own_data_rows import _row

from lab import report, report_own, transfer


def _write(results: Path, rows: list[dict]) -> None:
    results.mkdir(exist_ok=True)
    (results / report_own.OWN_DATA).write_text(json.dumps({"meta": {"command": ["x"]}, "rows": rows}))


def test_a_default_that_loses_more_than_2_points_elsewhere_is_marked(tmp_path: Path) -> None:
    rows = []
    for seed in (10, 11):
        rows += [
            _row(f"final_craft_full_complete_seed{seed}", offline_align=0.90),
            _row(f"final_craft_full_blank_best2_seed{seed}", offline_align=0.91),  # holds: +1 point
            _row(f"human_craft_full_complete_seed{seed}", offline_align=0.80, online_f1_1=0.80),
            # loses 3 points of online F1@1 against the same family's complete bags
            _row(f"human_craft_full_blank_best2_seed{seed}", offline_align=0.81, online_f1_1=0.77),
        ]
    rows.append(_row("human_craft_full_blank_best2_seed13"))  # no complete twin: left out of the means
    _write(tmp_path, rows)
    assert transfer.main([str(tmp_path)]) == 0
    doc = json.loads((tmp_path / transfer.TRANSFER).read_text())
    by_family = {(r["default"], r["family"]): r for r in doc["rows"]}
    expert = by_family[("final_observation: blank, best of 2 (Craft)", "Craft full, expert")]
    human = by_family[("final_observation: blank, best of 2 (Craft)", "Craft full, human-like")]
    assert expert["holds"] and expert["seeds"] == [10, 11]
    assert expert["gap"]["offline_align"] == pytest.approx(0.01)
    assert not human["holds"] and human["seeds"] == [10, 11]
    assert human["gap"]["online_f1_1"] == pytest.approx(-0.03)
    shift = by_family[("demonstrator: human-like against expert (Craft)", "Craft full, complete bags")]
    assert shift["gap"]["offline_align"] == pytest.approx(-0.10) and not shift["holds"]
    assert not any("Dial" in r["family"] for r in doc["rows"])  # no Dial arms: no Dial checks
    text = (tmp_path / "README.md").read_text()
    assert text == report.render_readme(tmp_path)
    assert "| final_observation: blank, best of 2 (Craft) | Craft full, expert, seeds 0–9 | Craft full, " \
        "human-like | the family | 10, 11 | complete bags, one run | 90.0 / 81.0 | +0.0 / +1.0 | " \
        "77.0 / 75.0 | " \
        "-3.0 / +0.0 | loses more than 2 points |" in text.splitlines()


def test_the_restart_check_pairs_the_runs_with_and_without_the_rule(tmp_path: Path) -> None:
    _write(tmp_path, [
        _row("human_craft_full_complete_seed11", offline_align=0.70),
        _row("human_craft_full_complete_norestart_seed11", offline_align=0.75),
    ])
    assert transfer.main([str(tmp_path)]) == 0
    rows = json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
    restart = next(r for r in rows if r["default"].startswith("restart rule"))
    assert restart["seeds"] == [11] and restart["gap"]["offline_align"] == pytest.approx(-0.05)
    assert not restart["holds"]
    assert "earlier_restart_rule" not in restart


def test_runs_under_the_earlier_restart_rule_are_named(tmp_path: Path) -> None:
    _write(tmp_path, [
        {**_row("human_craft_full_complete_seed11"), "restart_abandoned": 1},
        _row("human_craft_full_complete_norestart_seed11"),
        _row("human_craft_full_complete_seed12"),
        _row("human_craft_full_complete_norestart_seed12"),
    ])
    assert transfer.main([str(tmp_path)]) == 0
    rows = json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
    restart = next(r for r in rows if r["default"].startswith("restart rule"))
    assert restart["seeds"] == [11, 12] and restart["earlier_restart_rule"] == 1
    assert "| Craft full, human-like, the runs it restarted (1 run under the earlier restart rule) |" in \
        (tmp_path / "README.md").read_text()


def test_without_own_data_the_command_says_what_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert transfer.main([str(tmp_path)]) == 2
    assert "lab.own_data collate" in capsys.readouterr().err


def _family(name: str, role: str, old: tuple[float, float], new: tuple[float, float]) -> dict:
    arms = [{"arm": f"human_dial_complete_seed{s}"} for s in (5, 6)]
    return {"family": name, "role": role, "runs": 2, "changed": 1, "arms": arms, "means": {
        "previous": {"f1_1": old[0], "align": old[1]}, "one_se": {"f1_1": new[0], "align": new[1]},
        "test_oracle": {"f1_1": 0.9, "align": 0.9}}}


def test_the_detector_rule_is_checked_on_the_families_kept_out_of_its_choice(tmp_path: Path) -> None:
    _write(tmp_path, [_row("human_craft_full_complete_seed11")])
    families = [
        _family("seen", "seen while choosing the rule", (0.5, 0.5), (0.1, 0.1)),  # not a check
        _family("Dial human-like", "kept out", (0.60, 0.87), (0.65, 0.86)),
        _family("Craft human-like", "kept out", (0.81, 0.61), (0.78, 0.62)),  # F1@1 -3: loses
    ]
    (tmp_path / "detector_selection.json").write_text(json.dumps(
        {"meta": {"command": ["y"], "date": "d", "held_out": "h"}, "families": families}))
    assert transfer.main([str(tmp_path)]) == 0
    rows = [r for r in json.loads((tmp_path / transfer.TRANSFER).read_text())["rows"]
            if r["default"].startswith("detector selection")]
    assert [r["family"] for r in rows] == ["Dial human-like", "Craft human-like"]
    assert rows[0]["holds"] and rows[0]["gap"]["online_f1_1"] == pytest.approx(0.05)
    assert not rows[1]["holds"] and rows[0]["seeds"] == [5, 6]
    text = (tmp_path / "README.md").read_text()
    assert ("| Dial human-like | kept out | 2 | 1 | 60.0 / 87.0 | 65.0 / 86.0 | +5.0 / -1.0 | 90.0 / 90.0 "
            "| – |") in text.splitlines()  # a file from before the bundled column
    families[2]["means"]["bundled"] = {"f1_1": 0.84, "align": 0.79}
    (tmp_path / "detector_selection.json").write_text(json.dumps(
        {"meta": {"command": ["y"], "date": "d", "held_out": "h"}, "families": families}))
    assert transfer.main([str(tmp_path)]) == 0
    assert ("| Craft human-like | kept out | 2 | 1 | 81.0 / 61.0 | 78.0 / 62.0 | -3.0 / +1.0 | 90.0 / 90.0 "
            "| 84.0 / 79.0 |") in (tmp_path / "README.md").read_text().splitlines()
