"""ompn_node survives every single message: poisoned markers, sketches and stamps (issue cases and a
property-based fuzzer).  Callbacks are called in-process and the outputs recorded as the CDR bytes the
node publishes, so each test is deterministic; after any poison, the next valid episode must be
segmented exactly as an offline replay of that episode would be."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
hypothesis = pytest.importorskip("hypothesis")

from episode_markers import marker  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from node_in_process import Recorder, active_node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Int32MultiArray  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

OBS_DIM, VOCAB = 6, 5
NOW_S = int(time.time())
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(5)
    cfg = OMPNConfig(obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=3, slot_size=16,
                     sketch_mode="sum", sketch_vocab=VOCAB)
    path = tmp_path_factory.mktemp("poison") / "ckpt"
    save_checkpoint(path, OMPNPolicy(cfg))
    return path


def joint_state(sec: int, nanosec: int, obs: np.ndarray) -> JointState:
    msg = JointState(name=[f"j{i}" for i in range(OBS_DIM)], position=[float(v) for v in obs])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def boundaries(node: OMPNNode, start: int = 0) -> list[dict[str, str]]:
    out = []
    for raw in node.outputs.pubs["boundary"].raws[start:]:  # ompn_interfaces/SubtaskBoundary, decoded
        b = decode_subtask_boundary(raw)
        out.append({"step": str(b.step), "subtask": str(b.subtask), "score": f"{b.score:.6f}",
                    "level": str(b.memory_level), "detected_at": str(b.decided_step),
                    "stamp_ns": str(b.stamp_ns), "final": "true" if b.final else "false",
                    "header_ns": str(b.stamp_ns), "episode": str(b.episode)})
    return out


def run_episode(node: OMPNNode, sketch: list[int], obs: np.ndarray, stamps_ns: list[int],
                joint: bool = False) -> tuple[list[dict[str, str]], np.ndarray]:
    """Start marker, T + 1 observations (the last is the done step), end marker; the episode's outputs."""
    b0, p0 = len(node.outputs.pubs["boundary"].raws), len(node.outputs.pubs["pi"].raws)
    node.inputs.markers.on_episode(marker("start", sketch=",".join(map(str, sketch))))
    for x, s in zip(obs, stamps_ns, strict=True):
        if joint:
            node.inputs.joint_states.on_joint_state(joint_state(*divmod(s, 1_000_000_000), x))
        else:
            node.inputs.on_raw_array(m.encode_float32_array(x), s)
    node.inputs.markers.on_episode(marker("end", steps=str(len(obs) - 1)))
    pis = np.array([m.parse_float32_array(r) for r in node.outputs.pubs["pi"].raws[p0:]])
    return boundaries(node, b0), pis


def replay(ckpt: Path, sketch: list[int], obs: np.ndarray, stamps_ns: list[int]) -> tuple[list, np.ndarray]:
    """The offline replay of one episode: boundary (step, score, stamp) and the ~/pi rows."""
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig(high=0.3, low=0.3))
    seg.reset(np.asarray(sketch))
    events, pis = [], []
    for x, s in zip(obs, stamps_ns, strict=True):
        out = seg.step(x, s)
        so = out.step_output
        pis.append(np.concatenate([so.pi, [so.expected_position, so.pi_end]]).astype(np.float32))
        if out.boundary is not None:
            events.append(out.boundary)
    events = events + seg.end_episode(len(obs) - 2)  # the node ends it with one final event
    return [(e.step, f"{float(np.float32(e.score)):.6f}", e.stamp_ns) for e in events], np.array(pis)


def assert_matches_replay(node: OMPNNode, ckpt: Path, seed: int, joint: bool = False) -> None:
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(9, OBS_DIM)).astype(np.float32)
    stamps = [(NOW_S - 10_000 + 100 * seed) * 1_000_000_000 + 40_000_000 * t for t in range(len(obs))]
    sketch = [1, 3, 2]
    accepted = node.segmenter.accepted
    got, pis = run_episode(node, sketch, obs, stamps, joint)
    want, want_pis = replay(ckpt, sketch, obs, stamps)
    assert node.segmenter.accepted - accepted == len(obs)
    assert [(int(b["step"]), b["score"], int(b["stamp_ns"])) for b in got] == want
    assert all(int(b["header_ns"]) == int(b["stamp_ns"]) for b in got)  # outputs in the input's time base
    np.testing.assert_allclose(pis, want_pis, atol=1e-6)


def test_huge_sketch_value_rejects_the_start_and_the_next_valid_episode_is_exact(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    node.inputs.markers.on_episode(marker("start", sketch="99999999999999999999"))
    node.inputs.on_raw_array(m.encode_float32_array(np.zeros(OBS_DIM)), 1)
    node.inputs.markers.on_episode(marker("end", steps="1"))
    counters = node.counters()
    assert counters["rejected_bad_sketch"] == 1 and counters["rejected_no_sketch"] == 1
    assert counters["accepted"] == 0 and counters["episodes"] == 0
    assert_matches_replay(node, ckpt, seed=1)
    node.destroy_node()


def test_sketch_outside_the_vocabulary_is_not_run_on_the_previous_sketch(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    assert_matches_replay(node, ckpt, seed=2)
    node.inputs.markers.on_episode(marker("start", sketch="7,9"))
    for t in range(3):  # different observations (the same bytes 1 ns later would be one message sent twice)
        node.inputs.on_raw_array(m.encode_float32_array(np.full(OBS_DIM, t + 1.0)), t + 1)
    node.inputs.markers.on_episode(marker("end", steps="2"))
    counters = node.counters()
    assert counters["rejected_bad_sketch"] == 1 and counters["rejected_no_sketch"] == 3
    assert counters["rejected_episode_closed"] == 0 and counters["episodes"] == 1
    # a sketch message with bad ids is refused too; then the next valid episode is exact
    node.inputs.markers.on_sketch(Int32MultiArray(data=[0, 5]))
    assert node.counters()["rejected_bad_sketch"] == 2
    assert_matches_replay(node, ckpt, seed=3)
    assert node.counters()["episodes"] == 2
    node.destroy_node()


def test_overflowing_joint_state_stamp_is_rejected_and_an_end_marker_is_harmless(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, obs_source="joint_state")
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    node.inputs.joint_states.on_joint_state(joint_state(2147483647, 4294967295, np.zeros(OBS_DIM)))
    node.inputs.markers.on_episode(marker("end", steps="1"))
    assert node.counters()["rejected_bad_stamp"] == 1
    assert_matches_replay(node, ckpt, seed=4, joint=True)
    node.destroy_node()


def test_a_joint_value_beyond_float32_is_rejected_without_a_warning(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, obs_source="joint_state")
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning from the float64 -> float32 cast
        x = np.array([1e39] + [0.0] * (OBS_DIM - 1))
        node.inputs.joint_states.on_joint_state(joint_state(NOW_S, 0, x))
    node.inputs.markers.on_episode(marker("end", steps="0"))
    assert node.counters()["rejected_non_finite"] == 1 and node.counters()["accepted"] == 0
    assert_matches_replay(node, ckpt, seed=11, joint=True)
    node.destroy_node()


def test_a_boundary_at_the_last_representable_stamp_is_published(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, obs_source="joint_state", max_stamp_lead=0.0)
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    node.inputs.joint_states.on_joint_state(joint_state(2147483647, 999_999_999, np.zeros(OBS_DIM)))
    node.inputs.markers.on_episode(marker("end", steps="1"))
    (event,) = boundaries(node)
    assert int(event["stamp_ns"]) == m.STAMP_NS_MAX == int(event["header_ns"]) and event["final"] == "true"
    node.destroy_node()


@pytest.mark.parametrize("lead_check", [True, False])
def test_a_far_future_stamp_never_wedges_the_node(ctx, ckpt: Path, lead_check: bool) -> None:
    node = active_node(ctx, ckpt, obs_source="joint_state", max_stamp_lead=60.0 if lead_check else 0.0)
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    node.inputs.joint_states.on_joint_state(joint_state(2_000_000_000, 0, np.zeros(OBS_DIM)))  # 2033
    rng = np.random.default_rng(6)
    for t in range(20):
        node.inputs.joint_states.on_joint_state(joint_state(NOW_S, t * 1000, rng.normal(size=OBS_DIM)))
    counters = node.counters()
    assert counters["accepted"] == (20 if lead_check else 21) and counters["rejected_out_of_order_stamp"] == 0
    assert counters["rejected_future_stamp"] == (1 if lead_check else 0)
    # lead check off: the 2033 stamp is taken, then the robot's clock "steps back" while the node's runs
    assert counters["clock_jumps"] == 0 and counters["clock_steps"] == (0 if lead_check else 1)
    assert_matches_replay(node, ckpt, seed=7, joint=True)
    node.destroy_node()


def test_a_clock_restart_starts_a_new_episode_segmented_like_a_fresh_replay(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    node.inputs.markers.on_episode(marker("start", sketch="1,3,2"))
    rng = np.random.default_rng(8)
    for t in range(12):
        x = m.encode_float32_array(rng.normal(size=OBS_DIM))
        node.inputs.on_raw_array(x, 500_000_000_000 + t * 40_000_000)
    obs = rng.normal(size=(9, OBS_DIM)).astype(np.float32)
    stamps = [t * 40_000_000 for t in range(9)]  # the sim restarted: its clock starts at 0 again
    b0, p0 = len(node.outputs.pubs["boundary"].raws), len(node.outputs.pubs["pi"].raws)
    for x, s in zip(obs, stamps, strict=True):
        node.inputs.on_raw_array(m.encode_float32_array(x), s)
    node.inputs.markers.on_episode(marker("end", steps="8"))
    assert node.counters()["clock_jumps"] == 1 and node.counters()["rejected"] == 0
    assert node.counters()["episodes"] == 2
    got = [b for b in boundaries(node, b0) if int(b["detected_at"]) < 12 or int(b["stamp_ns"]) < 10**11]
    fresh = [b for b in got if int(b["stamp_ns"]) < 10**11]
    want, want_pis = replay(ckpt, [1, 3, 2], obs, stamps)
    assert [(int(b["step"]), b["score"], int(b["stamp_ns"])) for b in fresh] == want
    pis = np.array([m.parse_float32_array(r) for r in node.outputs.pubs["pi"].raws[p0:]])
    np.testing.assert_allclose(pis, want_pis, atol=1e-6)
    node.destroy_node()


def test_reset_service_clears_the_last_stamp(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, clock_jump_back=1e6)
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    node.inputs.on_raw_array(m.encode_float32_array(np.zeros(OBS_DIM)), 10_000_000_000)
    node.inputs.on_raw_array(m.encode_float32_array(np.zeros(OBS_DIM)), 9_000_000_000)
    assert node.counters()["rejected_out_of_order_stamp"] == 1
    from std_srvs.srv import Trigger

    response = node._on_reset(Trigger.Request(), Trigger.Response())
    assert response.success and node.stream.last_stamp is None and node.segmenter.step_index == -1
    node.inputs.on_raw_array(m.encode_float32_array(np.zeros(OBS_DIM)), 9_000_000_000)
    assert node.counters()["accepted"] == 2 and node.counters()["episodes"] == 2
    node.destroy_node()


def test_zero_byte_observation_and_short_end_marker(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    node.inputs.markers.on_episode(marker("start", sketch="1,2"))
    node.inputs.on_array(b"")
    assert node.counters()["rejected_malformed"] == 1
    for t in range(10):
        node.inputs.on_array(m.encode_float32_array(np.full(OBS_DIM, t / 10)))
    node.inputs.markers.on_episode(marker("end", steps="1"))  # says 1 step after 10
    final = boundaries(node)[-1]
    assert final["final"] == "true" and final["score"] != "nan" and int(final["stamp_ns"]) > 0
    assert node.counters()["bad_end_markers"] == 1 and node.counters()["accepted"] == 10
    node.destroy_node()


def test_live_detector_change_applies_from_the_next_step(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, detector_high=0.45)
    rng = np.random.default_rng(9)
    obs = rng.normal(size=(30, OBS_DIM)).astype(np.float32) * 3
    node.inputs.markers.on_episode(marker("start", sketch="1,3,2"))
    ref = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig(high=0.45, low=0.45))
    ref.reset(np.array([1, 3, 2]))
    want = []
    for t, x in enumerate(obs):
        if t == 15:
            change = [Parameter("detector_high", value=0.55), Parameter("detector_mode", value="rising_edge")]
            assert node.set_parameters_atomically(change).successful
            ref.detector.config = DetectorConfig(high=0.55, low=0.55, mode="rising_edge")
        node.inputs.on_raw_array(m.encode_float32_array(x), t + 1)
        out = ref.step(x, t + 1)
        want += [] if out.boundary is None else [(out.boundary.step, out.boundary.detected_at)]
    got = [(int(b["step"]), int(b["detected_at"])) for b in boundaries(node)]
    assert got == want and any(d < 15 for _, d in got) and any(s == d >= 15 for s, d in got)
    assert node.segmenter.detector_config.high == 0.55
    refused = node.set_parameters([Parameter("checkpoint", value="/elsewhere")])[0]
    assert not refused.successful and "clean up" in refused.reason and "'checkpoint'" in refused.reason
    node.destroy_node()


def test_diagnostics_name_the_node_fully_and_count_episodes(ctx, ckpt: Path) -> None:
    node = OMPNNode(context=ctx, namespace="/robot_2",
                    parameter_overrides=[Parameter("checkpoint", value=str(ckpt))])
    node.trigger_configure()
    node.trigger_activate()
    node.outputs.pubs = {k: Recorder() for k in node.outputs.pubs}
    for _ in range(3):  # start marker + sketch message + 2 steps + end marker, three times
        node.inputs.markers.on_episode(marker("start", sketch="1,2"))
        node.inputs.markers.on_sketch(Int32MultiArray(data=[1, 2]))
        for t in range(2):
            node.inputs.on_array(m.encode_float32_array(np.zeros(OBS_DIM) + t))
        node.inputs.markers.on_episode(marker("end", steps="1"))
    node.publish_diagnostics()
    status = m.deserialize(node.outputs.pubs["diagnostics"].raws[-1], layout.DIAGNOSTIC_ARRAY).status[0]
    assert status.name == "/robot_2/ompn_node: segmenter"
    values = {kv.key: kv.value for kv in status.values}
    assert values["episodes"] == "3" and values["episodes_ended"] == "3" and values["accepted"] == "6"
    assert values["episode_starts"] == "3" and values["messages_lost"] == "0"
    node.destroy_node()


# --- property-based: any marker, stamp, joint state, sketch or bytes: no crash, no wedge ---------
TEXT = st.text(max_size=30) | st.sampled_from(["99999999999999999999", "-1", "1,2", "7,9", "", "nan", "1e9"])
MARKERS = st.builds(
    lambda name, kind, values: (name, kind, values),
    st.sampled_from([layout.EPISODE_STATUS_NAME, "other", ""]) | st.text(max_size=8),
    st.sampled_from([layout.EPISODE_START, layout.EPISODE_END]) | st.text(max_size=6),
    st.dictionaries(st.sampled_from(["sketch", "steps", "episode", "task", "seed", "x"]), TEXT, max_size=5),
)
STAMPS = st.tuples(st.integers(-(2**31), 2**31 - 1), st.integers(0, 2**32 - 1))
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
JOINTS = st.tuples(STAMPS, st.lists(st.text(max_size=4), max_size=8), st.lists(FLOATS, max_size=8),
                   st.lists(FLOATS, max_size=8))
RAW = st.binary(max_size=64) | st.builds(lambda n, head: m.encode_float32_array(np.ones(n))[:head],
                                         st.integers(0, 8), st.integers(0, 64))
EVENTS = st.lists(
    st.one_of(st.tuples(st.just("marker"), MARKERS), st.tuples(st.just("stamp"), STAMPS),
              st.tuples(st.just("reset"), st.none()), st.tuples(st.just("joint"), JOINTS),
              st.tuples(st.just("sketch"), st.lists(st.integers(-(2**31), 2**31 - 1), max_size=6)),
              st.tuples(st.just("raw"), RAW)),
    max_size=12,
)  # fmt: skip


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(events=EVENTS)
def test_property_any_marker_or_stamp_sequence_leaves_a_working_node(ctx, ckpt: Path, events: list) -> None:
    node = active_node(ctx, ckpt, obs_source="joint_state")
    from std_srvs.srv import Trigger

    for kind, payload in events:
        if kind == "marker":
            name, message, values = payload
            msg = marker(message, **values)
            msg.status[0].name = name
            node.inputs.markers.on_episode(msg)
        elif kind == "stamp":
            node.inputs.joint_states.on_joint_state(joint_state(*payload, np.ones(OBS_DIM)))
        elif kind == "joint":
            (sec, nanosec), names, position, velocity = payload
            msg = JointState(name=names, position=position, velocity=velocity)
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            node.inputs.joint_states.on_joint_state(msg)
        elif kind == "sketch":
            node.inputs.markers.on_sketch(Int32MultiArray(data=payload))
        elif kind == "raw":
            node.inputs.on_raw_array(payload, 1)
        else:
            node._on_reset(Trigger.Request(), Trigger.Response())
    counters = node.counters()
    observations = sum(k in ("stamp", "joint", "raw") for k, _ in events)  # each one counted once
    counted = counters["accepted"] + counters["rejected"] - counters["rejected_bad_sketch"]
    assert counted + counters["repeated_messages"] == observations  # a message sent twice: one step
    assert_matches_replay(node, ckpt, seed=10, joint=True)
    node.destroy_node()
