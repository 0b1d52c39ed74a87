"""``ompn_segment --bags SOURCE --jobs N``: many bags of another lab, one table of segments, resumable."""

from __future__ import annotations

import csv
import itertools
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
from batch_bags import SPEC, write_lab_bag

from ompn_ros.app.batch_bags import bag_keys, list_bags
from ompn_ros.app.replay import replay_all
from ompn_ros.cli.segment import main
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.tune import score_predictions
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.load import stepper_from_checkpoint

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Four good bags (mcap files and bag folders), one corrupt, a reader spec and an untrained model."""
    root = tmp_path_factory.mktemp("lab")
    bags = root / "bags"
    (bags / "day2").mkdir(parents=True)
    stamps = {"a": write_lab_bag(bags / "a", 1), "b": write_lab_bag(bags / "b", 2),
              "day2__c": write_lab_bag(bags / "day2" / "c", 3),
              "day2__d": write_lab_bag(bags / "day2" / "d", 4)}
    (bags / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    spec = root / "lab_reader.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    config = OMPNConfig(obs_dim=4, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)
    save_checkpoint(root / "model", build_policy(config))
    return {"root": root, "bags": bags, "spec": spec, "model": root / "model", "stamps": stamps}


def _args(lab: dict, out: Path, *more: str) -> list[str]:
    return ["--checkpoint", str(lab["model"]), "--reader-config", str(lab["spec"]), "--out", str(out), *more]


def _table(out: Path) -> list[dict[str, str]]:
    with open(out / "segments.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_batch_segments_every_bag_and_names_the_refused_one(
    lab: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, copies = tmp_path / "seg", tmp_path / "annotated"
    code = main(["--bags", str(lab["bags"]), "--jobs", "2", "--annotate", str(copies), *_args(lab, out)])
    err = capsys.readouterr().err
    assert code == 1  # some bags were refused
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["bags"], summary["read"], summary["segmented"]) == (5, 4, 4)
    [refused] = summary["refused"]
    assert refused["bag"].endswith("broken.mcap") and "broken.mcap" in refused["reason"]
    assert "Traceback" not in err and "[5/5 100% eta 0 s]" in err and "refused broken.mcap" not in err
    assert "1 refused" in err and f"refused {refused['bag']}: " in err
    assert sorted(p.name for p in copies.iterdir()) == sorted(lab["stamps"])  # one annotated copy per bag
    rows = _table(out)
    spec = ReaderSpec.from_yaml(lab["spec"])
    policy = stepper_from_checkpoint(lab["model"])
    all_episodes, all_preds = [], []
    for key, stamps in lab["stamps"].items():
        mine = [r for r in rows if Path(r["bag"]).name == key.split("__")[-1]]
        episodes = read_episodes(lab["bags"] / key.replace("__", "/"), spec=spec).episodes
        replays = replay_all(policy, episodes, DetectorConfig())
        for number, (ep, r) in enumerate(zip(episodes, replays, strict=True)):
            segs = [row for row in mine if int(row["episode"]) == number]
            assert [int(row["end_step"]) for row in segs] == sorted(b.step for b in r.boundaries)
            assert int(segs[0]["start_step"]) == 0 and int(segs[-1]["end_step"]) == ep.length - 1
            for prev, row in itertools.pairwise(segs):
                assert int(row["start_step"]) == int(prev["end_step"]) + 1  # segments tile the episode
            for row in segs:  # stamps are the bag's own observation stamps
                assert int(row["start_stamp_ns"]) == stamps[number][int(row["start_step"])]
                assert int(row["end_stamp_ns"]) == stamps[number][int(row["end_step"])]
                assert row["detector"] == "falling_edge" and row["subtask_id"] == ""
            all_episodes.append(ep)
            all_preds.append(r.boundary_steps)
    expected = score_predictions(all_preds, all_episodes)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["episodes"] == len(all_episodes) == 8
    for key, value in expected.items():
        assert metrics[key] == pytest.approx(value)


def test_list_file_with_a_missing_entry_and_a_glob(lab: dict, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    listing = lab["root"] / "some.txt"
    listing.write_text("# two bags and one that is not there\nbags/a\n\nbags/day2/c\nbags/gone\n")
    bags = list_bags(str(listing))
    assert [b.key for b in bags] == ["a", "day2__c", "bags_gone"] and bags[2].path is None
    out = tmp_path / "seg"
    assert main(["--bags", str(listing), *_args(lab, out)]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["segmented"] == 2 and summary["refused"][0]["bag"] == "bags_gone"
    assert "no such file or directory" in summary["refused"][0]["reason"]
    capsys.readouterr()
    glob_out = tmp_path / "glob"
    assert main(["--bags", str(lab["bags"] / "day2" / "*"), *_args(lab, glob_out)]) == 0
    assert {Path(r["bag"]).name for r in _table(glob_out)} == {"c", "d"}
    assert "0 refused" in capsys.readouterr().err


def test_a_killed_run_loses_no_completed_bag(lab: dict, tmp_path: Path) -> None:
    """Kill a batch run once it has completed a bag, rerun: completed bags are skipped, not redone."""
    bags = tmp_path / "many"
    bags.mkdir()
    for i in range(8):
        write_lab_bag(bags / f"run{i}", 10 + i, episodes=3, steps=60)
    out = tmp_path / "seg"
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    command = [sys.executable, "-m", "ompn_ros.cli.segment", "--bags", str(bags), *_args(lab, out)]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list((out / "bags").glob("*.json")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = {p.name: p.stat().st_mtime_ns for p in (out / "bags").glob("*.json")}
    assert 1 <= len(done) < 8, "the run was not killed mid-way"
    assert not (out / "segments.csv").exists()
    assert main(["--bags", str(bags), *_args(lab, out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["segmented"] == 8 and summary["skipped"] == len(done)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "bags").glob("*.json") if p.name in done} == done
    assert {Path(r["bag"]).name for r in _table(out)} == {f"run{i}" for i in range(8)}
    assert not [p for p in (out / "bags").iterdir() if p.name.startswith(".")]
    # other detector settings: every bag is redone
    detector = tmp_path / "det.yaml"
    detector.write_text("ompn_node:\n  ros__parameters:\n    detector_high: 0.3\n")
    assert main(["--bags", str(bags), "--detector-config", str(detector), *_args(lab, out)]) == 0
    assert json.loads((out / "summary.json").read_text())["skipped"] == 0
    assert main(["--bags", str(bags), "--detector-config", str(detector), *_args(lab, out)]) == 0
    assert json.loads((out / "summary.json").read_text())["skipped"] == 8  # the same settings: all skipped


@pytest.mark.parametrize(("extra", "needle"), [(["--tune"], "--bags"), (["--jobs", "0"], "--jobs"),
                                               (["--bag", "x"], "--bags")])
def test_bad_batch_options_are_one_line(lab: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        extra: list[str], needle: str) -> None:
    code = main(["--bags", str(lab["bags"]), *extra, *_args(lab, tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and needle in err and len(err.strip().splitlines()) == 1


def test_copies_inside_the_bags_are_refused(lab: dict, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    copies = lab["bags"] / "annotated"
    (copies / "old").mkdir(parents=True)
    write_lab_bag(copies / "old" / "a", 99, episodes=1, steps=6)
    try:
        code = main(["--bags", str(lab["bags"]), "--annotate", str(copies), *_args(lab, tmp_path / "o")])
    finally:
        shutil.rmtree(copies)
    err = capsys.readouterr().err
    assert code == 2 and "--annotate" in err and "write them elsewhere" in err and "Traceback" not in err


def test_an_empty_folder_refuses_the_run(lab: dict, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    assert main(["--bags", str(tmp_path / "empty"), *_args(lab, tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and str(tmp_path / "empty") in err and "Traceback" not in err


def test_keys_are_unique_and_safe(tmp_path: Path) -> None:
    paths = [tmp_path / "x" / "a.mcap", tmp_path / "x" / "a", tmp_path / "y z" / "a.db3"]
    keys = bag_keys(paths)
    assert list(keys.values()) == ["x__a", "x__a-2", "y_z__a"]


def test_rows_name_the_sketch_id_of_each_segment() -> None:
    from ompn_ros.app.batch import segment_rows
    from ompn_ros.data.episode import Episode
    from ompn_ros.detect.online import BoundaryEvent
    from ompn_ros.segmenter import ReplayResult

    ep = Episode(observations=np.zeros((7, 2), np.float32), actions=np.zeros(6, np.int64),
                 subtask=None, sketch=np.array([7, 6]), task="t", seed=0)
    events = [BoundaryEvent(step=5, detected_at=6, subtask=2, score=0.9, level=2, stamp_ns=0, final=True),
              BoundaryEvent(step=1, detected_at=2, subtask=0, score=0.7, level=1, stamp_ns=0),
              BoundaryEvent(step=3, detected_at=4, subtask=1, score=0.8, level=1, stamp_ns=0)]
    empty = np.zeros((6, 3))
    replay = ReplayResult(p_hat=empty, pi=empty, pi_end=empty[:, 0], expected_position=empty[:, 0],
                          scores=empty[:, 0], boundaries=events)
    rows = segment_rows(4, ep, replay, np.arange(7) * 10, "hsmm")
    found = [(r["start_step"], r["end_step"], r["subtask_id"]) for r in rows]
    assert found == [(0, 1, 7), (2, 3, 6), (4, 5, None)]
    assert [(r["start_stamp_ns"], r["end_stamp_ns"]) for r in rows] == [(0, 10), (20, 30), (40, 50)]
    assert {r["episode"] for r in rows} == {4} and rows[2]["score"] == 0.9
    assert [r["end_stamp_ns"] for r in segment_rows(0, ep, replay, None, "hsmm")] == [None] * 3


def test_the_table_is_also_parquet_when_pyarrow_is_installed(tmp_path: Path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")
    from ompn_ros.app.batch_table import write_table

    rows = [{"bag": "b", "episode": 0, "start_step": 0, "end_step": 3, "subtask": 0, "score": 0.5}]
    written = write_table(tmp_path, rows)
    assert [p.name for p in written] == ["segments.csv", "segments.parquet"]
    assert pq.read_table(written[1]).to_pylist()[0]["end_step"] == 3
