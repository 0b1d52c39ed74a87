"""The committed reproduction results: the issue's JSON shape, and the README quotes them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {
    "craft": {"full_nosketch": "Craft full, no sketch", "partial_nosketch": "Craft partial, no sketch",
              "full_sketch": "Craft full, sketch", "partial_sketch": "Craft partial, sketch"},
    "dial": {"nosketch": "Dial, no sketch (auto threshold)", "sketch": "Dial, sketch (auto threshold)"},
}


@pytest.mark.parametrize("domain", sorted(SETTINGS))
def test_results_json_has_the_documented_shape(domain: str) -> None:
    results = json.loads((ROOT / "results" / f"{domain}.json").read_text())
    meta = json.loads((ROOT / "results" / f"{domain}_extras.json").read_text())["meta"]
    assert set(results) == set(SETTINGS[domain])
    for setting, row in results.items():
        for metric in ("align_acc", "f1_tol1", "f1_tol0", "online_f1_tol1"):
            cell = row[metric]
            assert set(cell) == {"mean", "std", "n"}, (setting, metric)
            assert 0.0 <= cell["mean"] <= 1.0 and cell["std"] >= 0.0, (setting, metric)
            assert cell["n"] == meta["seeds"], (setting, metric)


@pytest.mark.parametrize("domain", sorted(SETTINGS))
def test_readme_table_quotes_the_committed_results(domain: str) -> None:
    results = json.loads((ROOT / "results" / f"{domain}.json").read_text())
    readme = (ROOT / "README.md").read_text()
    for setting, label in SETTINGS[domain].items():
        row = next((line for line in readme.splitlines() if line.startswith(f"| {label} |")), None)
        assert row is not None, f"README has no results row for {label}"
        cells = [c.strip() for c in row.strip("|").split("|")]
        for column, metric in ((1, "align_acc"), (2, "f1_tol1")):
            cell = results[setting][metric]
            assert cells[column] == f"{100 * cell['mean']:.1f} ± {100 * cell['std']:.1f}", (label, metric)


@pytest.mark.parametrize("domain", sorted(SETTINGS))
def test_readme_ensemble_table_quotes_the_committed_extras(domain: str) -> None:
    extras = json.loads((ROOT / "results" / f"{domain}_extras.json").read_text())["extras"]
    results = json.loads((ROOT / "results" / f"{domain}.json").read_text())
    ensemble = next(table for title, table in extras.items() if title.startswith("Ensemble of the 5 seeds"))
    lines = [line.strip() for line in (ROOT / "README.md").read_text().splitlines()]
    for setting, label in SETTINGS[domain].items():
        row = next((line for line in lines if line.startswith(f"| {label}, ensemble of 5 |")), None)
        assert row is not None, f"README has no ensemble row for {label}"
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[1] == f"{100 * ensemble[setting]['align_acc']:.1f}", label
        assert cells[2] == f"{100 * ensemble[setting]['f1_tol1']:.1f}", label
        single = results[setting]
        assert cells[3] == f"{100 * single['align_acc']['mean']:.1f} / {100 * single['f1_tol1']['mean']:.1f}"


@pytest.mark.parametrize("domain", sorted(SETTINGS))
def test_readme_quotes_the_constrained_detector_columns(domain: str) -> None:
    results = json.loads((ROOT / "results" / f"{domain}.json").read_text())
    readme = (ROOT / "README.md").read_text()
    for setting, label in SETTINGS[domain].items():
        row = next(line for line in readme.splitlines() if line.startswith(f"| {label} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        for column, metric in ((4, "constrained_align"), (5, "constrained_f1_tol1")):
            cell = results[setting][metric]
            assert cells[column] == f"{100 * cell['mean']:.1f} ± {100 * cell['std']:.1f}", (label, metric)


def test_readme_quotes_the_per_seed_ensembles() -> None:
    extras = json.loads((ROOT / "results" / "craft_extras.json").read_text())["extras"]
    table = next(t for title, t in extras.items() if title.startswith("Ensembles per seed"))
    lines = [line.strip() for line in (ROOT / "README.md").read_text().splitlines()]
    assert set(table) == {"full_nosketch", "partial_nosketch"}
    for setting, row in table.items():
        label = f"{SETTINGS['craft'][setting]}, ensembles of {int(row['members']['mean'])}"
        line = next((x for x in lines if x.startswith(f"| {label} |")), None)
        assert line is not None, f"README has no row for {label}"
        cells = [c.strip() for c in line.strip("|").split("|")]
        metrics = ("constrained_align", "constrained_f1_tol1", "align_acc", "f1_tol1", "online_f1_tol1")
        for column, metric in enumerate(metrics, start=1):
            cell = row[metric]
            assert cell["n"] == 5, (setting, metric)
            assert cells[column] == f"{100 * cell['mean']:.1f} ± {100 * cell['std']:.1f}", (label, metric)
