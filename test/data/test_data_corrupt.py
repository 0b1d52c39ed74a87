"""Bad bags: each raises the right BagError naming file/topic/index; skip_tail keeps the good part."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros import layout
from ompn_ros.data import (
    BagNotFoundError,
    CorruptBagError,
    MissingTopicError,
    ReaderSpec,
    TopicTypeError,
    VectorLengthError,
    read_episodes,
    write_episodes,
)
from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import EpisodeBagWriter


def _storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


def test_truncated_mcap(tmp_path: Path) -> None:
    episodes = make_episodes("craft", 25, seed=5, min_steps=30, max_steps=30)  # ~3.5 MB, several chunks
    write_episodes(tmp_path / "bag", episodes, "craft", storage="mcap")
    file = _storage_file(tmp_path / "bag")
    with open(file, "r+b") as fh:
        fh.truncate(file.stat().st_size * 3 // 4)
    spec = ReaderSpec.for_domain("craft")
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert str(file) in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    kept = result.episodes
    assert 1 <= len(kept) < len(episodes)
    for a, b in zip(episodes, kept):
        assert_same_episode(a, b)
    report = result.report.bags[0]
    assert report.error and "mcap" in report.error
    assert report.dropped_episodes >= 1


def test_zeroed_sqlite_page(tmp_path: Path) -> None:
    episodes = make_episodes("dial", 40, seed=6, min_steps=50, max_steps=50)
    write_episodes(tmp_path / "bag", episodes, "dial", storage="sqlite3")
    file = _storage_file(tmp_path / "bag")
    pages = file.stat().st_size // 4096
    with open(file, "r+b") as fh:  # a b-tree leaf of the messages table (no overflow pages: small rows)
        fh.seek(pages // 2 * 4096)
        fh.write(b"\0" * 4096)
    spec = ReaderSpec.for_domain("dial")
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert str(file) in str(info.value) and "malformed" in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert 1 <= len(result.episodes) < len(episodes)
    for a, b in zip(episodes, result.episodes):
        assert_same_episode(a, b, joints=True)
    assert "sqlite scan broken" in (result.report.bags[0].error or "")


def _bag_with_short_observation(path: Path, bad_index: int) -> list:
    """Craft bag whose observation message #bad_index has 100 instead of 1075 floats."""
    episodes = make_episodes("craft", 4, seed=7, min_steps=6, max_steps=6)
    with EpisodeBagWriter(path, layout.CRAFT) as writer:
        real = writer._write
        counter = {"obs": 0}

        def write(name: str, stamp: int, raw: bytes) -> None:
            if name == layout.OBSERVATION:
                if counter["obs"] == bad_index:
                    raw = m.serialize(m.float32_array(np.zeros(100)))
                counter["obs"] += 1
            real(name, stamp, raw)

        writer._write = write  # type: ignore[method-assign]
        for ep in episodes:
            writer.write_episode(ep)
    return episodes


def _bag_with_int_observation(path: Path) -> None:
    from rosbags.rosbag2 import Writer

    with Writer(path, version=9) as w:
        obs = w.add_connection("/observation", layout.INT32, typestore=m.typestore())
        act = w.add_connection("/action", layout.INT32, typestore=m.typestore())
        w.write(obs, 1, m.serialize(m.int32(3)))
        w.write(act, 2, m.serialize(m.int32(1)))


def test_wrong_vector_length(tmp_path: Path) -> None:
    bad = 7 * 2 + 3  # 4th observation of the 3rd episode (7 observations per episode)
    episodes = _bag_with_short_observation(tmp_path / "bag", bad)
    spec = ReaderSpec.for_domain("craft")
    with pytest.raises(VectorLengthError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    err = info.value
    assert err.topic == "/observation" and err.index == bad
    assert str(tmp_path / "bag") in str(err) and f"message #{bad}" in str(err) and "1075" in str(err)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert len(result.episodes) == 2
    for a, b in zip(episodes, result.episodes):
        assert_same_episode(a, b)
    assert "message #17" in (result.report.bags[0].error or "")


def test_wrong_type_on_observation_topic(tmp_path: Path) -> None:
    _bag_with_int_observation(tmp_path / "bag")
    for on_error in ("raise", "skip_tail"):
        with pytest.raises(TopicTypeError) as info:
            read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft"), on_error=on_error)  # type: ignore[arg-type]
        assert info.value.topic == "/observation" and info.value.index == 0
        assert "std_msgs/msg/Int32" in str(info.value) and str(tmp_path / "bag") in str(info.value)


def test_missing_topic_and_missing_bag(tmp_path: Path) -> None:
    write_episodes(tmp_path / "bag", make_episodes("craft", 1), "craft")
    spec = ReaderSpec.from_dict({"action": {"topic": "cmd", "type": layout.INT32}})
    with pytest.raises(MissingTopicError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert info.value.topic == "/cmd" and "bag topics" in str(info.value)
    with pytest.raises(BagNotFoundError, match="no such file"):
        read_episodes(tmp_path / "nothing")
    with pytest.raises(BagNotFoundError, match="glob matched nothing"):
        read_episodes(str(tmp_path / "none_*"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagNotFoundError, match="no rosbag2 bag"):
        read_episodes(tmp_path / "empty")


def test_strict_alignment_missing_action(tmp_path: Path) -> None:
    """A dropped action message: strict presets raise AlignmentError at that observation."""
    from ompn_ros.data import AlignmentError

    episodes = make_episodes("craft", 2, seed=8, min_steps=5, max_steps=5)
    with EpisodeBagWriter(tmp_path / "bag", layout.CRAFT) as writer:
        real = writer._write
        seen = {"n": 0}

        def write(name: str, stamp: int, raw: bytes) -> None:
            if name == layout.ACTION:
                seen["n"] += 1
                if seen["n"] == 3:
                    return
            real(name, stamp, raw)

        writer._write = write  # type: ignore[method-assign]
        for ep in episodes:
            writer.write_episode(ep)
    with pytest.raises(AlignmentError) as info:
        read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft"))
    assert info.value.topic == "/observation" and info.value.index == 2
    loose = read_episodes(tmp_path / "bag", spec=ReaderSpec(strict=False))
    assert loose.report.total("missing") == {"/action": 1}
    assert loose.report.bags[0].dropped_steps == 1
    assert loose.episodes[0].length == 4
    assert_same_episode(episodes[1], loose.episodes[1])
