"""BENCHMARKS.md's table of targets is what ``bench/report.py`` makes from the committed latest.json.

Also: every target of ``bench/targets.py`` names a figure of ``bench/latest.json`` in the same unit,
every figure's area has the record of the run that measured it (the reserved ``_machine`` key, which
no figure reader takes for a figure), and ``bench/run_all.py`` records the machine and merges a
subset run's figures and machines over the previous ones.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Final

import pytest

ROOT: Final = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

import report  # noqa: E402
import run_all  # noqa: E402
from targets import MACHINE_KEY, TARGETS, Target  # noqa: E402

LATEST: Final = ROOT / "bench" / "latest.json"
DOC: Final = ROOT / "BENCHMARKS.md"
RECORD_KEYS: Final = {"areas", "cpu", "cores", "memory_gib", "gpu", "date", "commit", "quick"}


def latest() -> dict[str, Any]:
    return json.loads(LATEST.read_text(encoding="utf-8"))


def committed_block() -> str:
    text = DOC.read_text(encoding="utf-8")
    start, end = text.index(report.BEGIN), text.index(report.END) + len(report.END)
    return text[start:end]


def test_committed_table_is_the_generated_one() -> None:
    assert committed_block() == report.render(latest()), \
        "BENCHMARKS.md's table is stale: run .venv/bin/python bench/report.py"


def test_table_opens_benchmarks_md() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert text.index(report.BEGIN) < text.index("## History"), "the table must come before the history"


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.key)
def test_every_target_names_a_figure_in_its_unit(target: Target) -> None:
    figures = latest()
    assert target.key in figures, f"bench/latest.json has no {target.key}"
    assert figures[target.key]["unit"] == target.unit, target.key


def test_every_area_has_its_machine() -> None:
    figures = latest()
    records = figures[MACHINE_KEY]
    assert all(RECORD_KEYS <= set(record) for record in records), records
    areas = [area for record in records for area in record["areas"]]
    assert len(areas) == len(set(areas)), f"an area has two machines: {areas}"
    assert {key.split(".", 1)[0] for key in figures if key != MACHINE_KEY} == set(areas)


def test_a_figure_on_the_wrong_side_is_missed() -> None:
    target = Target("node.x", "x", "<=", 1.5, "ms", "here")
    figures = {"node.x": {"value": 1.5, "unit": "ms"}, MACHINE_KEY: []}
    assert "| met | not recorded |" in report.row(target, figures)
    figures["node.x"]["value"] = 1.51
    assert "| **missed** |" in report.row(target, figures)
    at_least = Target("a.b", "b", ">=", 3, "x", "here")
    assert at_least.met(3.0) and not at_least.met(2.9)


def test_a_changed_figure_changes_the_table() -> None:
    figures = latest()
    key = TARGETS[0].key
    figures[key] = {**figures[key], "value": figures[key]["value"] * 10 + 1}
    assert report.render(figures) != committed_block()


def test_bad_inputs_are_named() -> None:
    with pytest.raises(report.ReportError, match=r"no figure 'node\.x'"):
        report.row(Target("node.x", "x", "<=", 1, "ms", ""), {MACHINE_KEY: []})
    with pytest.raises(report.ReportError, match="unit"):
        report.row(Target("node.x", "x", "<=", 1, "ms", ""), {"node.x": {"value": 1, "unit": "us"}})
    with pytest.raises(report.ReportError, match="markers"):
        report.replace_block("# Benchmarks\n", "table")


def test_report_rewrites_only_the_block(tmp_path: Path) -> None:
    doc = tmp_path / "B.md"
    doc.write_text(f"before\n{report.BEGIN}\nold\n{report.END}\nafter\n", encoding="utf-8")
    assert report.main(["--latest", str(LATEST), "--doc", str(doc)]) == 0
    assert doc.read_text(encoding="utf-8") == f"before\n{report.render(latest())}\nafter\n"
    assert report.main(["--latest", str(tmp_path / "missing.json"), "--doc", str(doc)]) == 2


def test_run_all_records_this_machine() -> None:
    record = run_all.machine(["node", "model"], quick=True)
    assert RECORD_KEYS <= set(record)
    assert record["areas"] == ["model", "node"] and record["quick"] is True
    assert record["cpu"] and isinstance(record["cores"], int)


def test_a_subset_run_keeps_the_other_areas_and_their_machine() -> None:
    old = {"a.x": {"value": 1.0, "unit": "s"}, "b.y": {"value": 2.0, "unit": "s"},
           MACHINE_KEY: [{"areas": ["a", "b"], "date": "old"}]}
    new = {"b.y": {"value": 3.0, "unit": "s"}, MACHINE_KEY: [{"areas": ["b"], "date": "new"}]}
    merged = run_all.merge(old, new, {"b"})
    assert merged["a.x"] == old["a.x"] and merged["b.y"] == new["b.y"]
    assert merged[MACHINE_KEY] == [{"areas": ["a"], "date": "old"}, {"areas": ["b"], "date": "new"}]
    assert run_all.merge(old, new, set()) == new
