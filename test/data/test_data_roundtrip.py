"""Episode -> bag -> Episode round trips (both storage plugins), and an independent mcap decoder."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes, write_episodes
from ompn_ros.data.recorder.bag_writer import END_MARKER_OFFSET_NS

STORAGES = ("mcap", "sqlite3")


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_round_trip_is_exact(tmp_path: Path, storage: str, domain: str) -> None:
    episodes = make_episodes(domain, 6, seed=1)
    stats = write_episodes(tmp_path / "bag", episodes, domain, storage=storage)
    assert stats.episodes == 6
    result = read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain(domain))
    assert len(result.episodes) == 6
    for a, b in zip(episodes, result.episodes):
        assert_same_episode(a, b, joints=domain == "dial")
    report = result.report.bags[0]
    assert report.split == "markers"
    assert not report.missing and not report.duplicates and not report.unattached
    assert report.final_duplicated == 0
    assert result.report.steps == sum(e.length for e in episodes)


@pytest.mark.parametrize("storage", STORAGES)
def test_default_spec_and_input_forms(tmp_path: Path, storage: str) -> None:
    """File, bag dir, dir of bags, glob and sequences all resolve; the default spec infers types."""
    episodes = make_episodes("craft", 4, seed=2)
    write_episodes(tmp_path / "runs" / "a", episodes[:2], "craft", storage=storage)
    write_episodes(tmp_path / "runs" / "b", episodes[2:], "craft", storage=storage)
    suffix = ".mcap" if storage == "mcap" else ".db3"
    storage_file = next((tmp_path / "runs" / "a").glob(f"*{suffix}"))
    assert len(read_episodes(storage_file).episodes) == 2
    assert len(read_episodes(tmp_path / "runs" / "b").episodes) == 2
    every = read_episodes(tmp_path / "runs")
    assert len(every.episodes) == 4 and len(every.report.bags) == 2
    for a, b in zip(episodes, every.episodes):
        assert_same_episode(a, b)
    assert len(read_episodes(str(tmp_path / "runs" / "*")).episodes) == 4
    assert len(read_episodes([tmp_path / "runs" / "b", tmp_path / "runs" / "a"]).episodes) == 4


def test_step_contract_order_and_stamps(tmp_path: Path) -> None:
    """Messages come in the layout's publish order with the synthetic stamps."""
    from rosbags.rosbag2 import Reader

    episodes = make_episodes("dial", 2, seed=3, min_steps=3, max_steps=3)
    write_episodes(tmp_path / "bag", episodes, "dial")
    with Reader(tmp_path / "bag") as reader:
        seq = [(c.topic.lstrip("/"), stamp) for c, stamp, _ in reader.messages()]
    names = [t for t, _ in seq]
    step = ["observation", "joint_states", "subtask", "action"]
    one = ["episode_marker", "sketch"] + step * 3 + ["observation", "joint_states", "episode_marker"]
    assert names == one + one
    t0 = layout.EPISODE_GAP_NS
    assert seq[0][1] == t0 and seq[1][1] == t0 + layout.TOPIC_OFFSET_NS
    assert [s for _, s in seq[2:6]] == [t0 + layout.STEP_NS + k * layout.TOPIC_OFFSET_NS for k in range(4)]
    end = t0 + 4 * layout.STEP_NS + END_MARKER_OFFSET_NS
    assert seq[len(one) - 1][1] == end
    assert seq[len(one)][1] == end + layout.EPISODE_GAP_NS
    assert all(b[1] > a[1] for a, b in itertools.pairwise(seq))


def test_independent_mcap_decoder(tmp_path: Path) -> None:
    """The ``mcap`` library decodes our bags from their embedded ros2msg schemas (no rosbags)."""
    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    episodes = make_episodes("dial", 3, seed=4)
    write_episodes(tmp_path / "bag", episodes, "dial", storage="mcap")
    file = next((tmp_path / "bag").glob("*.mcap"))
    obs: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    markers: list[tuple[str, dict[str, str]]] = []
    schemas: dict[str, str] = {}
    with open(file, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        for schema, channel, _message, msg in reader.iter_decoded_messages():
            schemas[channel.topic] = schema.name
            if channel.topic == "/observation":
                assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [("obs", 39, 39)]
                obs.append(np.asarray(msg.data, dtype=np.float32))
            elif channel.topic == "/action":
                actions.append(np.asarray(msg.data, dtype=np.float32))
            elif channel.topic == "/episode_marker":  # EpisodeMarker, decoded from its embedded schema
                values = {layout.KEY_STEPS: str(msg.steps), layout.KEY_SKETCH: ",".join(map(str, msg.sketch))}
                markers.append((("start", "end")[msg.kind], values))
    assert schemas["/observation"] == "std_msgs/msg/Float32MultiArray"
    assert schemas["/joint_states"] == "sensor_msgs/msg/JointState"
    assert schemas["/episode_marker"] == "ompn_interfaces/msg/EpisodeMarker"
    np.testing.assert_array_equal(np.stack(obs), np.concatenate([e.observations for e in episodes]))
    np.testing.assert_array_equal(np.stack(actions), np.concatenate([e.actions for e in episodes]))
    assert [k for k, _ in markers] == ["start", "end"] * 3
    assert markers[1][1][layout.KEY_STEPS] == str(episodes[0].length)
    assert markers[0][1][layout.KEY_SKETCH] == ",".join(str(v) for v in episodes[0].sketch)


def test_reader_spec_yaml_presets_match_layout() -> None:
    root = Path(__file__).resolve().parents[2] / "config"
    for domain in ("craft", "dial"):
        assert ReaderSpec.from_yaml(root / f"reader_{domain}.yaml") == ReaderSpec.for_domain(domain)
    foreign = ReaderSpec.from_yaml(root / "reader_jointstate_example.yaml")
    assert foreign.observation.type == layout.JOINT_STATE and foreign.episode is None
    assert ReaderSpec.from_dict(ReaderSpec.for_domain("dial").to_dict()) == ReaderSpec.for_domain("dial")


def test_reader_spec_rejects_bad_keys() -> None:
    from ompn_ros.data import ReaderSpecError

    with pytest.raises(ReaderSpecError, match="unknown reader spec keys"):
        ReaderSpec.from_dict({"observaton": "x"})
    with pytest.raises(ReaderSpecError, match="fields"):
        ReaderSpec.from_dict({"observation": {"topic": "js", "type": layout.JOINT_STATE, "fields": ["pos"]}})


def _real(domain: str):  # type: ignore[no-untyped-def]
    module = pytest.importorskip(f"sim_nodes.{domain}")
    if not hasattr(module, "generate_episode"):
        pytest.skip(f"sim_nodes.{domain}.generate_episode not available")
    return module.generate_episode


@pytest.mark.parametrize("storage", STORAGES)
def test_round_trip_real_craft(tmp_path: Path, storage: str) -> None:
    gen = _real("craft")
    episodes = [gen(s, task=t, full_obs=True) for s, t in ((1, "makebed"), (2, "makeaxe"))]
    write_episodes(tmp_path / "bag", episodes, "craft", storage=storage)
    result = read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft"))
    assert len(result.episodes) == 2
    for a, b in zip(episodes, result.episodes):
        assert_same_episode(a, b)


@pytest.mark.parametrize("storage", STORAGES)
def test_round_trip_real_dial(tmp_path: Path, storage: str) -> None:
    gen = _real("dial")
    episodes = [gen(5)]
    write_episodes(tmp_path / "bag", episodes, "dial", storage=storage)
    result = read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("dial"))
    assert len(result.episodes) == 1
    assert_same_episode(episodes[0], result.episodes[0])
    ep = episodes[0]
    for key in ("joint_position", "joint_velocity", "joint_effort"):
        np.testing.assert_array_equal(result.episodes[0].extras[key], np.asarray(ep.extras[key], np.float64))


def test_recording_cut_at_both_ends(tmp_path: Path) -> None:
    """A recording that starts and stops mid-episode: only the complete episodes come back."""
    from rosbags.rosbag2 import Reader, Writer

    from ompn_ros.data import messages as m

    episodes = make_episodes("craft", 4, seed=12, min_steps=6, max_steps=6)
    write_episodes(tmp_path / "full", episodes, "craft")
    ep_len = 7 * layout.STEP_NS + END_MARKER_OFFSET_NS + layout.EPISODE_GAP_NS
    t0 = layout.EPISODE_GAP_NS
    cut_start = t0 + 3 * layout.STEP_NS  # inside episode 0, after its step 1
    cut_stop = t0 + 3 * ep_len + 4 * layout.STEP_NS  # inside episode 3
    with Reader(tmp_path / "full") as reader, Writer(tmp_path / "cut", version=9) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=m.typestore())
                 for c in reader.connections}
        for conn, stamp, raw in reader.messages():
            if cut_start <= stamp < cut_stop:
                writer.write(conns[conn.id], stamp, raw)
    result = read_episodes(tmp_path / "cut", spec=ReaderSpec.for_domain("craft"))
    assert len(result.episodes) == 2
    for a, b in zip(episodes[1:3], result.episodes):
        assert_same_episode(a, b)
    report = result.report.bags[0]
    assert report.dropped_episodes == 1  # episode 3: no end marker
    assert report.unattached == {"/observation": 5 + 3}  # obs 2..6 of episode 0, obs 0..2 of episode 3
    assert any("without a start marker" in n for n in report.notes)
