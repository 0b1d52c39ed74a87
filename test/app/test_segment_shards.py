"""``ompn_segment --num-shards N --shard-index I`` and ``ompn_segment aggregate``: a dataset split over
separate processes (as over machines or array tasks) gives the table of one run, row for row."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from batch_bags import SPEC, write_lab_bag

from ompn_ros.app.shards import select, shard_of
from ompn_ros.cli.segment import main
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig

ROOT = Path(__file__).resolve().parents[2]
SHARDS = 3


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("shards")
    for i in range(9):
        write_lab_bag(root / "bags" / f"day{i % 3}" / f"run{i}", 40 + i, episodes=2, steps=24)
    spec = root / "lab_reader.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    config = OMPNConfig(obs_dim=4, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)
    save_checkpoint(root / "model", build_policy(config))
    return {"root": root, "bags": root / "bags", "spec": spec, "model": root / "model"}


def _args(lab: dict[str, Path], out: Path) -> list[str]:
    return ["--bags", str(lab["bags"]), "--checkpoint", str(lab["model"]),
            "--reader-config", str(lab["spec"]), "--out", str(out)]


def _shard(lab: dict[str, Path], out: Path, index: int) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "ompn_ros.cli.segment", *_args(lab, out), "--num-shards", str(SHARDS),
               "--shard-index", str(index)]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_the_assignment_is_stable_and_splits_every_item_once() -> None:
    keys = [f"day{i % 7}__run{i}" for i in range(300)]
    parts = [[k for _, k in select(keys, str, 4, index)] for index in range(4)]
    assert sorted(k for part in parts for k in part) == sorted(keys)
    assert all(40 <= len(part) <= 110 for part in parts)  # a hash spreads them
    assert [shard_of(k, 4) for k in keys] == [shard_of(k, 4) for k in reversed(keys)][::-1]
    assert select(keys[:50], str, 4, 1) == [(p, k) for p, k in select(keys, str, 4, 1) if p < 50]


def test_three_shards_equal_one_run_row_for_row(lab: dict[str, Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    whole = tmp_path / "whole"
    assert main(_args(lab, whole)) == 0
    shared = tmp_path / "shared"
    procs = [_shard(lab, shared, index) for index in range(SHARDS)]  # side by side, one folder
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0 and "Traceback" not in err, err[-3000:]
    assert not (shared / "segments.csv").exists()  # a shard writes its own table only
    manifests = [json.loads((shared / "shards" / f"{i}-of-{SHARDS}" / "manifest.json").read_text())
                 for i in range(SHARDS)]
    assert sorted(item["key"] for m in manifests for item in m["items"]) == sorted(
        p.stem for p in (whole / "bags").glob("*.json"))
    capsys.readouterr()
    assert main(["aggregate", str(shared), "--out", str(tmp_path / "merged")]) == 0
    assert (tmp_path / "merged" / "segments.csv").read_text() == (whole / "segments.csv").read_text()
    merged = json.loads((tmp_path / "merged" / "summary.json").read_text())
    assert merged["shards"] == {"count": 3, "complete": [0, 1, 2], "missing": [], "failed": {}}
    assert merged["segments"] == json.loads((whole / "summary.json").read_text())["segments"]
    metrics = json.loads((tmp_path / "merged" / "metrics.json").read_text())
    assert metrics == json.loads((whole / "metrics.json").read_text())

    # one folder per machine: each holds its shard's manifest and records only
    machines = []
    for index, manifest in enumerate(manifests):
        machine = tmp_path / f"machine{index}"
        part = machine / "shards" / f"{index}-of-{SHARDS}"
        shutil.copytree(shared / "shards" / f"{index}-of-{SHARDS}", part)
        (machine / "bags").mkdir()
        for item in manifest["items"]:
            shutil.copy(shared / "bags" / f"{item['key']}.json", machine / "bags")
        machines.append(str(machine))
    assert main(["aggregate", *machines, "--out", str(tmp_path / "final")]) == 0
    assert (tmp_path / "final" / "segments.csv").read_text() == (whole / "segments.csv").read_text()

    # a missing shard and a shard that lost a record are named, one line each
    capsys.readouterr()
    lost = manifests[0]["items"][0]["key"]
    (Path(machines[0]) / "bags" / f"{lost}.json").unlink()
    assert main(["aggregate", machines[0], machines[2], "--out", str(tmp_path / "partial")]) == 1
    err = capsys.readouterr().err
    assert "shard 1 of 3 is missing: run it with --num-shards 3 --shard-index 1" in err
    assert f"shard 0 of 3 failed: 1 record(s) missing, first {lost}; rerun it" in err
    assert "Traceback" not in err


def test_a_shard_rerun_skips_its_complete_bags(lab: dict[str, Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "seg"
    argv = [*_args(lab, out), "--num-shards", "2", "--shard-index", "1"]
    assert main(argv) == 0
    mine = json.loads((out / "shards" / "1-of-2" / "manifest.json").read_text())
    assert mine["status"] == "complete" and 0 < len(mine["items"]) < 9
    assert main(argv) == 0
    summary = json.loads((out / "shards" / "1-of-2" / "summary.json").read_text())
    assert summary["skipped"] == summary["bags"] == len(mine["items"])


@pytest.mark.parametrize(("extra", "needle"), [(["--num-shards", "3"], "--shard-index"),
                                               (["--num-shards", "3", "--shard-index", "3"], "0..2"),
                                               (["--num-shards", "0", "--shard-index", "0"], "at least 1")])
def test_bad_shard_options_are_one_line(lab: dict[str, Path], tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str],
                                        extra: list[str], needle: str) -> None:
    assert main([*_args(lab, tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_aggregate_without_shards_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["aggregate", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no shard manifest" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_annotated_bags_of_shards_are_listed_and_a_missing_shard_named(lab: dict[str, Path], tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]
                                                                      ) -> None:
    out, copies = tmp_path / "seg", tmp_path / "copies"
    argv = [*_args(lab, out), "--annotate", str(copies), "--num-shards", str(SHARDS)]
    for index in (0, 2):  # shard 1 never ran
        assert main([*argv, "--shard-index", str(index)]) == 0
    capsys.readouterr()
    assert main(["aggregate", str(out)]) == 1
    err = capsys.readouterr().err
    assert "shard 1 of 3 is missing: run it with --num-shards 3 --shard-index 1" in err
    listed = json.loads((out / "summary.json").read_text())["annotated"]
    manifests = [json.loads((out / "shards" / f"{i}-of-{SHARDS}" / "manifest.json").read_text())
                 for i in (0, 2)]
    keys = [item["key"] for manifest in manifests for item in manifest["items"]]
    assert sorted(entry["bag"] for entry in listed) == sorted(keys) and 0 < len(keys) < 9
    assert all(Path(entry["copy"]).is_dir() and Path(entry["copy"]).parent == copies for entry in listed)
