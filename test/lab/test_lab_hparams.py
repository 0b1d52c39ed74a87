"""The memory depth × size sweep: its grid and shards, resumability, the JSON/table builder, the figure."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from lab import hparams, report, report_hparams
from lab.hparams_figure import save_hparams_figure
from lab.pipeline import State
from lab.scoring import Evaluation
from lab.spec import ReproduceError
from ompn_ros.cli._common import missing_default_texts


def test_grid_is_every_n_m_seed_and_shards_partition_it(tmp_path: Path):
    cells = hparams.SweepSpec(tmp_path).cells()
    assert len(cells) == 27
    assert {(c.n_slots, c.slot_size) for c in cells} == {(n, m) for n in (2, 3, 4) for m in (32, 64, 128)}
    assert {c.seed for c in cells} == {0, 1, 2}
    shards = [hparams.SweepSpec(tmp_path, shard=(i, 2)).cells() for i in range(2)]
    assert sorted(shards[0] + shards[1], key=cells.index) == cells
    assert not set(shards[0]) & set(shards[1])


def test_a_cell_trains_the_reproduction_setting_with_its_memory_overrides():
    spec = hparams.Cell(3, 64, 2).run_spec(iterations=None)
    assert spec.name == "full_nosketch_n3_m64_seed2"
    assert spec.overrides == {"n_slots": 3, "slot_size": 64}
    assert spec.setting.name == "full_nosketch" and not spec.setting.sketch and spec.seed == 2
    assert spec.skip_trained


@pytest.mark.parametrize(
    "fields, match",
    [
        ({"shard": (2, 2)}, "--shard"),
        ({"n_slots": (0, 2)}, "--n"),
        ({"slot_sizes": ()}, "--m"),
        ({"seeds": (-1,)}, "--seeds"),
    ],
)
def test_bad_sweep_options_are_named(tmp_path: Path, fields: dict[str, Any], match: str):
    with pytest.raises(ReproduceError, match=match):
        hparams.SweepSpec(tmp_path, **fields)


def test_bad_shard_on_the_command_line_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    assert hparams.main(["--work", str(tmp_path), "--shard", "two"]) == 2
    err = capsys.readouterr().err
    assert "--shard must be I/N" in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists()


def _state(sweep: hparams.SweepSpec) -> State:
    state = State(
        hparams.reproduce_spec(sweep),
        {"train": {"iterations": 200}, "model": {"n_slots": 2, "slot_size": 128}},
    )
    state.data[False] = ([], [])
    return state


def _fake_run(calls: list[str], train_seconds: float = float("nan")) -> Any:
    def run_setting(spec: Any, pool: Any, test: Any, base: Any, work: Path) -> Evaluation:
        calls.append(spec.name)
        (work / "runs" / spec.name).mkdir(parents=True, exist_ok=True)
        return Evaluation(row={"align_acc": 0.9, "f1_tol1": 0.95, "train_seconds": train_seconds}, p_hat=[])

    return run_setting


def test_a_scored_run_is_skipped_and_a_run_of_another_length_is_not(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    calls: list[str] = []
    monkeypatch.setattr(hparams, "run_setting", _fake_run(calls))
    sweep = hparams.SweepSpec(tmp_path, results=tmp_path / "results")
    state, cell = _state(sweep), hparams.Cell(3, 32, 1)
    first = hparams.run_cell(state, sweep, cell)
    assert calls == ["full_nosketch_n3_m32_seed1"]
    assert first["row"]["train_seconds"] is None  # NaN is written as null
    again = hparams.run_cell(state, sweep, cell)
    assert calls == ["full_nosketch_n3_m32_seed1"] and again == first
    longer = hparams.SweepSpec(tmp_path, results=tmp_path / "results", iterations=300)
    hparams.run_cell(_state(longer), longer, cell)
    assert len(calls) == 2
    assert hparams.collect_rows(sweep)[0]["iterations"] == 300


def test_only_the_shipped_cell_adopts_reproduction_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(hparams, "run_setting", _fake_run([]))
    source = tmp_path / "repro"
    for seed in (0, 1):
        for part in ("best", "last"):
            (source / f"full_nosketch_seed{seed}" / part).mkdir(parents=True)
    sweep = hparams.SweepSpec(tmp_path / "work", results=tmp_path / "results", reuse_runs=source)
    state = _state(sweep)
    assert hparams.run_cell(state, sweep, hparams.Cell(2, 128, 0))["adopted"]
    assert (tmp_path / "work" / "runs" / "full_nosketch_n2_m128_seed0" / "best").is_dir()
    assert not hparams.run_cell(state, sweep, hparams.Cell(2, 64, 1))["adopted"]
    assert not hparams.run_cell(state, sweep, hparams.Cell(2, 128, 2))["adopted"]  # no such source run
    # a copy whose stored configuration differs is trained again (it has a train time): not adopted
    monkeypatch.setattr(hparams, "run_setting", _fake_run([], train_seconds=12.0))
    row = hparams.run_cell(state, sweep, hparams.Cell(2, 128, 1))
    assert not row["adopted"] and row["row"]["train_seconds"] == 12.0
    assert (tmp_path / "work" / "runs" / "full_nosketch_n2_m128_seed1" / "adopted_from.txt").is_file()
    built = report_hparams.build_doc([row, {**row, "adopted": True}], expected=2)
    assert built["meta"]["adopted_runs"] == []


def _row(n: int, m: int, seed: int, align: float, started: float = 0.0) -> dict[str, Any]:
    return {
        "n_slots": n,
        "slot_size": m,
        "seed": seed,
        "iterations": 200,
        "n_test": 300,
        "adopted": False,
        "started": started,
        "finished": started + 10.0,
        "stage_seconds": 10.0,
        "row": {"align_acc": align, "f1_tol1": 0.5, "train_seconds": None, "best_iteration": 100.0 + seed},
    }


def test_doc_has_mean_std_per_cell_and_the_paper_values_in_their_cells():
    rows = [_row(3, 64, 0, 0.80), _row(3, 64, 1, 0.90, started=5.0), _row(2, 128, 0, 0.70, started=30.0)]
    doc = report_hparams.build_doc(rows, expected=27)
    cell = doc["cells"]["n3_m64"]
    assert cell["metrics"]["align_acc"]["mean"] == pytest.approx(0.85)
    assert cell["metrics"]["align_acc"]["std"] == pytest.approx(0.05)  # population std
    assert cell["metrics"]["align_acc"]["n"] == 2
    assert cell["metrics"]["train_seconds"] == {"mean": None, "std": None, "n": 0}
    assert set(cell["seeds"]) == {"0", "1"} and cell["seeds"]["1"]["best_iteration"] == 101.0
    assert cell["paper_align"] == {"mean": 0.93, "std": 0.017}
    assert doc["cells"]["n2_m128"]["paper_align"] is None
    assert list(doc["cells"]) == ["n2_m128", "n3_m64"]
    assert doc["meta"]["partial"] and doc["meta"]["runs"] == 3
    assert doc["meta"]["wall_seconds"] == pytest.approx(40.0)


def test_paper_table_is_the_five_cell_cross():
    assert set(report_hparams.PAPER_ALIGN) == {(3, 64), (2, 64), (4, 64), (3, 32), (3, 128)}
    assert report_hparams.PAPER_ALIGN[(2, 64)] == (0.96, 0.014)


def test_readme_section_places_paper_numbers_in_brackets(tmp_path: Path):
    assert report_hparams.hparams_markdown(tmp_path) == []
    rows = [_row(3, 64, 0, 0.80), _row(3, 64, 1, 0.90), _row(2, 128, 0, 0.70)]
    report_hparams.write_doc(tmp_path, report_hparams.build_doc(rows, expected=27))
    text = report.render_readme(tmp_path)
    assert "memory depth n × slot size m" in text and "partial: 3 of 27 runs" in text
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| n \\ m |"))
    assert lines[start] == "| n \\ m | 64 | 128 |"
    assert lines[start + 2] == "| 2 | – | 70.0 (0.0) |"
    assert lines[start + 3] == "| 3 | 85.0 (5.0) [93 (1.7)] | – |"


def test_detail_rows_are_sorted_by_n_then_m_as_numbers(tmp_path: Path):
    rows = [_row(2, 128, 0, 0.9), _row(2, 32, 0, 0.7), _row(3, 64, 0, 0.8)]
    report_hparams.write_doc(tmp_path, report_hparams.build_doc(rows, expected=27))
    lines = report_hparams.hparams_markdown(tmp_path)
    start = next(i for i, line in enumerate(lines) if line.startswith("| n | m |"))
    assert [tuple(line.split(" | ")[:2]) for line in lines[start + 2 : start + 5]] == [
        ("| 2", "32"),
        ("| 2", "128"),
        ("| 3", "64"),
    ]


def test_figure_is_written(tmp_path: Path):
    rows = [_row(n, m, s, 0.8 + 0.01 * s) for n in (2, 3) for m in (32, 64) for s in (0, 1)]
    path = save_hparams_figure(report_hparams.build_doc(rows, expected=8), tmp_path / "f" / "h.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_without_runs_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    assert hparams.main(["--work", str(tmp_path), "--results", str(tmp_path / "r"), "--report"]) == 2
    assert "no scored runs" in capsys.readouterr().err


def test_report_collects_the_row_files_of_every_shard(tmp_path: Path):
    for n, m, seed in ((2, 32, 0), (4, 128, 2)):
        run_dir = tmp_path / "runs" / hparams.Cell(n, m, seed).run_spec(None).name
        run_dir.mkdir(parents=True)
        (run_dir / hparams.ROW_FILE).write_text(json.dumps(_row(n, m, seed, 0.9)))
    results = tmp_path / "results"
    assert hparams.main(["--work", str(tmp_path), "--results", str(results), "--report"]) == 0
    doc = json.loads((results / report_hparams.FILE).read_text())
    assert set(doc["cells"]) == {"n2_m32", "n4_m128"} and doc["meta"]["expected_runs"] == 27
    assert (results / "figures" / report_hparams.FIGURE).is_file()
    assert "n \\ m" in (results / report.README).read_text()


def test_every_option_says_what_happens_without_it():
    assert missing_default_texts(hparams.build_parser()) == []
