"""Offline tools on a full disk, unfinished bags and annotated copies: one line naming the file at
fault, exit 2, and nothing truncated that looks complete."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from small_disk import small_disk

from ompn_ros import layout
from ompn_ros.cli.segment import main as segment_main
from ompn_ros.cli.train import main as train_main
from ompn_ros.data.errors import CorruptBagError
from ompn_ros.data.reader.raw import collect_rosbags
from ompn_ros.data.recorder.bag_writer import write_episodes
from ompn_ros.train import synthetic

SMALL = ["--quiet", "--set", "model.n_slots=2", "--set", "model.slot_size=16", "--set", "train.batch_size=8",
         "--set", "train.eval_every=2", "--set", "train.threads=1"]  # fmt: skip


def _hidden(root: Path) -> list[Path]:
    return [p for p in root.rglob(".*")]


@pytest.mark.parametrize("free_kb", [2, 40, 400])  # full at the log, the best checkpoint, the training state
def test_train_on_a_full_disk_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], free_kb: int
) -> None:
    with small_disk(tmp_path / "disk", 1024, free_kb=free_kb) as disk:
        out = disk / "run"
        code = train_main(["--synthetic", "discrete", "--episodes", "12", "--out", str(out), *SMALL,
                           "--set", "train.iterations=2"])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err, err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and str(out) in lines[0] and "No space left" in lines[0], err
        assert not _hidden(out)  # no temporary left behind
        for checkpoint in (out / "best", out / "last"):  # a checkpoint is whole or absent
            assert not checkpoint.exists() or {"model.safetensors", "config.json"} <= {
                p.name for p in checkpoint.iterdir()}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    episodes = synthetic.make_dataset("discrete", 3, seed=5)
    domain = dataclasses.replace(layout.CRAFT, obs_dim=episodes[0].observations.shape[1])
    bag = tmp_path_factory.mktemp("offline") / "bag"
    write_episodes(bag, episodes, domain)
    return bag


def test_segment_on_a_full_disk_leaves_no_truncated_file(
    recorded: Path, synthetic_checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for free_kb in (8, 24):  # full before pi.npz, then before a later file
        with small_disk(tmp_path / f"disk{free_kb}", 256, free_kb=free_kb) as disk:
            out = disk / "seg"
            code = segment_main(["--bag", str(recorded), "--checkpoint", str(synthetic_checkpoint),
                                 "--out", str(out), "--plot-episodes", "1"])  # fmt: skip
            err = capsys.readouterr().err
            assert code == 2 and "Traceback" not in err, err
            assert f"cannot write '{out}/" in err and "No space left" in err and "free" in err, err
            assert not _hidden(out)
            for file in out.iterdir():  # whatever is there is whole
                if file.suffix == ".npz":
                    assert len(np.load(file).files) > 0
                elif file.suffix == ".json":
                    json.loads(file.read_text())


def test_annotated_bag_has_a_visible_storage_file_and_overwrite_option(
    recorded: Path, synthetic_checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "annotated"
    args = ["--bag", str(recorded), "--checkpoint", str(synthetic_checkpoint), "--out", str(tmp_path / "seg"),
            "--plot-episodes", "0", "--annotate", str(out)]  # fmt: skip
    assert segment_main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["annotated.mcap", "metadata.yaml"]
    assert "annotated.mcap" in (out / "metadata.yaml").read_text() and not _hidden(tmp_path)
    capsys.readouterr()
    assert segment_main(args) == 2
    err = capsys.readouterr().err
    assert "output exists" in err and "--overwrite" in err and "Traceback" not in err
    assert segment_main([*args, "--overwrite"]) == 0


def _foreign_mcap(path: Path) -> Path:
    """An mcap bag as another lab's recorder writes it (rosbags' writer, a JointState topic)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    joint_state = store.types["sensor_msgs/msg/JointState"]
    header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/arm/joint_states", joint_state.__msgtype__, typestore=store)
        for i in range(200):
            msg = joint_state(header(stamp(i, 0), "base"), ["a", "b"], np.array([i, 1.0]), np.zeros(2),
                              np.zeros(2))  # fmt: skip
            writer.write(conn, (i + 1) * 10**9, store.serialize_cdr(msg, joint_state.__msgtype__))
    return path


def test_an_unfinished_bag_says_so_and_names_skip_tail(tmp_path: Path) -> None:
    bag = _foreign_mcap(tmp_path / "recording")
    file = next(bag.glob("*.mcap"))
    data = file.read_bytes()
    file.write_bytes(data[: len(data) - 600])  # no footer and end magic yet: still being recorded
    with pytest.raises(CorruptBagError) as err:
        collect_rosbags(bag, None)
    text = str(err.value)
    assert "unfinished" in text and "--on-error skip_tail" in text and file.name in text, text
