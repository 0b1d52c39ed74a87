"""LeRobot v3 datasets in and out, checked with LeRobot's own code (``lerobot-dataset``).

Datasets are written by LeRobot's writer from Dial demonstrations (``ompn_collect`` bags read by the bag
reader), segmented by ``ompn_segment --dataset``, and loaded back by LeRobot's loader; the subtasks are
compared frame for frame with the node's replay of the same episodes (the stream rule, the shipped Dial
checkpoint and its detector).
"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from lerobot_support import ledataset_or_skip, load_dataset, write_dataset

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.cli.collect import main as collect
from ompn_ros.cli.segment import main as segment
from ompn_ros.data import read_episodes
from ompn_ros.data.episode import Episode
from ompn_ros.data.lerobot import DatasetReader, DatasetSpec
from ompn_ros.data.reader import ReaderSpec
from ompn_ros.detect.settings import resolve_detector
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.stream.replay import replay_episode

pytestmark = pytest.mark.filterwarnings("ignore")
LABELLED = {"observation": ["observation.state"], "action": "action", "labels": "task_index",
            "label_kind": "id"}


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Two Dial demonstrations: an ``ompn_collect`` bag, its episodes, the same as a LeRobot dataset."""
    ledataset_or_skip()
    root = tmp_path_factory.mktemp("lerobot")
    bags = root / "bags" / "dial"
    assert collect(["--domain", "dial", "--episodes", "2", "--seed", "3", "--out", str(bags)]) == 0
    episodes = list(read_episodes(root / "bags" / "dial", spec=ReaderSpec.for_domain("dial")).episodes)
    write_dataset(root / "dataset", episodes)
    spec = root / "labelled.yaml"
    spec.write_text(yaml.safe_dump({"dataset": LABELLED}))
    checkpoint = str(shipped_checkpoint("dial"))
    settings, _ = resolve_detector(checkpoint, None, "")
    stepper = stepper_from_checkpoint(checkpoint)
    online = settings.online, settings.duration_model, settings.head
    node = [replay_episode(StreamingSegmenter(stepper, *online), ep, include_done_step=True)
            for ep in episodes]
    return {"root": root, "episodes": episodes, "dataset": root / "dataset", "spec": spec,
            "checkpoint": checkpoint, "node": node}


def _per_frame(steps: list[int], frames: int) -> np.ndarray:
    """The subtask of each frame: the boundaries before it (one at the last step closes the last subtask,
    which runs to the last frame)."""
    cuts = [s for s in steps if s < frames - 2]
    return np.array([sum(s < f for s in cuts) for f in range(frames)])


def _copy(lab: dict, tmp_path: Path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(lab["dataset"], target)
    return target


def test_the_reader_gives_the_episodes_lerobot_stored(lab: dict):
    found = list(DatasetReader(lab["dataset"], DatasetSpec.from_dict(LABELLED)).episodes())
    assert [e.index for e in found] == [0, 1]
    for got, want in zip(found, lab["episodes"], strict=True):
        np.testing.assert_array_equal(got.episode.observations, want.observations)
        np.testing.assert_array_equal(got.episode.actions, want.actions)
        np.testing.assert_array_equal(got.episode.subtask, want.subtask)
        np.testing.assert_allclose(got.timestamps, np.arange(want.length + 1) / 25, atol=1e-5)


def test_subtask_index_loaded_by_lerobot_equals_the_node_frame_for_frame(lab: dict, tmp_path: Path):
    out = tmp_path / "seg"
    assert segment(["--dataset", str(lab["dataset"]), "--checkpoint", lab["checkpoint"], "--out", str(out),
                    "--write-subtasks", "index"]) == 0
    loaded = load_dataset(out / "dataset")
    got = np.array([int(loaded[i]["subtask_index"]) for i in range(len(loaded))])
    episode = np.array([int(loaded[i]["episode_index"]) for i in range(len(loaded))])
    for number, (ep, r) in enumerate(zip(lab["episodes"], lab["node"], strict=True)):
        want = _per_frame([b.step for b in r.boundaries], ep.length + 1)
        np.testing.assert_array_equal(got[episode == number], want)
        assert want.max() >= 2  # the node found subtasks: the check compares something
    names = __import__("pandas").read_parquet(out / "dataset" / "meta" / "subtasks.parquet")
    assert [names.iloc[k].name for k in range(len(names))] == [f"subtask {k}" for k in range(got.max() + 1)]
    shared = (lab["dataset"] / "meta" / "tasks.parquet", out / "dataset" / "meta" / "tasks.parquet")
    assert shared[0].stat().st_ino == shared[1].stat().st_ino  # unchanged files are shared, not copied
    source = lab["dataset"] / "data" / "chunk-000" / "file-000.parquet"
    assert (out / "dataset" / "data" / "chunk-000" / "file-000.parquet").stat().st_ino != source.stat().st_ino


def test_the_table_rows_are_the_node_boundaries_with_frame_stamps(lab: dict, tmp_path: Path):
    assert segment(["--dataset", str(lab["dataset"]), "--checkpoint", lab["checkpoint"], "--out",
                    str(tmp_path)]) == 0
    rows = list(csv.DictReader((tmp_path / "segments.csv").open()))
    for number, r in enumerate(lab["node"]):
        mine = [row for row in rows if int(row["episode"]) == number]
        assert [int(row["end_step"]) for row in mine] == [b.step for b in r.boundaries]
        stamps = [int(row["end_stamp_ns"]) for row in mine]
        np.testing.assert_allclose(stamps, [b.step / 25 * 1e9 for b in r.boundaries], atol=1e3)
    assert not (tmp_path / "dataset").exists()  # no format asked: the table only


def test_language_rows_in_place_rewrite_only_the_frame_files(lab: dict, tmp_path: Path):
    import pyarrow.parquet as pq

    data = _copy(lab, tmp_path)
    before = {p.relative_to(data): _digest(p) for p in data.rglob("*") if p.is_file()}
    assert segment(["--dataset", str(data), "--checkpoint", lab["checkpoint"], "--out", str(tmp_path / "o"),
                    "--write-subtasks", "language-v1", "--in-place"]) == 0
    changed = {p for p, d in before.items() if _digest(data / p) != d}
    assert changed == {Path("data/chunk-000/file-000.parquet"), Path("meta/info.json")}
    table = pq.read_table(data / "data" / "chunk-000" / "file-000.parquet")
    rows, episode = table.column("language_persistent").to_pylist(), table.column("episode_index").to_pylist()
    stamps = table.column("timestamp").to_pylist()
    for number, (ep, r) in enumerate(zip(lab["episodes"], lab["node"], strict=True)):
        first = episode.index(number)
        want = _per_frame([b.step for b in r.boundaries], ep.length + 1)
        starts = np.flatnonzero(np.diff(np.concatenate([[-1], want])) != 0)
        assert rows[first] == [{"role": "assistant", "content": f"subtask {k}", "style": "subtask",
                                "timestamp": pytest.approx(stamps[first + s]), "camera": None,
                                "tool_calls": None}
                               for k, s in enumerate(starts)]
        assert all(rows[i] == rows[first] for i in range(first, first + ep.length + 1))
    info = json.loads((data / "meta" / "info.json").read_text())
    assert info["features"]["language_persistent"] == {"dtype": "language", "shape": [1], "names": None}
    assert table.column("language_events").to_pylist() == [[]] * table.num_rows


def test_episode_columns_loaded_by_lerobot_metadata(lab: dict, tmp_path: Path):
    data = _copy(lab, tmp_path)
    assert segment(["--dataset", str(data), "--checkpoint", lab["checkpoint"], "--out", str(tmp_path / "o"),
                    "--write-subtasks", "episodes", "--in-place"]) == 0
    meta = ledataset_or_skip().LeRobotDatasetMetadata("lab/demo", root=data)
    for number, (ep, r) in enumerate(zip(lab["episodes"], lab["node"], strict=True)):
        cuts = [b.step for b in r.boundaries if b.step < ep.length - 1]  # the last runs to the last frame
        assert len(cuts) >= 2
        assert list(meta.episodes[number]["subtask_end_frames"]) == [*cuts, ep.length]
        assert list(meta.episodes[number]["subtask_start_frames"]) == [0, *[s + 1 for s in cuts]]
        assert list(meta.episodes[number]["subtask_names"]) == [f"subtask {k}" for k in range(len(cuts) + 1)]
        times = [0, *[(s + 1) / 25 for s in cuts]]
        assert list(meta.episodes[number]["subtask_start_times"]) == pytest.approx(times)
    assert len(load_dataset(data)) == sum(ep.length + 1 for ep in lab["episodes"])  # still loads


def test_a_bag_and_its_lerobot_conversion_give_the_same_segments(lab: dict, tmp_path: Path):
    """rosbag2 -> LeRobot (LeRobot's writer): segmented in both forms, the same boundaries and scores."""
    assert segment(["--bags", str(lab["root"] / "bags"), "--domain", "dial", "--checkpoint",
                    lab["checkpoint"], "--out", str(tmp_path / "bags")]) == 0
    assert segment(["--dataset", str(lab["dataset"]), "--checkpoint", lab["checkpoint"],
                    "--out", str(tmp_path / "dataset")]) == 0
    keys = ("episode", "start_step", "end_step", "subtask")
    bag = list(csv.DictReader((tmp_path / "bags" / "segments.csv").open()))
    dataset = list(csv.DictReader((tmp_path / "dataset" / "segments.csv").open()))
    assert len(bag) >= 6
    assert [[row[k] for k in keys] for row in bag] == [[row[k] for k in keys] for row in dataset]
    scores = [float(r["score"]) for r in bag], [float(r["score"]) for r in dataset]
    np.testing.assert_allclose(*scores, rtol=1e-6)


def test_offline_top_k_takes_k_from_the_labels(lab: dict, tmp_path: Path):
    assert segment(["--dataset", str(lab["dataset"]), "--dataset-spec", str(lab["spec"]), "--checkpoint",
                    lab["checkpoint"], "--out", str(tmp_path), "--boundaries", "top_k"]) == 0
    rows = list(csv.DictReader((tmp_path / "segments.csv").open()))
    for number, ep in enumerate(lab["episodes"]):
        assert len([r for r in rows if int(r["episode"]) == number]) == len(ep.boundaries)
    assert {r["detector"] for r in rows} == {"top_k"}
    assert json.loads((tmp_path / "metrics.json").read_text())["episodes"] == 2


@pytest.mark.parametrize("args, words", [
    (["--dataset-spec", "SPEC"], "does not have"),
    (["--in-place"], "--write-subtasks FORMAT"),
    (["--write-subtasks", "index", "--annotate", "DATA/inside"], "outside the dataset"),
    (["--boundaries", "top_k"], "--subtasks K or labels"),
])
def test_bad_requests_are_one_line_and_change_nothing(lab: dict, tmp_path: Path, capsys, args, words):
    spec = tmp_path / "bad.yaml"
    spec.write_text(yaml.safe_dump({"observation": "observation.joints"}))
    data = _copy(lab, tmp_path)
    before = {p: _digest(p) for p in data.rglob("*") if p.is_file()}
    args = [a.replace("SPEC", str(spec)).replace("DATA", str(data)) for a in args]
    assert segment(["--dataset", str(data), "--checkpoint", lab["checkpoint"], "--out", str(tmp_path / "o"),
                    *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 or words in err[-1], err
    assert words in err[-1]
    assert {p: _digest(p) for p in data.rglob("*") if p.is_file()} == before


def test_not_a_v3_dataset_is_refused_in_one_line(tmp_path: Path, capsys):
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v2.1", "features": {}}))
    assert segment(["--dataset", str(tmp_path), "--checkpoint", str(shipped_checkpoint("dial")),
                    "--out", str(tmp_path / "o")]) == 2
    assert "only LeRobot v3 datasets" in capsys.readouterr().err


@pytest.mark.slow
def test_a_lerobot_dataset_trains_and_comes_back_annotated(lab: dict, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch):
    """ompn_train --dataset on LeRobot's dataset, then its checkpoint segments it, loaded by LeRobot."""
    from ompn_ros.cli.train import main as train

    monkeypatch.setenv("OMPN_CACHE_DIR", str(tmp_path / "cache"))
    run = tmp_path / "run"
    assert train(["--dataset", str(lab["dataset"]), "--dataset-spec", str(lab["spec"]), "--config",
                  str(Path(__file__).resolve().parents[2] / "config" / "train_dial.yaml"), "--out", str(run),
                  "--set", "train.iterations=4", "--set", "train.eval_every=2", "--set", "train.patience=0",
                  "--set", "model.slot_size=16", "--set", "train.boundary_head=false", "--quiet"]) == 0
    report = json.loads((run / "read_report.json").read_text())
    assert report["episodes"] == 2 and "LeRobot dataset" in report["summary"]
    assert segment(["--dataset", str(lab["dataset"]), "--checkpoint", str(run / "best"), "--out",
                    str(tmp_path / "seg"), "--write-subtasks", "index"]) == 0
    loaded = load_dataset(tmp_path / "seg" / "dataset")
    assert len(loaded) == sum(ep.length + 1 for ep in lab["episodes"])
    assert "subtask_index" in loaded[0]


def test_video_features_are_left_out_in_one_line_and_refused_when_named(lab: dict, tmp_path: Path, capsys):
    data = _copy(lab, tmp_path)
    info = json.loads((data / "meta" / "info.json").read_text())
    info["features"]["observation.images.top"] = {"dtype": "video", "shape": [48, 64, 3],
                                                  "names": ["height", "width", "channels"]}
    (data / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    out = str(tmp_path / "o")
    assert segment(["--dataset", str(data), "--checkpoint", lab["checkpoint"], "--out", out]) == 0
    assert "ompn_segment: video/image features not read: observation.images.top" in capsys.readouterr().err
    spec = tmp_path / "video.yaml"
    spec.write_text(yaml.safe_dump({"observation": ["observation.state", "observation.images.top"]}))
    assert segment(["--dataset", str(data), "--dataset-spec", str(spec), "--checkpoint", lab["checkpoint"],
                    "--out", str(tmp_path / "o2")]) == 2
    assert "a video feature" in capsys.readouterr().err


def test_select_reads_only_the_episodes_asked_for(lab: dict):
    found = list(DatasetReader(lab["dataset"], select=lambda index: index == 1).episodes())
    assert [e.index for e in found] == [1]
    np.testing.assert_array_equal(found[0].episode.observations, lab["episodes"][1].observations)


def test_an_episode_of_one_frame_is_named_and_kept_as_subtask_0(lab: dict, tmp_path: Path, capsys):
    short = Episode(observations=lab["episodes"][0].observations[:1].copy(),
                    actions=lab["episodes"][0].actions[:0].copy(), subtask=np.zeros(0, np.int64))
    data = write_dataset(tmp_path / "short", [lab["episodes"][1], short], labels=False)
    assert segment(["--dataset", str(data), "--checkpoint", lab["checkpoint"], "--out", str(tmp_path / "o"),
                    "--write-subtasks", "index"]) == 0
    assert "episode 1 has 1 frame: no step to segment, left out" in capsys.readouterr().err
    loaded = load_dataset(tmp_path / "o" / "dataset")
    assert int(loaded[len(loaded) - 1]["episode_index"]) == 1
    assert int(loaded[len(loaded) - 1]["subtask_index"]) == 0
