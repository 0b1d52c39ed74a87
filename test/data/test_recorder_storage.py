"""Durable storage (CRC'd mcap chunks, periodic commits) and the stop cut, without ROS."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import CRCValidationError, StreamReader
from rosbags.rosbag2 import StoragePlugin

from ompn_ros import layout
from ompn_ros.data import BagError, Episode, read_episodes, write_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.recorder.sim_stamps import SimStamper
from ompn_ros.data.recorder.stop_cut import StopCut
from ompn_ros.data.recorder.storage import DurableWriter, chunk_crcs, offered_qos, refresh_chunk_crcs


def _episodes(n: int = 3, steps: int = 40) -> list[Episode]:
    rng = np.random.default_rng(0)
    return [Episode(observations=rng.standard_normal((steps + 1, layout.CRAFT.obs_dim)).astype(np.float32),
                    actions=rng.integers(0, 5, steps), subtask=np.repeat([0, 1], steps // 2),
                    sketch=np.array([1, 2]), task="makebed", seed=i, success=True) for i in range(n)]


def _mcap_file(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def test_mcap_chunks_carry_crcs_that_the_mcap_package_verifies(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    stats = write_episodes(bag, _episodes(), "craft", storage="mcap")
    crcs = chunk_crcs(_mcap_file(bag))
    assert crcs and all(stored != 0 and stored == computed for stored, computed in crcs)
    with open(_mcap_file(bag), "rb") as fh:
        n = sum(1 for _ in make_reader(fh, validate_crcs=True).iter_messages())
    assert n == stats.total_messages


def test_flipped_byte_in_a_chunk_is_detected(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_episodes(bag, _episodes(), "craft", storage="mcap")
    path = _mcap_file(bag)
    data = bytearray(path.read_bytes())
    marker = m.encode_float32_array(np.zeros(0, np.float32), "obs")[:12]  # an observation's CDR prefix
    at = data.index(marker, len(data) // 3) + 40  # inside some observation's floats
    data[at] ^= 0x01
    path.write_bytes(bytes(data))
    assert any(stored != computed for stored, computed in chunk_crcs(path))
    with open(path, "rb") as fh, pytest.raises(CRCValidationError):
        list(StreamReader(fh, validate_crcs=True).records)
    with pytest.raises(BagError):  # the bag reader (rosbags) checks the CRC too
        read_episodes(bag)
    assert refresh_chunk_crcs(path) == 1  # a deliberate edit can be made consistent again
    assert all(stored == computed for stored, computed in chunk_crcs(path))
    assert len(read_episodes(bag).episodes) == 3


def _write(writer: DurableWriter, n: int) -> None:
    conn = writer.add_connection("/x", layout.INT32, typestore=m.typestore())
    for i in range(n):
        writer.write(conn, 1_000 + i, m.encode_int32(i))


def _rows(bag: Path) -> int:
    con = sqlite3.connect(f"file:{next(bag.glob('*.db3'))}?mode=ro", uri=True)
    try:
        return int(con.execute("SELECT count(*) FROM messages").fetchone()[0])
    finally:
        con.close()


def test_sqlite_checkpoint_commits_while_the_bag_is_open(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    writer = DurableWriter(bag, storage_plugin=StoragePlugin.SQLITE3, commit_period=None)
    writer.open()
    _write(writer, 50)
    assert _rows(bag) == 0  # one open transaction: a killed process would lose it all
    writer.checkpoint()
    assert _rows(bag) == 50
    writer.close()


def test_commit_period_checkpoints_during_writes(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    writer = DurableWriter(bag, storage_plugin=StoragePlugin.SQLITE3, commit_period=1e-9)
    writer.open()
    _write(writer, 20)
    assert writer.checkpoints == 20 and _rows(bag) == 20
    writer.close()


def test_mcap_checkpoint_flushes_a_readable_prefix(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    writer = DurableWriter(bag, storage_plugin=StoragePlugin.MCAP, commit_period=None)
    writer.open()
    _write(writer, 30)
    writer.checkpoint()
    got = []
    with open(_mcap_file(bag), "rb") as fh:  # no footer yet: read record by record until the end
        try:
            for rec in StreamReader(fh, validate_crcs=True).records:
                if isinstance(rec, Message):
                    got.append(m.parse_int32(rec.data))
        except McapError:
            pass
    assert got == list(range(30))
    writer.close()


def test_commit_period_must_be_positive(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="commit_period"):
        DurableWriter(tmp_path / "bag", commit_period=0.0)


# --- stop cut -----------------------------------------------------------------------------------------
def _offer_all(cut: StopCut[str], stream: list[tuple[str, int]]) -> list[str]:
    out = []
    for topic, src in stream:
        out += cut.offer(topic, src, f"{topic}@{src}")
    return out + cut.finish()


def test_stop_cut_ends_every_topic_before_the_first_step_after_the_signal() -> None:
    cut: StopCut[str] = StopCut("obs")
    cut.request(25)
    # steps at 0, 10, 20, 30 (obs, then sub, act); delivery order mixed across topics
    stream = [("obs", 0), ("sub", 1), ("act", 2), ("obs", 10), ("act", 12), ("sub", 11), ("obs", 20),
              ("act", 32), ("sub", 21), ("obs", 30), ("act", 22), ("sub", 31), ("obs", 40)]
    written = _offer_all(cut, stream)
    assert sorted(written) == sorted(f"{t}@{s}" for t, s in stream if s < 30)
    assert cut.cut_ns == 30 and cut.dropped == 4 and cut.passed == {"obs", "act", "sub"}


def test_stop_cut_without_a_later_step_releases_the_held_messages() -> None:
    cut: StopCut[str] = StopCut("obs")
    cut.request(5)
    assert _offer_all(cut, [("obs", 0), ("sub", 6), ("act", 7)]) == ["obs@0", "sub@6", "act@7"]
    assert cut.cut_ns is None and cut.dropped == 0


def test_stop_cut_without_step_topic_cuts_at_the_signal() -> None:
    cut: StopCut[str] = StopCut(None)
    assert cut.offer("a", 100, "early") == ["early"]  # before any stop request: written
    cut.request(50)
    assert _offer_all(cut, [("a", 49), ("a", 50), ("b", 10)]) == ["a@49", "b@10"]


# --- sim-time stamps ----------------------------------------------------------------------------------
def test_sim_stamps_follow_the_clock() -> None:
    st = SimStamper()
    assert st.stamp(5_000) == 5_000 and not st.started  # no /clock yet: system time
    st.open_step(10_000, sim_now_ns=0)
    assert not st.started
    st.open_step(10_000, sim_now_ns=777_000)
    assert st.started and st.stamp(10_000) == 777_000
    st.open_step(90_000, sim_now_ns=900_000)  # sim time moved on: the next step starts there
    assert st.stamp(90_000) == 900_000


def test_sim_stamps_keep_publish_order_whatever_the_delivery_order() -> None:
    rng = np.random.default_rng(1)
    st = SimStamper()
    # steps every 1000 ns of system time, three messages 0/100/200 ns into each step; sim time stands
    # still for four steps at a time (coarse /clock) and runs at a quarter of system time
    steps = range(40)
    sim = {t: 5_000_000 + 250 * (t - t % 4) for t in steps}
    msgs = [(t, k, 1_000 * t + 100 * k) for t in steps for k in range(3)]
    order = rng.permutation(len(msgs))  # delivery order: any
    stamped = {}
    for j in order:
        t, k, src = msgs[j]
        if k == 0 or not st.started:
            st.open_step(src, sim[t])
        stamped[(t, k)] = st.stamp(src)
    ranked = sorted(stamped, key=stamped.get)
    assert ranked == sorted(stamped)  # (step, topic) order == stamp order
    assert len(set(stamped.values())) == len(stamped)


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_metadata_says_jazzy_and_the_offered_qos(tmp_path: Path, plugin: StoragePlugin) -> None:
    """``ros_distro: jazzy`` in metadata.yaml and in the storage file, and the publishers' QoS per topic
    (a best-effort sensor stays best effort when ``ros2 bag play`` replays it)."""
    rclpy_qos = pytest.importorskip("rclpy.qos")
    from rosbags.interfaces import QosDurability, QosHistory, QosReliability
    from rosbags.rosbag2 import Reader

    sensor = rclpy_qos.qos_profile_sensor_data  # best effort, keep last 5
    with DurableWriter(tmp_path / "bag", storage_plugin=plugin) as writer:
        conn = writer.add_connection("/scan", layout.FLOAT32_ARRAY, typestore=m.typestore(),
                                     offered_qos_profiles=offered_qos([sensor]))
        writer.write(conn, 1, m.encode_float32_array([1.0]))
    info = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy"
    (offered,) = info["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
    assert (offered["reliability"], offered["history"], offered["depth"]) == ("best_effort", "keep_last", 5)
    with Reader(tmp_path / "bag") as reader:
        (qos,) = reader.connections[0].ext.offered_qos_profiles  # type: ignore[union-attr]
        assert reader.ros_distro == "jazzy"
    assert (qos.reliability, qos.history, qos.durability) == (
        QosReliability.BEST_EFFORT, QosHistory.KEEP_LAST, QosDurability.VOLATILE)
    (file,) = [p for p in (tmp_path / "bag").iterdir() if p.suffix in (".mcap", ".db3")]
    assert b"ros_distro: jazzy" in file.read_bytes() and b"ros_distro: rosbags" not in file.read_bytes()
