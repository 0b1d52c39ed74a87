"""The compatibility corpus: bags as other ROS 2 tools and drivers write them, read value for value or
refused in one line (docs/bags.md)."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from compat_corpus import (
    CMD,
    GAP_NS,
    SPEC,
    STATE,
    STEP_NS,
    Demo,
    check_episodes,
    demos,
    edit_metadata,
    old_metadata,
    old_sqlite_schema,
    read_and_check,
    set_qos,
    storage_file,
    write_rosbags,
    write_split,
)
from padded_arrays import _padded

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import AlignmentError, BagNotFoundError, CorruptBagError, NoEpisodeError

JOINTS = ["shoulder", "elbow", "wrist"]
ROOT = Path(__file__).resolve().parents[2]
ARM_SPEC = ROOT / "config" / "reader_jointstate_example.yaml"


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("compression", [None, "file", "message"])
def test_rosbags_bags_read_back(tmp_path: Path, storage: str, compression: str | None) -> None:
    """Plain, file-compressed and message-compressed (zstd) bags of both storages."""
    demo = demos([20, 25, 18], seed=1)
    bag = write_rosbags(tmp_path / "bag", demo, storage=storage, compression=compression)
    read_and_check(bag, demo)


def _arm_bag(path: Path, *, commands: bool = True, header_zero: bool = False) -> Path:
    """A driver's JointState bag: 20 states and (optionally) 20 commands 2 ms later."""
    from rosbags.rosbag2 import Writer

    with Writer(path, version=9) as w:
        js = w.add_connection("/arm/joint_states", layout.JOINT_STATE, typestore=m.typestore())
        cmd = w.add_connection("/arm/joint_command", layout.JOINT_STATE, typestore=m.typestore())
        for k in range(20):
            t = 10**9 + k * STEP_NS
            state = m.joint_state(0 if header_zero else t, JOINTS, np.full(3, float(k)), np.ones(3))
            w.write(js, t + 1000, m.serialize(state))
            if commands:
                command = m.joint_state(0 if header_zero else t + 2_000_000, JOINTS, (), np.ones(3))
                w.write(cmd, t + 2_000_000, m.serialize(command))
    return path


def _arm_spec(**changes: object) -> ReaderSpec:
    return ReaderSpec.from_dict({**ReaderSpec.from_yaml(ARM_SPEC).to_dict(), **changes})


def test_header_stamp_zero_is_refused_in_one_line(tmp_path: Path) -> None:
    """A driver that leaves ``header.stamp`` at 0, read with ``stamp: header`` (was: IndexError)."""
    bag = _arm_bag(tmp_path / "bag", header_zero=True)
    for on_error in ("raise", "skip_tail"):
        with pytest.raises(AlignmentError) as info:
            read_episodes(bag, spec=_arm_spec(), on_error=on_error)  # type: ignore[arg-type]
        text = str(info.value)
        assert "'/arm/joint_states'" in text and "header.stamp is 0 in 20 of 20" in text
        assert "stamp: log" in text and str(bag) in text
    result = read_episodes(bag, spec=_arm_spec(stamp="log"))  # the fix the line names
    assert [e.length for e in result.episodes] == [20]  # final_observation: extrapolate


@pytest.mark.parametrize("stamp", ["header", "log"])
def test_topic_without_messages(tmp_path: Path, stamp: str) -> None:
    """A spec topic whose connection is in the bag with 0 messages (was: IndexError)."""
    bag = _arm_bag(tmp_path / "bag", commands=False)
    with pytest.raises(NoEpisodeError) as info:
        read_episodes(bag, spec=_arm_spec(stamp=stamp))
    assert "no message at all on ['/arm/joint_command']" in str(info.value)
    result = read_episodes(bag, spec=_arm_spec(stamp=stamp), on_error="skip_tail")
    assert result.episodes == [] and result.report.bags[0].messages["/arm/joint_command"] == 0


def test_extrapolate_with_one_commanded_step(tmp_path: Path) -> None:
    """A two-observation demonstration whose first observation has no command, with
    ``final_observation: extrapolate``: row T duplicates the one step (was: IndexError)."""
    demo = demos([20], seed=2)
    t = 10**9 + 20 * STEP_NS + GAP_NS
    states = np.asarray([[1, 2, 3, 4], [2, 3, 5, 7]], dtype=np.float32)
    demo.messages += [(t, STATE, m.serialize(m.float32_array(states[0]))),
                      (t + STEP_NS, STATE, m.serialize(m.float32_array(states[1]))),
                      (t + STEP_NS + 2_000_000, CMD, m.serialize(m.float32_array([0.5, -0.5])))]
    bag = write_rosbags(tmp_path / "bag", demo)
    spec = ReaderSpec.from_dict({**SPEC.to_dict(), "final_observation": "extrapolate"})
    result = read_episodes(bag, spec=spec)
    first, short = result.episodes
    np.testing.assert_array_equal(first.observations, demo.observations[0])
    np.testing.assert_array_equal(short.observations, states[[1, 1]])
    np.testing.assert_array_equal(short.actions, [[0.5, -0.5]])
    report = result.report.bags[0]
    assert report.adjusted == {DUPLICATED: [1]}
    assert report.final_duplicated == 1 and report.missing == {CMD: 1}


DUPLICATED = "last observation duplicated as row T"


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("topics", [(STATE, CMD), (CMD,)])
def test_qos_string_differs_from_the_storage_file(tmp_path: Path, storage: str,
                                                  topics: tuple[str, ...]) -> None:
    """metadata.yaml's QoS string differs from the storage file's (rosbag2's own test bags, bags
    rewritten by ``ros2 bag convert``): read anyway, with a note (was: 0 messages)."""
    demo = demos([20, 25, 18], seed=3)
    bag = write_rosbags(tmp_path / "bag", demo, storage=storage)
    edit_metadata(bag, lambda info: set_qos(info, topics))
    report = read_and_check(bag, demo).bags[0]  # type: ignore[attr-defined]
    noted = sorted(t for t in (STATE, CMD)
                   if any(f"topic '{t}': the QoS profiles" in note for note in report.notes))
    assert noted == sorted(topics)


def test_qos_string_differs_on_one_jointstate_topic(tmp_path: Path) -> None:
    """The same on one JointState topic of a driver's bag (was: IndexError)."""
    bag = _arm_bag(tmp_path / "bag")
    edit_metadata(bag, lambda info: set_qos(info, ("/arm/joint_command",)))
    result = read_episodes(bag, spec=_arm_spec())
    (episode,) = result.episodes
    np.testing.assert_array_equal(episode.observations[:20, :3], np.repeat(np.arange(20.0), 3).reshape(20, 3))
    np.testing.assert_array_equal(episode.actions, np.ones((20, 3)))


def _listing(folder: Path) -> dict[str, tuple[int, int]]:
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.iterdir()}


@pytest.mark.parametrize("on_error", ["raise", "skip_tail"])
def test_wal_mode_sqlite_is_read_without_writing_beside_it(tmp_path: Path, on_error: str) -> None:
    """A WAL-mode ``.db3`` (older rosbag2, the ``resilient`` preset): read, and nothing is created or
    changed in the bag's directory (was: ``-shm`` and ``-wal`` files left beside the bag)."""
    demo = demos([20, 25], seed=4)
    bag = write_rosbags(tmp_path / "bag", demo, storage="sqlite3")
    con = sqlite3.connect(storage_file(bag))
    assert con.execute("PRAGMA journal_mode=WAL").fetchone() == ("wal",)
    con.close()
    before = _listing(bag)
    read_and_check(bag, demo, on_error=on_error)
    read_and_check(storage_file(bag), demo, on_error=on_error)
    assert _listing(bag) == before


def test_multiarray_data_offset_padding_is_not_data(tmp_path: Path) -> None:
    """``layout.data_offset`` padding at the front of ``data`` (Float32 and Float64 MultiArray, 1-D and
    2-D layouts) is not read as values (was: the padding became the first elements)."""
    from rosbags.rosbag2 import Writer

    demo = demos([12, 9], seed=5)
    f64 = "std_msgs/msg/Float64MultiArray"
    with Writer(tmp_path / "bag", version=9) as w:
        state = w.add_connection(STATE, layout.FLOAT32_ARRAY, typestore=m.typestore())
        cmd = w.add_connection(CMD, f64, typestore=m.typestore())
        obs_rows = iter(np.concatenate(demo.observations))
        act_rows = iter(np.concatenate(demo.actions))
        for k, (stamp, topic, _) in enumerate(demo.messages):
            if topic == STATE:
                w.write(state, stamp, _padded(layout.FLOAT32_ARRAY, next(obs_rows), 3, dims=1 + k % 2))
            else:
                w.write(cmd, stamp, _padded(f64, next(act_rows), 1 + k % 2))
    spec = ReaderSpec.from_dict({**SPEC.to_dict(), "action": {"topic": CMD, "type": f64, "dim": 2}})
    read_and_check(tmp_path / "bag", demo, spec=spec)
    raw = _padded(layout.FLOAT32_ARRAY, np.arange(4.0), 2)
    np.testing.assert_array_equal(m.parse_float32_array(raw), np.arange(4.0))  # the live node's parser


def test_truncated_message_compressed_mcap_keeps_what_precedes_the_cut(tmp_path: Path) -> None:
    """A message-compressed (zstd) mcap cut at 3/4, read with ``skip_tail``: the demonstrations before
    the cut, value for value (was: no episode, the compressed frames taken for CDR)."""
    demo = demos([300] * 50, seed=6)  # about 3 MB: several 1 MiB chunks
    bag = write_rosbags(tmp_path / "bag", demo, compression="message")
    file = storage_file(bag)
    with open(file, "r+b") as fh:
        fh.truncate(file.stat().st_size * 3 // 4)
    result = read_episodes(bag, spec=SPEC, on_error="skip_tail")
    assert 10 <= len(result.episodes) < 50 and result.report.bags[0].error
    demo.observations, demo.actions = (demo.observations[:len(result.episodes)],
                                       demo.actions[:len(result.episodes)])
    check_episodes(result.episodes, demo)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_message_compressed_storage_file_without_metadata(tmp_path: Path, storage: str) -> None:
    """The storage file of a message-compressed bag read on its own (no metadata.yaml says it is
    compressed): read, with a note (was: 'cannot decode', called corrupt)."""
    demo = demos([20, 25, 18], seed=7)
    bag = write_rosbags(tmp_path / "bag", demo, storage=storage, compression="message")
    (bag / "metadata.yaml").unlink()
    for path in (storage_file(bag), bag):
        report = read_and_check(path, demo).bags[0]  # type: ignore[attr-defined]
        assert any("zstd-compressed (rosbag2 message compression)" in note for note in report.notes)


CUT = 10**9 + 20 * STEP_NS + GAP_NS + 3 * STEP_NS + 1  # inside the second demonstration, after 3 steps


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("metadata", [True, False])
def test_split_bag_is_one_bag(tmp_path: Path, storage: str, metadata: bool) -> None:
    """A split bag, with its metadata.yaml or without it (the recorder crashed), read as a directory, as
    its storage files one by one and as a glob: the demonstration cut by the file boundary stays one
    (was, without metadata.yaml or file by file: steps [20, 3, 21, 18] instead of [20, 25, 18])."""
    demo = demos([20, 25, 18], seed=8)
    files = write_split(tmp_path / "bag", demo, [CUT, CUT + 30 * STEP_NS], storage=storage, metadata=metadata)
    for paths in (tmp_path / "bag", files, str(tmp_path / "bag" / "bag_*")):
        report = read_and_check(paths, demo).bags  # type: ignore[attr-defined]
        assert [b.path for b in report] == [str(tmp_path / "bag")]
        reindexed = [n for n in report[0].notes if n.startswith("no metadata.yaml")]
        assert bool(reindexed) != metadata and all("ros2 bag reindex" in n for n in reindexed)
    assert sorted(p.name for p in (tmp_path / "bag").iterdir()) == sorted(
        [f.name for f in files] + (["metadata.yaml"] if metadata else []))  # nothing written beside them
    with pytest.raises(BagNotFoundError) as info:
        read_episodes(files[:2], spec=SPEC)
    assert "one of the 3 split files" in str(info.value) and "['bag_2." in str(info.value)


def test_split_bag_without_metadata_message_compressed_and_truncated(tmp_path: Path) -> None:
    """A recorder killed while writing the last split of a message-compressed mcap bag: no metadata.yaml
    and a truncated last file; ``skip_tail`` keeps the demonstrations before the cut."""
    demo = demos([20, 25, 18], seed=9)
    files = write_split(tmp_path / "bag", demo, [CUT, CUT + 30 * STEP_NS], compression="message",
                        metadata=False)
    with open(files[-1], "r+b") as fh:
        fh.truncate(files[-1].stat().st_size - 100)  # the summary and the footer are lost
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=SPEC)
    assert str(tmp_path / "bag") in str(info.value) and "ompn_reindex" not in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=SPEC, on_error="skip_tail")
    assert result.report.bags[0].error and "ompn_reindex" not in result.report.bags[0].error
    check_episodes(result.episodes, Demo(demo.observations[:2], demo.actions[:2]))  # the last one is cut


@pytest.mark.parametrize(("storage", "version", "schema"), [
    ("sqlite3", 4, 1), ("sqlite3", 5, 2), ("sqlite3", 6, 3), ("sqlite3", 7, 3), ("sqlite3", 8, None),
    ("sqlite3", 9, None), ("mcap", 5, None), ("mcap", 6, None), ("mcap", 7, None), ("mcap", 8, None),
])
def test_metadata_versions_and_old_sqlite_schemas(tmp_path: Path, storage: str, version: int,
                                                  schema: int | None) -> None:
    """metadata.yaml versions 4 to 9 (Foxy to Jazzy) with the ``.db3`` schemas of their time; where the
    storage holds no QoS string and metadata.yaml one (rosbag2's own test bags), a note says so."""
    demo = demos([20, 25, 18], seed=10)
    bag = write_rosbags(tmp_path / "bag", demo, storage=storage, version=8 if version < 9 else 9)
    edit_metadata(bag, lambda info: old_metadata(info, version))
    if schema is not None:
        old_sqlite_schema(storage_file(bag), schema)
    report = read_and_check(bag, demo).bags[0]  # type: ignore[attr-defined]
    storage_has_qos = schema is not None and schema >= 2  # rosbags stores [] for the QoS
    assert any("QoS profiles" in note for note in report.notes) == (version < 9 and not storage_has_qos)


def test_foreign_mcap_writer(tmp_path: Path) -> None:
    """A bare ``.mcap`` written with the ``mcap`` package's ROS 2 writer (Foxglove's), no metadata.yaml."""
    from mcap_ros2.writer import Writer as McapRos2Writer

    demo = demos([20, 25, 18], seed=11)
    msgdef = "std_msgs/MultiArrayLayout layout\nfloat32[] data\n" + "=" * 80 + (
        "\nMSG: std_msgs/MultiArrayLayout\nMultiArrayDimension[] dim\nuint32 data_offset\n" + "=" * 80
        + "\nMSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n")
    with open(tmp_path / "demo.mcap", "wb") as fh:
        writer = McapRos2Writer(fh)
        schema = writer.register_msgdef(layout.FLOAT32_ARRAY, msgdef)
        for stamp, topic, raw in demo.messages:
            values = m.parse_float32_array(raw)
            message = {"layout": {"dim": [{"label": "v", "size": len(values), "stride": len(values)}],
                                  "data_offset": 0}, "data": values.tolist()}
            writer.write_message(topic, schema, message, log_time=stamp, publish_time=stamp)
        writer.finish()
    read_and_check(tmp_path / "demo.mcap", demo)
    read_and_check(tmp_path, demo)  # a folder of bare mcap files


def test_wal_mode_sqlite_in_a_read_only_directory(tmp_path: Path) -> None:
    """The same bag on a read-only file system (a read-only bind mount in a private mount namespace;
    skipped where the test may not create one): read (was: 'sqlite database is malformed (PRAGMA
    quick_check: unable to open database file)')."""
    demo = demos([20, 25], seed=4)
    bag = write_rosbags(tmp_path / "ro" / "bag", demo, storage="sqlite3")
    con = sqlite3.connect(storage_file(bag))
    con.execute("PRAGMA journal_mode=WAL")
    con.close()
    code = ("import sys; from ompn_ros.data import read_episodes; from compat_corpus import SPEC;"
            "r = read_episodes(sys.argv[1], spec=SPEC); print([e.length for e in r.episodes])")
    folder = tmp_path / "ro"
    script = (f"mount --bind {folder} {folder} && mount -o remount,ro,bind {folder} || exit 77; "
              f"! touch {folder}/probe 2>/dev/null || exit 77; "
              f'"{sys.executable}" -c "{code}" {bag}')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "test")])}
    try:
        proc = subprocess.run(["unshare", "-m", "sh", "-c", script], env=env, capture_output=True, text=True,
                              timeout=120)
    except FileNotFoundError:
        pytest.skip("no unshare")
    if proc.returncode == 77 or "unshare:" in proc.stderr:
        pytest.skip(f"cannot make a read-only mount here: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[20, 25]"
