"""The reproduction scores what a user gets: ``ompn_train``'s checkpoint with the detector it bundled.

No training here: the plan's commands are parsed by the product's own CLIs, and the scoring is run on a
run directory laid out as ``ompn_train`` and ``ompn_segment`` leave it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

import ompn_ros
from lab import reproduce_product as rp
from lab.spec import REPRODUCTION_ITERATIONS, SETTINGS
from ompn_ros.app.segment_setup import detector_settings
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.cli import segment as segment_cli
from ompn_ros.cli import train as train_cli

PLANS = [(d, s) for d in sorted(SETTINGS) for s in SETTINGS[d]]


def _value(argv: list[str], flag: str) -> str:
    return argv[argv.index(flag) + 1]


@pytest.mark.parametrize(("domain", "setting"), PLANS)
def test_each_run_is_scored_by_ompn_segment_with_the_checkpoint_ompn_train_wrote(
    domain: str, setting: str, tmp_path: Path
) -> None:
    steps = rp.run_commands(domain, setting, 3, tmp_path, REPRODUCTION_ITERATIONS[domain])
    assert list(steps) == ["train", "segment"]
    train, segment = steps["train"], steps["segment"]
    assert train[0] == "ompn_train" and segment[0] == "ompn_segment"
    trained = train_cli.build_parser().parse_args(train[1:])
    scored = segment_cli.build_parser().parse_args(segment[1:])
    assert Path(scored.checkpoint) == trained.out / "best"
    assert scored.detector_config is None, "segment must run the checkpoint's own detector.json"
    assert not any(o.startswith(("detector", "model.detector")) for o in trained.overrides), trained.overrides
    assert "train.seed=3" in trained.overrides
    assert f"train.iterations={REPRODUCTION_ITERATIONS[domain]}" in trained.overrides
    assert ("model.sketch_mode=sum" in trained.overrides) == SETTINGS[domain][setting].sketch
    collected = rp.collect_commands(domain, SETTINGS[domain][setting], tmp_path)
    bags = {_value(argv, "--out") for argv in collected.values()}
    assert {str(trained.bags[0]), scored.bag} == bags


def test_ompn_segment_without_a_detector_config_runs_the_bundled_detector(tmp_path: Path) -> None:
    checkpoint = tmp_path / "best"
    shutil.copytree(shipped_checkpoint("dial"), checkpoint)
    doc = json.loads((checkpoint / "detector.json").read_text())
    doc["online"]["high"] = 0.123  # a value no default or shipped setting has
    (checkpoint / "detector.json").write_text(json.dumps(doc))
    settings, _ = detector_settings(str(checkpoint), None)
    assert settings.online.high == pytest.approx(0.123)


def _metrics(online: float, tuned: float) -> dict[str, Any]:
    def block(value: float) -> dict[str, float]:
        return {k: value for k in rp.ONLINE_KEYS}

    return {"online": block(online), "online_tuned": block(tuned), "offline_topk": block(0.9),
            "offline_auto": block(0.8), "offline_thr0.5": block(0.1)}


def _finished_run(work: Path, domain: str, seed: int, online: float, mode: str) -> dict[str, list[str]]:
    steps = rp.run_commands(domain, next(iter(SETTINGS[domain])), seed, work, 5)
    run = Path(_value(steps["train"], "--out"))
    (run / "best").mkdir(parents=True)
    (run / "best" / "detector.json").write_text(json.dumps({"online": {"mode": mode}, "source": "tuned"}))
    (run / "summary.json").write_text(json.dumps({"train_seconds": 10.0 + seed, "best_iteration": 100,
                                                  "iterations": 200, "restarts": 0}))
    scored = Path(_value(steps["segment"], "--out"))
    scored.mkdir(parents=True)
    (scored / "metrics.json").write_text(json.dumps(_metrics(online, tuned=0.01)))
    return steps


@pytest.mark.parametrize(("domain", "paper"), [("craft", 0.9), ("dial", 0.8)])
def test_scores_are_the_bundled_detector_online_and_the_paper_detector_offline(
    domain: str, paper: float, tmp_path: Path
) -> None:
    rows, records = [], []
    for seed, online in ((0, 0.5), (1, 0.7)):
        row, record = rp.score_run(domain, _finished_run(tmp_path, domain, seed, online, "head"))
        rows.append(row)
        records.append(record)
    assert [r["online_f1_tol1"] for r in rows] == [0.5, 0.7]
    assert all(r["align"] == paper and r["f1_tol1"] == paper for r in rows)
    assert {r["detector_mode"] for r in records} == {"head"}
    cells = rp.aggregate(rows)
    assert cells["online_align"] == {"mean": pytest.approx(0.6), "std": pytest.approx(0.1), "n": 2}
    assert cells["train_seconds"]["mean"] == pytest.approx(10.5)


def test_the_result_file_names_its_version_commands_seeds_and_settings(tmp_path: Path) -> None:
    steps = _finished_run(tmp_path / "work", "dial", 0, 0.6, "threshold")
    row, record = rp.score_run("dial", steps)
    args = rp.build_parser().parse_args(["dial", "--settings", "nosketch", "--seeds", "1"])
    args.argv, args.settings, args.iterations, args.work = ["dial", "--seeds", "1"], ["nosketch"], 5, tmp_path
    target = rp.write_results(tmp_path / "results", "dial", {"nosketch": rp.aggregate([row])},
                              rp.provenance("dial", args, {"nosketch": {"0": record}}))
    doc = json.loads(target.read_text())
    prov = doc["provenance"]
    assert prov["version"] == ompn_ros.__version__ and prov["pipeline"] == rp.PIPELINE
    assert prov["seeds"] == [0] and prov["settings"] == ["nosketch"]
    assert prov["runs"]["nosketch"]["0"]["commands"]["train"].startswith("ompn_train ")
    assert set(prov["collect"]) == {"collect_full_train", "collect_full_test"}
    assert doc["settings"]["nosketch"]["online_align"]["mean"] == pytest.approx(0.6)


def test_unknown_settings_are_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert rp.main(["craft", "--settings", "full_nosketch,fulll"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "fulll" in err and "full_sketch" in err


def test_a_note_goes_to_the_provenance_not_into_the_recorded_command() -> None:
    assert rp._without_note(["dial", "--note", "seed 0 reused", "--seeds", "1", "--note=x"]) == [
        "dial", "--seeds", "1"]
