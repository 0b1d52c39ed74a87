"""Annotated bags: a recorded bag replayed through the segmenter, copied with ~/pi, ~/segment and
~/boundary added, and checked with the independent ``mcap`` / ``mcap_ros2`` readers and rosbags."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

torch = pytest.importorskip("torch")
mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.app.annotate import (  # noqa: E402
    CUSTOM_DATA_KEY,
    STAMPS_KEY,
    annotate_bag,
    match_observation_stamps,
    observation_stamps,
)
from ompn_ros.app.errors import AnnotateError  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.reader import read_episodes  # noqa: E402
from ompn_ros.data.recorder.bag_writer import write_episodes  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.model.streaming import StreamingPolicy  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402
from ompn_ros.train import synthetic  # noqa: E402

torch.set_num_threads(1)
NS = "/ompn_node"
PI, SEGMENT, BOUNDARY, STATE = f"{NS}/pi", f"{NS}/segment", f"{NS}/boundary", f"{NS}/state"
ADDED = (PI, SEGMENT, BOUNDARY, STATE)
# Craft topics with the small observations of the synthetic corridor task
DOMAIN = dataclasses.replace(layout.CRAFT, obs_dim=synthetic.discrete_obs_dim(8, 4))


def _mcap_messages(bag_dir: Path) -> list[tuple[str, str, int, bytes]]:
    """``(topic, schema, log_time, data)`` of every message, read with the ``mcap`` library."""
    out = []
    for file in sorted(bag_dir.glob("*.mcap")):
        with open(file, "rb") as fh:
            for schema, channel, message in mcap_reader.make_reader(fh).iter_messages(log_time_order=True):
                name = schema.name if schema else ""
                out.append((channel.topic, name, message.log_time, bytes(message.data)))
    return out


def _decoded(bag_dir: Path, topic: str) -> list[tuple[int, object]]:
    factory = mcap_ros2_decoder.DecoderFactory()
    out = []
    for file in sorted(bag_dir.glob("*.mcap")):
        with open(file, "rb") as fh:
            reader = mcap_reader.make_reader(fh, decoder_factories=[factory])
            for _, _, message, msg in reader.iter_decoded_messages(topics=[topic]):
                out.append((message.log_time, msg))
    return out


def _observation_stamps(bag_dir: Path, lengths: list[int]) -> list[np.ndarray]:
    """The observation log stamps of each episode (every episode keeps its T + 1 observations)."""
    with AnyReader([bag_dir]) as reader:
        conns = [c for c in reader.connections if c.topic == "/observation"]
        stamps = np.array([s for _, s, _ in reader.messages(connections=conns)], dtype=np.int64)
    assert len(stamps) == sum(n + 1 for n in lengths)
    return np.split(stamps, np.cumsum([n + 1 for n in lengths])[:-1])


def _segmenter(obs_dim: int, high: float) -> StreamingSegmenter:
    torch.manual_seed(3)
    cfg = OMPNConfig(obs_dim=obs_dim, action_type="discrete", action_dim=synthetic.DISCRETE_ACTION_DIM,
                     n_slots=3, slot_size=16)
    policy = StreamingPolicy(OMPNPolicy(cfg), backend="numpy")
    return StreamingSegmenter(policy, DetectorConfig(high=high))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory):
    """An mcap bag of 3 synthetic episodes, its episodes, stamps and replay outputs."""
    root = tmp_path_factory.mktemp("annotate")
    bag = root / "in"
    write_episodes(bag, synthetic.make_dataset("discrete", 3, seed=11), DOMAIN, storage="mcap")
    episodes = read_episodes(bag).episodes
    stamps = _observation_stamps(bag, [e.length for e in episodes])
    probe = replay_episode(_segmenter(episodes[0].observations.shape[1], 0.5), episodes[0])
    high = float(np.quantile(probe.scores[1:], 0.6))  # a threshold this random model crosses
    seg = _segmenter(episodes[0].observations.shape[1], high)
    results = []
    for ep, st in zip(episodes, stamps):
        results.append(replay_episode(seg, ep, include_done_step=True, stamps_ns=st))
    assert sum(len(r.boundaries) for r in results) > len(results)  # more than the final boundaries
    return root, bag, episodes, stamps, results


@pytest.fixture(scope="module")
def annotated(recorded):
    root, bag, _, stamps, results = recorded
    out = root / "annotated"
    report = annotate_bag(bag, out, list(zip(stamps, results)), namespace=NS)
    return out, report


def test_every_original_message_is_copied_unchanged(recorded, annotated) -> None:
    _, bag, *_ = recorded
    out, report = annotated
    original = _mcap_messages(bag)
    copied = [msg for msg in _mcap_messages(out) if msg[0] not in ADDED]
    assert sorted(copied) == sorted(original)
    assert report.copied == len(original)


def test_pi_is_published_once_per_step_at_the_observation_stamps(recorded, annotated) -> None:
    _, _, episodes, stamps, results = recorded
    out, report = annotated
    pis = _decoded(out, PI)
    assert [t for t, _ in pis] == np.concatenate([s[: e.length] for e, s in zip(episodes, stamps)]).tolist()
    values = np.array([np.asarray(msg.data) for _, msg in pis])
    want = np.concatenate([np.column_stack([r.pi, r.expected_position, r.pi_end]) for r in results])
    np.testing.assert_allclose(values, want, rtol=0, atol=1e-6)
    dims = {(d.label, d.size, d.stride) for _, msg in pis for d in msg.layout.dim}
    assert dims == {(layout.PI_LABEL, 5, 5)}  # one dimension over all n + 2 values
    assert report.added[PI] == report.steps == sum(e.length for e in episodes)
    states = _decoded(out, STATE)
    assert [t for t, _ in states] == [t for t, _ in pis]
    named = np.array([[*msg.pi, msg.expected_position, msg.pi_end] for _, msg in states])
    np.testing.assert_array_equal(named, values)
    assert [(msg.episode, msg.step) for _, msg in states] == [
        (i + 1, t) for i, e in enumerate(episodes) for t in range(e.length)]
    assert all(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == t for t, msg in states)


def test_segment_labels_follow_the_boundaries(recorded, annotated) -> None:
    _, _, episodes, _, results = recorded
    out, _ = annotated
    segments = _decoded(out, SEGMENT)
    assert [t for t, _ in segments] == [t for t, _ in _decoded(out, PI)]
    labels = np.array([msg.data for _, msg in segments])
    offset = 0
    for ep, result in zip(episodes, results):
        got = labels[offset: offset + ep.length]
        offset += ep.length
        assert got[0] == 0 and np.all(np.diff(got) >= 0)
        # a new segment starts right after each boundary step, nowhere else
        starts = np.flatnonzero(np.diff(got)) + 1
        assert (starts - 1).tolist() == [b.step for b in result.boundaries if b.step < ep.length - 1]


def test_boundary_events_match_the_replay(recorded, annotated) -> None:
    _, _, _, stamps, results = recorded
    out, report = annotated
    events = _decoded(out, BOUNDARY)
    want = [(i + 1, st, b)
            for i, (st, r) in enumerate(zip(stamps, results)) for b in r.published]
    assert len(events) == len(want) == report.added[BOUNDARY]
    assert sum(b.final for *_, b in want) == len(results)  # one final boundary per episode
    for (log_time, msg), (episode, st, b) in zip(events, want):
        assert log_time == st[b.detected_at]
        assert (msg.node, msg.episode, msg.step, msg.subtask, msg.subtask_id, msg.memory_level) == (
            NS, episode, b.step, b.subtask, -1, b.level)
        assert (msg.decided_step, msg.final, msg.header.frame_id) == (b.detected_at, b.final, "")
        assert msg.score == pytest.approx(b.score, rel=1e-6)
        header = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        assert header == st[b.step] == b.stamp_ns
        assert msg.decided_stamp.sec * 1_000_000_000 + msg.decided_stamp.nanosec == log_time


def test_output_opens_with_rosbags_anyreader(recorded, annotated) -> None:
    _, bag, *_ = recorded
    out, report = annotated
    info = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    note = json.loads(info["custom_data"][CUSTOM_DATA_KEY])
    assert note == {"source": "in", "namespace": NS, "segment_labels": "boundary"}
    with AnyReader([out]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        conn = next(c for c in reader.connections if c.topic == PI)
        _, _, raw = next(iter(reader.messages(connections=[conn])))
        first = reader.deserialize(raw, conn.msgtype)
    with AnyReader([bag]) as reader:
        for c in reader.connections:
            assert counts[c.topic] == c.msgcount and types[c.topic] == c.msgtype
    assert types[PI] == layout.FLOAT32_ARRAY and types[SEGMENT] == layout.INT32
    assert types[BOUNDARY] == "ompn_interfaces/msg/SubtaskBoundary"
    assert types[STATE] == "ompn_interfaces/msg/SubtaskState"
    assert counts[PI] == report.steps and len(first.data) == 5


def test_sqlite3_input(tmp_path: Path) -> None:
    bag = tmp_path / "in_db"
    write_episodes(bag, synthetic.make_dataset("discrete", 2, seed=4), DOMAIN, storage="sqlite3")
    episodes = read_episodes(bag).episodes
    stamps = _observation_stamps(bag, [e.length for e in episodes])
    matched = match_observation_stamps(bag, episodes)  # what ompn_segment has: episodes, no stamps
    assert [x.tolist() for x in matched] == [x.tolist() for x in stamps]
    seg = _segmenter(episodes[0].observations.shape[1], 0.3)
    outputs = [(st, replay_episode(seg, ep)) for ep, st in zip(episodes, matched)]
    report = annotate_bag(bag, tmp_path / "out", outputs)
    got = _mcap_messages(tmp_path / "out")
    with AnyReader([bag]) as reader:
        original = sorted((c.topic, s, bytes(d)) for c, s, d in reader.messages())
    assert sorted((t, s, d) for t, _, s, d in got if t not in ADDED) == original
    assert sum(t == PI for t, *_ in got) == report.steps == sum(e.length for e in episodes)
    # the storage file alone is a bag too, and sqlite3 is an output storage as well
    db3 = annotate_bag(next(bag.glob("*.db3")), tmp_path / "out_db", outputs, storage="sqlite3")
    with AnyReader([tmp_path / "out_db"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert db3.copied == report.copied and counts[PI] == report.steps
    assert counts[BOUNDARY] == sum(len(r.published) for _, r in outputs)


def test_refuses_bad_input_and_existing_output(recorded, annotated, tmp_path: Path) -> None:
    _, bag, _, stamps, results = recorded
    outputs = list(zip(stamps, results))
    not_a_bag = tmp_path / "notes.txt"
    not_a_bag.write_text("hello")
    with pytest.raises(AnnotateError, match=r"notes\.txt.*not a rosbag2"):
        annotate_bag(not_a_bag, tmp_path / "o1", outputs)
    with pytest.raises(AnnotateError, match="no such bag"):
        annotate_bag(tmp_path / "missing", tmp_path / "o1", outputs)
    existing = tmp_path / "exists"
    existing.mkdir()
    with pytest.raises(AnnotateError, match=r"exists.*overwrite"):
        annotate_bag(bag, existing, outputs)
    report = annotate_bag(bag, existing, outputs, overwrite=True)
    assert report.copied > 0 and (existing / "metadata.yaml").is_file()
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging left
    with pytest.raises(AnnotateError, match=r"must not be the input bag, lie inside it or contain it"):
        annotate_bag(bag, bag.parent, outputs, overwrite=True)
    assert (bag / "metadata.yaml").is_file()


def test_refuses_mismatched_replay_outputs(recorded, tmp_path: Path) -> None:
    _, bag, episodes, stamps, results = recorded
    short = [(stamps[0], results[0]), (stamps[1][:-3], results[1])]
    with pytest.raises(AnnotateError, match=r"episode #1: \d+ observation stamps for \d+ replayed steps"):
        annotate_bag(bag, tmp_path / "o", short)
    backwards = [(stamps[0][::-1].copy(), results[0])]
    with pytest.raises(AnnotateError, match="episode #0: observation stamps are not strictly increasing"):
        annotate_bag(bag, tmp_path / "o", backwards)
    bare = dataclasses.replace(episodes[0], extras={})  # stamps neither given nor read with it
    with pytest.raises(AnnotateError, match=r"episode #0 .*extras\['obs_stamp_ns'\]"):
        annotate_bag(bag, tmp_path / "o", [(bare, results[0])])
    assert not (tmp_path / "o").exists()


def test_refuses_a_bag_that_already_has_the_topics(annotated, recorded, tmp_path: Path) -> None:
    out, _ = annotated
    _, _, _, stamps, results = recorded
    with pytest.raises(AnnotateError, match=r"topic '/ompn_node/(pi|segment|boundary)'.*another namespace"):
        annotate_bag(out, tmp_path / "twice", list(zip(stamps, results)))
    report = annotate_bag(out, tmp_path / "twice", list(zip(stamps, results)), namespace="/ompn_b")
    assert report.added["/ompn_b/pi"] == report.steps


def test_match_observation_stamps(recorded) -> None:
    _, bag, episodes, stamps, _ = recorded
    matched = match_observation_stamps(bag, episodes, topic="/observation")
    assert [x.tolist() for x in matched] == [x.tolist() for x in stamps]
    # a final row that is not the bag's next observation (e.g. a reader that duplicated another
    # observation as row T): T stamps for that episode, the next episode still lines up
    ep = episodes[1]
    assert not np.array_equal(ep.observations[0], ep.observations[-1])
    dup = dataclasses.replace(ep, observations=np.concatenate([ep.observations[:-1], ep.observations[:1]]))
    matched = match_observation_stamps(bag, [episodes[0], dup, episodes[2]])
    assert matched[1].tolist() == stamps[1][:-1].tolist() and matched[2].tolist() == stamps[2].tolist()
    # a subset of the episodes (the others dropped by the reader) still lines up
    assert match_observation_stamps(bag, [episodes[2]])[0].tolist() == stamps[2].tolist()


def test_match_observation_stamps_refuses(recorded) -> None:
    _, bag, episodes, *_ = recorded
    wrong = dataclasses.replace(episodes[0], observations=episodes[0].observations + 0.5)
    with pytest.raises(AnnotateError, match=r"episode #1: observation of step 0 not found"):
        match_observation_stamps(bag, [episodes[0], wrong])
    with pytest.raises(AnnotateError, match=r"topic '/subtask'.*not Float32MultiArray"):
        match_observation_stamps(bag, episodes, topic="subtask")
    with pytest.raises(AnnotateError, match=r"topic '/robot/obs'.*not in the bag"):
        match_observation_stamps(bag, episodes, topic="obs", namespace="/robot")
    # episodes out of bag order cannot be matched forward
    with pytest.raises(AnnotateError, match=r"episode #1: observation of step \d+ not found"):
        match_observation_stamps(bag, [episodes[2], episodes[0]])


def test_observation_stamps_prefers_the_readers_stamps(recorded, tmp_path: Path) -> None:
    _, bag, episodes, stamps, results = recorded
    assert [x.tolist() for x in observation_stamps(bag, episodes)] == [x.tolist() for x in stamps]
    kept = [dataclasses.replace(ep, extras={**ep.extras, STAMPS_KEY: st + 7})
            for ep, st in zip(episodes, stamps)]
    got = observation_stamps(tmp_path / "no_bag_needed", kept)
    assert [x.tolist() for x in got] == [(st + 7).tolist() for st in stamps]
    # Episodes carrying their stamps go straight into annotate_bag
    report = annotate_bag(bag, tmp_path / "out", [(ep, r) for ep, r in zip(kept[:1], results)])
    pis = _decoded(tmp_path / "out", PI)
    assert [t for t, _ in pis] == (stamps[0][: episodes[0].length] + 7).tolist() and report.episodes == 1


def test_foreign_bag_keeps_custom_data_qos_and_message_definitions(tmp_path: Path) -> None:
    bag = tmp_path / "foreign"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data("robot", "jaco")
        conn = writer.add_connection("/jaco/note", layout.STRING, typestore=m.typestore())
        for i in range(3):
            writer.write(conn, 1_000 + i, m.serialize(m.msg_class(layout.STRING)(data=f"n{i}")))
    report = annotate_bag(bag, tmp_path / "out", [])
    info = yaml.safe_load((tmp_path / "out" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["custom_data"]["robot"] == "jaco" and report.copied == 3 and report.steps == 0
    assert [msg for msg in _mcap_messages(tmp_path / "out") if msg[0] == "/jaco/note"] == _mcap_messages(bag)
    with AnyReader([bag]) as a, AnyReader([tmp_path / "out"]) as b:
        before = next(c for c in a.connections if c.topic == "/jaco/note")
        after = next(c for c in b.connections if c.topic == "/jaco/note")
        assert (after.msgtype, after.msgdef, after.digest) == (before.msgtype, before.msgdef, before.digest)
        assert after.ext == before.ext
