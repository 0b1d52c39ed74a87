"""A bag assembled from several topics (``ReaderSpec.assemble``) and cut at a corrupt tail is read a
second time from its storage (``reader.observe.reread``): that read takes the messages as the first
one does, also when metadata.yaml's QoS string differs from the storage file's or the messages are
zstd frames no metadata.yaml declares (docs/bags.md)."""

from __future__ import annotations

from pathlib import Path

import pytest
from assembled_bags import _assemble_bag
from compat_corpus import edit_metadata, set_qos
from joint_lab_bags import SPEC_DICT, TYPES
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m

SPEC = ReaderSpec.from_dict(SPEC_DICT)


def _same_episodes(a: object, b: object) -> None:
    got, want = a.episodes, b.episodes  # type: ignore[attr-defined]
    assert len(got) == len(want) >= 1
    for x, y in zip(got, want, strict=True):
        for name in ("observations", "actions", "subtask"):
            assert getattr(x, name).tobytes() == getattr(y, name).tobytes(), name


def _message_compressed(src: Path, dst: Path) -> Path:
    """``src`` copied message by message into a message-compressed (zstd) bag; its storage file."""
    writer = Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with Reader(src) as reader, writer:
        conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=m.typestore())
                 for c in reader.connections}
        for conn, stamp, data in reader.messages():
            writer.write(conns[conn.topic], stamp, data)
    (dst / "metadata.yaml").unlink()
    (file,) = dst.glob("*.mcap")
    return file


@pytest.mark.parametrize("variant", ["qos", "zstd"])
def test_cut_bag_is_assembled_again_as_first_read(tmp_path: Path, variant: str) -> None:
    """Was: the second read asked ``rosbags`` for metadata.yaml's connections only (no message of a
    topic whose QoS string differs) and took zstd frames for CDR (no episode)."""
    _assemble_bag(tmp_path / "bag", bad_command=30)  # a cut in the second episode
    plain = read_episodes(tmp_path / "bag", spec=SPEC, on_error="skip_tail")
    if variant == "qos":
        edit_metadata(tmp_path / "bag", lambda info: set_qos(info, tuple(TYPES)))
        path = tmp_path / "bag"
    else:
        path = _message_compressed(tmp_path / "bag", tmp_path / "zstd")
    result = read_episodes(path, spec=SPEC, on_error="skip_tail")
    _same_episodes(result, plain)
    report, first = result.report.bags[0], plain.report.bags[0]
    assert report.obs_dropped == first.obs_dropped and report.error
    hint = "the QoS profiles" if variant == "qos" else "zstd-compressed"
    assert any(hint in note for note in report.notes)
