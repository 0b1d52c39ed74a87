"""``ompn_segment --dataset DIR --num-shards N --shard-index I`` and ``ompn_segment aggregate``: a LeRobot
dataset's episodes split over separate processes (as over machines or array tasks) give the table and
the annotated dataset of one run, row for row and frame for frame.

The dataset is written by LeRobot's own writer (``lerobot-dataset``) from Dial demonstrations
(``ompn_collect`` bags), its frame files kept small so that episodes of several shards share a file and
the episodes lie in several files; the merged dataset is loaded back by LeRobot's own loader.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from lerobot_support import ledataset_or_skip, load_dataset, write_dataset

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.cli.collect import main as collect
from ompn_ros.cli.segment import main as segment
from ompn_ros.data import read_episodes
from ompn_ros.data.reader import ReaderSpec

pytestmark = pytest.mark.filterwarnings("ignore")
ROOT = Path(__file__).resolve().parents[2]
SHARDS = 3
LABELLED = {"observation": ["observation.state"], "action": "action", "labels": "task_index",
            "label_kind": "id"}


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Seven Dial demonstrations as a LeRobot dataset of several frame files, and a labelled spec."""
    ledataset_or_skip()
    root = tmp_path_factory.mktemp("lerobot_shards")
    assert collect(["--domain", "dial", "--episodes", "7", "--seed", "5", "--out", str(root / "bags")]) == 0
    episodes = list(read_episodes(root / "bags", spec=ReaderSpec.for_domain("dial")).episodes)
    write_dataset(root / "dataset", episodes, file_mb=0.1)
    files = sorted((root / "dataset" / "data").glob("chunk-*/file-*.parquet"))
    assert 2 <= len(files) < len(episodes)  # episodes of several shards share a file, in several files
    spec = root / "labelled.yaml"
    spec.write_text(yaml.safe_dump({"dataset": LABELLED}))
    return {"root": root, "dataset": root / "dataset", "spec": spec, "episodes": len(episodes),
            "checkpoint": str(shipped_checkpoint("dial"))}


def _args(lab: dict, out: Path, fmt: str = "index") -> list[str]:
    return ["--dataset", str(lab["dataset"]), "--dataset-spec", str(lab["spec"]), "--checkpoint",
            lab["checkpoint"], "--out", str(out), "--write-subtasks", fmt]


def _shard(lab: dict, out: Path, index: int, fmt: str = "index") -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "ompn_ros.cli.segment", *_args(lab, out, fmt), "--num-shards",
               str(SHARDS), "--shard-index", str(index)]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _frames(root: Path) -> dict[str, np.ndarray]:
    """The frames of the dataset at ``root`` as LeRobot's loader returns them."""
    loaded = load_dataset(root)
    items = [loaded[i] for i in range(len(loaded))]
    return {key: np.array([int(item[key]) for item in items])
            for key in ("subtask_index", "episode_index", "frame_index", "index")}


def _records(out: Path, index: int) -> list[int]:
    folder = out / "shards" / f"{index}-of-{SHARDS}" / "files"
    docs = [json.loads(path.read_text()) for path in sorted(folder.glob("*.json"))]
    return [e["index"] for doc in docs for e in doc["episodes"]]


def test_three_shard_processes_equal_one_run_frame_for_frame(lab: dict, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    whole = tmp_path / "whole"
    assert segment(_args(lab, whole)) == 0
    shared = tmp_path / "shared"
    procs = [_shard(lab, shared, index) for index in range(SHARDS)]  # side by side, one folder
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0 and "Traceback" not in err, err[-3000:]
    for index in range(SHARDS):  # each shard segmented its own episodes only
        mine = _records(shared, index)
        assert mine and all(e % SHARDS == index for e in mine)
    assert sorted(e for i in range(SHARDS) for e in _records(shared, i)) == list(range(lab["episodes"]))
    assert not (shared / "dataset").exists()  # a shard writes no dataset
    capsys.readouterr()
    merged = tmp_path / "merged"
    assert segment(["aggregate", str(shared), "--out", str(merged)]) == 0
    assert (merged / "segments.csv").read_text() == (whole / "segments.csv").read_text()
    metrics = [json.loads((folder / "metrics.json").read_text()) for folder in (merged, whole)]
    assert metrics[0] == metrics[1] and metrics[0]["episodes"] == lab["episodes"]
    got, want = _frames(merged / "dataset"), _frames(whole / "dataset")
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])
    assert want["subtask_index"].max() >= 2  # subtasks were found: the comparison compares something
    pandas = pytest.importorskip("pandas")
    pandas.testing.assert_frame_equal(pandas.read_parquet(merged / "dataset" / "meta" / "subtasks.parquet"),
                                      pandas.read_parquet(whole / "dataset" / "meta" / "subtasks.parquet"))
    summary = json.loads((merged / "summary.json").read_text())
    assert summary["shards"] == {"count": 3, "complete": [0, 1, 2], "missing": [], "failed": {}}
    assert summary["episodes"] == lab["episodes"]
    assert not [p for p in merged.iterdir() if p.name.startswith(".")]  # no staging folder left

    # a second aggregate replaces its dataset whole
    assert segment(["aggregate", str(shared), "--out", str(merged)]) == 0
    np.testing.assert_array_equal(_frames(merged / "dataset")["subtask_index"], want["subtask_index"])


@pytest.mark.parametrize("fmt", ["language", "episodes"])
def test_language_rows_and_episode_columns_merge_as_one_run(lab: dict, tmp_path: Path, fmt: str) -> None:
    import pyarrow.parquet as pq

    whole, shared = tmp_path / "whole", tmp_path / "shared"
    assert segment(_args(lab, whole, fmt)) == 0
    for index in range(SHARDS):
        assert segment([*_args(lab, shared, fmt), "--num-shards", str(SHARDS), "--shard-index",
                        str(index)]) == 0
    # the aggregating machine has the dataset elsewhere; the annotated one goes where it is told
    moved = tmp_path / "elsewhere" / "my_arm"
    shutil.copytree(lab["dataset"], moved)
    assert segment(["aggregate", str(shared), "--out", str(tmp_path / "table"), "--dataset", str(moved),
                    "--annotate", str(tmp_path / "merged" / "dataset")]) == 0
    assert not (tmp_path / "table" / "dataset").exists()
    assert (tmp_path / "table" / "segments.csv").read_text() == (whole / "segments.csv").read_text()
    folder = "data" if fmt == "language" else "meta/episodes"
    columns = ["language_persistent", "language_events"] if fmt == "language" else [
        "episode_index", "subtask_names", "subtask_start_frames", "subtask_end_frames", "subtask_start_times",
        "subtask_end_times"]
    want_files = sorted((whole / "dataset" / folder).glob("chunk-*/file-*.parquet"))
    assert want_files
    for path in want_files:
        relative = path.relative_to(whole / "dataset")
        got = pq.read_table(tmp_path / "merged" / "dataset" / relative, columns=columns).to_pylist()
        assert got == pq.read_table(path, columns=columns).to_pylist()
        assert any(row[columns[0 if fmt == "language" else 1]] for row in got)  # subtasks were written
    if fmt == "episodes":
        meta = ledataset_or_skip().LeRobotDatasetMetadata("lab/demo", root=tmp_path / "merged" / "dataset")
        assert len(meta.episodes) == lab["episodes"]


def _state(out: Path, index: int) -> str:
    path = out / "shards" / f"{index}-of-{SHARDS}" / "manifest.json"
    return json.loads(path.read_text())["status"] if path.exists() else "absent"


def test_a_killed_shard_resumes_and_a_missing_shard_is_named(lab: dict, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "seg"
    proc = _shard(lab, out, 1)
    folder = out / "shards" / f"1-of-{SHARDS}" / "files"
    deadline = time.monotonic() + 120
    while not list(folder.glob("*.json")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)  # killed after its first frame file, as by the out-of-memory killer
    proc.communicate(timeout=60)
    first = sorted(folder.glob("*.json"))
    assert first, "the shard finished or wrote nothing before it was killed"
    stamps = {p.name: p.stat().st_mtime_ns for p in first}
    files = len(list((lab["dataset"] / "data").glob("chunk-*/file-*.parquet")))
    if _state(out, 1) == "running":
        assert len(first) < files or proc.returncode is not None

    for index in (0, 2):
        assert segment([*_args(lab, out), "--num-shards", str(SHARDS), "--shard-index", str(index)]) == 0
    capsys.readouterr()
    if _state(out, 1) == "running":  # a shard that did not finish is named, nothing is written
        assert segment(["aggregate", str(out), "--out", str(tmp_path / "early")]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert lines == ["ompn_segment aggregate: error: shard 1 of 3 failed: did not finish (running); "
                         "rerun it to complete it"]
        assert not (tmp_path / "early").exists()

    assert segment([*_args(lab, out), "--num-shards", str(SHARDS), "--shard-index", "1"]) == 0  # resumes
    assert {p.name: p.stat().st_mtime_ns for p in first} == stamps  # the files done before were skipped
    assert len(list(folder.glob("*.json"))) == files
    whole = tmp_path / "whole"
    assert segment(_args(lab, whole)) == 0
    assert segment(["aggregate", str(out), "--out", str(tmp_path / "merged")]) == 0
    assert (tmp_path / "merged" / "segments.csv").read_text() == (whole / "segments.csv").read_text()
    np.testing.assert_array_equal(_frames(tmp_path / "merged" / "dataset")["subtask_index"],
                                  _frames(whole / "dataset")["subtask_index"])

    # one machine's folder lost: its shard is named on one line, exit 2, nothing written
    (out / "shards" / f"2-of-{SHARDS}" / "manifest.json").unlink()
    capsys.readouterr()
    assert segment(["aggregate", str(out), "--out", str(tmp_path / "partial")]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["ompn_segment aggregate: error: shard 2 of 3 is missing: run it with "
                                        "--num-shards 3 --shard-index 2"]
    assert not (tmp_path / "partial").exists()


@pytest.mark.parametrize(("extra", "needle"), [
    (["--num-shards", "3"], "--shard-index"),
    (["--num-shards", "3", "--shard-index", "0", "--in-place"], "aggregate writes the annotated dataset"),
    (["--num-shards", "3", "--shard-index", "0", "--annotate", "x"], "aggregate writes the annotated"),
])
def test_bad_dataset_shard_options_are_one_line(lab: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                extra: list[str], needle: str) -> None:
    assert segment([*_args(lab, tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
