"""The result files: stable table ids, and results/README.md is what the generator makes of the JSON."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from lab import report

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results"


def test_committed_readme_is_generated_from_the_committed_json():
    assert (RESULTS / "README.md").read_text(encoding="utf-8") == report.render_readme(RESULTS)


@pytest.mark.parametrize("domain", report.DOMAINS)
def test_committed_extras_have_stable_ids_titles_and_rows(domain: str):
    doc = json.loads((RESULTS / f"{domain}_extras.json").read_text())
    assert set(doc) == {"extras", "meta"}
    assert set(doc["extras"]) <= set(report.EXTRA_IDS)
    for table in doc["extras"].values():
        assert set(table) == {"title", "rows"} and table["title"] and table["rows"]
    assert "ablations" in doc["extras"]


def _cell(mean: float, std: float = 0.0, n: int = 2) -> dict[str, float]:
    return {"mean": mean, "std": std, "n": n}


def _write_tiny(results: Path) -> None:
    row = {
        k: _cell(0.5)
        for k in (
            "align_acc",
            "f1_tol1",
            "f1_tol0",
            "online_f1_tol1",
            "online_align_strict",
            "online_delay_mean",
            "online_false_alarms_per_episode",
        )
    }
    extras = {
        "k_sweep": report.table(
            report.k_sweep_title("full_nosketch"),
            {"K=2": {"f1_tol1": 0.25, "precision_tol1": 1.0, "recall_tol1": 0.125}},
        ),
        "ensembles_per_seed": report.table(
            report.ensembles_per_seed_title(2),
            {"full_nosketch": {"members": _cell(3.0), "online_delay_mean": _cell(0.5, 0.25)}},
        ),
    }
    meta = {
        "seeds": 2,
        "stages": {"train": 1.0},
        "total_seconds": 2.0,
        "n_test": {"full": 6},
        "figures": [],
        "command": ["python -m lab.reproduce", "craft"],
    }
    report.write_results(results, "craft", {"full_nosketch": row}, extras, meta)


def test_written_tables_render_fractions_counts_and_steps(tmp_path: Path):
    _write_tiny(tmp_path)
    text = (tmp_path / "README.md").read_text()
    assert text == report.render_readme(tmp_path)
    assert "| full_nosketch | 50.0 (0.0) | 50.0 (0.0) |" in text  # fractions in %
    assert "### K sweep (full_nosketch, seed 0, tol=1)" in text
    assert "| K=2 | 25.0 | 100.0 | 12.5 |" in text
    per_seed = next(line for line in text.splitlines() if line.startswith("| full_nosketch | 3 (0)"))
    assert per_seed.endswith("| 0.50 (0.25) |")  # members a count, the delay in steps
    assert "## dial" not in text  # only domains with results


def test_unknown_table_ids_are_refused(tmp_path: Path):
    with pytest.raises(ValueError, match="unknown table ids"):
        report.write_results(tmp_path, "craft", {}, {"K sweep": report.table("K sweep", {})}, {})


def test_report_command_regenerates_the_readme(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    for source in RESULTS.glob("*.json"):  # the domains' files and the own-data / own-robot ones
        shutil.copy(source, tmp_path / source.name)
    assert report.main([str(tmp_path)]) == 0
    assert (tmp_path / "README.md").read_text() == (RESULTS / "README.md").read_text()
    assert report.main([str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_ompn_reproduce_report_only_regenerates_the_readme(tmp_path: Path):
    from lab import reproduce

    _write_tiny(tmp_path)
    (tmp_path / "README.md").write_text("stale\n")
    assert reproduce.main(["--report-only", "--results", str(tmp_path)]) == 0
    assert (tmp_path / "README.md").read_text() == report.render_readme(tmp_path)
