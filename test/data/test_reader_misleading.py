"""Bags the reader used to misname or crash on: intact mcap files ``rosbags`` refuses, a file cut
inside its only chunk, a label topic without messages, a renamed split bag without metadata.yaml,
and a bare file whose bulk is a topic the spec does not use (docs/bags.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from compat_corpus import (
    CMD,
    SPEC,
    STATE,
    demos,
    read_and_check,
    storage_file,
    write_mcap,
    write_rosbags,
    write_split,
)

from ompn_ros import layout
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import CorruptBagError, NoEpisodeError
from ompn_ros.data.reader.paths import wanted_topics
from ompn_ros.data.reader.raw import collect_rosbags

ROOT = Path(__file__).resolve().parents[2]
LENGTHS = [20, 25, 18]
GAP_CUT = 10**9 + 20 * 40_000_000 + 10 * 40_000_000 + 2 * 10**9  # inside the second demonstration


@pytest.mark.parametrize("on_error", ["raise", "skip_tail"])
def test_unindexed_mcap_out_of_time_order(tmp_path: Path, on_error: str) -> None:
    """A streaming logger's mcap without index whose messages are not in log-time order (each
    topic's buffer flushed in turn): read record by record, value for value, noted (was: 'corrupt',
    and under ``skip_tail`` no episode)."""
    demo = demos(LENGTHS, seed=21)
    by_topic = sorted(demo.messages, key=lambda msg: msg[1] != STATE)  # every state, then every command
    bag = write_mcap(tmp_path / "lab.mcap", by_topic, indexed=False)
    report = read_and_check(bag, demo, on_error=on_error).bags[0]  # type: ignore[attr-defined]
    assert report.error is None
    assert any("no index and its messages are not in log-time order" in n for n in report.notes)


@pytest.mark.parametrize("on_error", ["raise", "skip_tail"])
def test_intact_mcap_with_an_empty_profile(tmp_path: Path, on_error: str) -> None:
    """A writer that leaves the mcap profile empty: read, every demonstration (was: refused, and under
    ``skip_tail`` the last demonstration lost)."""
    demo = demos(LENGTHS, seed=22)
    bag = write_mcap(tmp_path / "lab.mcap", demo.messages, profile="")
    report = read_and_check(bag, demo, on_error=on_error).bags[0]  # type: ignore[attr-defined]
    assert report.error is None and any("profile is not 'ros2'" in n for n in report.notes)


def test_single_chunk_mcap_cut_inside_its_chunk(tmp_path: Path) -> None:
    """An mcap file of one chunk, cut inside it: refused as unfinished; under ``skip_tail`` no episode
    and the damage in the report (was: 'required topic not in bag (bag topics: [])')."""
    demo = demos(LENGTHS, seed=23)
    whole = storage_file(write_rosbags(tmp_path / "bag", demo)).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 7 // 10])
    with pytest.raises(CorruptBagError, match="unfinished"):
        read_episodes(cut, spec=SPEC)
    result = read_episodes(cut, spec=SPEC, on_error="skip_tail")
    report = result.report.bags[0]
    assert result.episodes == [] and report.error is not None and "mcap stream broken" in report.error
    assert any("nothing could be read before the damage" in n for n in report.notes)


def _with_empty_label_topic(path: Path) -> Path:
    from rosbags.rosbag2 import Writer

    demo = demos(LENGTHS, seed=24)
    with Writer(path, version=9) as w:
        conns = {t: w.add_connection(t, layout.FLOAT32_ARRAY, typestore=m.typestore()) for t in (STATE, CMD)}
        w.add_connection("/lab/skill", layout.INT32, typestore=m.typestore())  # never published on
        for stamp, topic, raw in demo.messages:
            w.write(conns[topic], stamp, raw)
    return path


LABELLED = ReaderSpec.from_dict({**SPEC.to_dict(), "subtask": "/lab/skill", "labels": "id"})


def test_label_topic_without_messages_is_refused(tmp_path: Path) -> None:
    """A label topic recorded with 0 messages: one line naming it and ``labels: none``; ``skip_tail``
    reads no episode and says why (was: IndexError traceback)."""
    bag = _with_empty_label_topic(tmp_path / "bag")
    with pytest.raises(NoEpisodeError) as info:
        read_episodes(bag, spec=LABELLED)
    assert "'/lab/skill'" in str(info.value) and "labels: none" in str(info.value)
    result = read_episodes(bag, spec=LABELLED, on_error="skip_tail")
    assert result.episodes == [] and result.report.bags[0].dropped == {"no labels": 1}


@pytest.mark.parametrize("cli", ["ompn_train", "ompn_segment"])
def test_label_topic_without_messages_cli_exit_2(tmp_path: Path, cli: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Both command-line tools: exit 2 with the one line, no traceback (was: exit 1, IndexError)."""
    from ompn_ros.cli import segment, train

    bag = _with_empty_label_topic(tmp_path / "bag")
    spec_file = tmp_path / "reader.yaml"
    spec_file.write_text(yaml.safe_dump({"reader": LABELLED.to_dict()}))
    if cli == "ompn_train":
        code = train.main(["--bags", str(bag), "--config", str(ROOT / "config" / "train_dial.yaml"),
                           "--out", str(tmp_path / "run"), "--set", f"data.reader_spec={spec_file}"])
    else:
        code = segment.main(["--bag", str(bag), "--checkpoint", str(shipped_checkpoint("dial")),
                             "--reader-config", str(spec_file), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.startswith(f"{cli}: error: ")]
    assert len(lines) == 1 and "no message at all on the label topic" in lines[0], err
    assert "Traceback" not in err


def test_renamed_split_bag_without_metadata(tmp_path: Path) -> None:
    """A split bag without metadata.yaml in a directory the user renamed (its files keep the old name):
    read as one bag, as ``ros2 bag reindex`` takes any ``<name>_<n>.<ext>`` (was: [20, 3, 21, 18])."""
    demo = demos(LENGTHS, seed=25)
    files = write_split(tmp_path / "rosbag2_2026_12_07", demo, [GAP_CUT], metadata=False)
    renamed = files[0].parent.rename(tmp_path / "pick_and_place")
    report = read_and_check(renamed, demo).bags[0]  # type: ignore[attr-defined]
    assert any("read as one bag in split order" in n for n in report.notes)


def test_separate_recordings_stay_separate(tmp_path: Path) -> None:
    """Control: bare files of separate recordings that happen to end in ``_<n>`` but are not numbered
    from 0 stay separate bags."""
    folder = tmp_path / "runs"
    folder.mkdir()
    first, second = demos([20], seed=26), demos([25, 18], seed=27)
    for name, demo in (("run_1", first), ("run_2", second)):
        write_mcap(folder / f"{name}.mcap", demo.messages)
    result = read_episodes(folder, spec=SPEC)
    assert [e.length for e in result.episodes] == [20, 25, 18] and len(result.report.bags) == 2


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bare_file_keeps_only_the_wanted_topics(tmp_path: Path, storage: str) -> None:
    """A bare storage file (no metadata.yaml) whose bulk is a camera: only the spec's topics are kept
    while reading (was: every topic's bytes held; bench/bench_unwanted.py measures the memory)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    demo = demos(LENGTHS, seed=28)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(tmp_path / "bag", version=9, storage_plugin=plugin) as w:  # type: ignore[arg-type]
        conns = {t: w.add_connection(t, layout.FLOAT32_ARRAY, typestore=m.typestore()) for t in (STATE, CMD)}
        cam = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=m.typestore())
        image = m.msg_class("sensor_msgs/msg/Image")(header=m.header(0, "cam"), height=64, width=64,
                                                     encoding="mono8", is_bigendian=0, step=64,
                                                     data=np.zeros(64 * 64, "uint8"))
        for stamp, topic, raw in demo.messages:
            w.write(conns[topic], stamp, raw)
            if topic == STATE:
                w.write(cam, stamp + 1, m.serialize(image))
    bare = storage_file(tmp_path / "bag")
    kept = collect_rosbags(bare, None, None, lambda types: wanted_topics(SPEC, types))
    assert sorted(kept.topics) == [CMD, STATE] and "/camera/image_raw" in kept.types
    read_and_check(bare, demo)
