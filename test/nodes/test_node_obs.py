"""ompn_node with ``observation_spec``, in process: configure checks, assembled steps, drops, wrong types.

The step and partner callbacks are driven directly with serialized messages (the DDS path is covered
by test_node_obs_two_process.py), so counts are exact and the test is fast.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from node_process import node_command  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ompn_ros.data.messages import parse_float32_array  # noqa: E402
from ompn_ros.data.obs import ObservationSpec, assemble_stream  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.ros.params import ParameterError  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

torch.set_num_threads(1)
OBS_DIM = 3 + 2 + 6  # joint positions j1..j3, gripper (2), wrench (6)
SPEC_TEXT = (
    "{step_topic: joint_states, tolerance_s: 0.05, stamp: header, fields: ["
    "{topic: joint_states, type: sensor_msgs/msg/JointState, field: position, names: [j1, j2, j3]},"
    "{topic: gripper, type: std_msgs/msg/Float32MultiArray, field: data, size: 2},"
    "{topic: /arm9/wrench, type: geometry_msgs/msg/WrenchStamped, field: wrench}]}"
)
NS = f"/nodeobs_{os.getpid()}"
STEP, GRIP, WRENCH = f"{NS}/joint_states", f"{NS}/gripper", "/arm9/wrench"
SPEC_RECEIVE = SPEC_TEXT.replace("stamp: header", "stamp: receive")
MS = 1_000_000


class FakeClock:
    """The node's clock at reception, set by the test (the receive times are then exact)."""

    def __init__(self) -> None:
        self.nanoseconds = 0

    def now(self) -> FakeClock:
        return self


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "nodeobs", seed=4,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=3, slot_size=16)


def make_node(ctx, ckpt: Path, spec: str = SPEC_TEXT, **params) -> OMPNNode:
    overrides = [Parameter("checkpoint", value=str(ckpt)), Parameter("observation_spec", value=spec)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return OMPNNode(context=ctx, namespace=NS, parameter_overrides=overrides)


def active_node(ctx, ckpt: Path, spec: str = SPEC_RECEIVE, **params) -> OMPNNode:
    node = make_node(ctx, ckpt, spec=spec, max_stamp_lead=0.0, **params)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.last_error
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    clock = FakeClock()
    node.get_clock = lambda: clock  # type: ignore[method-assign]
    return node


def stamp_of(ms: int):
    from builtin_interfaces.msg import Time

    return Time(sec=ms // 1000, nanosec=(ms % 1000) * MS)


def joint_state(k: int, ms: int) -> bytes:
    msg = JointState()
    msg.header.stamp = stamp_of(ms)
    msg.name = ["j3", "j1", "j2"]
    msg.position = [-1.0 * k, 1.0 * k, 0.5 * k]
    return serialize_message(msg)


def gripper(k: int) -> bytes:
    return serialize_message(Float32MultiArray(data=[0.1 * k, 1.0 - 0.1 * k]))


def wrench(k: int, ms: int) -> bytes:
    msg = WrenchStamped()
    msg.header.stamp = stamp_of(ms)
    msg.wrench.force.x, msg.wrench.torque.z = 0.25 * k, -0.5 * k
    return serialize_message(msg)


def feed(node: OMPNNode, messages: list[tuple[str, bytes]], start_ms: int = 1000) -> None:
    """Deliver ``messages`` one millisecond apart (receive times ``start_ms``, ``start_ms + 1``, ...)."""
    partners = {t: node.inputs.spec.partner_callback(t) for t in (GRIP, WRENCH)}
    clock = node.get_clock()
    for i, (topic, raw) in enumerate(messages):
        clock.nanoseconds = (start_ms + i) * MS
        if topic == STEP:
            node.inputs.spec.on_step(raw)
        else:
            partners[topic](raw)


def test_bad_spec_is_one_line_at_start_up(ctx, ckpt: Path) -> None:
    bad = SPEC_TEXT.replace("field: position", "field: positon")
    with pytest.raises(ParameterError) as err:
        make_node(ctx, ckpt, spec=bad)
    text = str(err.value)
    assert "observation_spec" in text and "positon" in text and "\n" not in text
    with pytest.raises(ParameterError, match="'/arm9/wr ench' is not a valid ROS topic name"):
        make_node(ctx, ckpt, spec=SPEC_TEXT.replace("/arm9/wrench", "/arm9/wr ench"))


def test_bad_spec_from_the_command_line_exits_2(ros_env: dict[str, str], tmp_path: Path) -> None:
    spec = tmp_path / "spec.yaml"
    spec.write_text("observation:\n  step_topic: js\n  fields:\n    - {topic: js, type: Foo, field: data}\n")
    cmd = node_command(f"observation_spec:={spec}")
    proc = subprocess.run(cmd, env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    assert len(lines) == 1 and "observation_spec" in lines[0] and "Foo" in lines[0], lines
    assert "Traceback" not in proc.stderr
    inline = "observation_spec:={step_topic: js, fields: []}"  # rcl reads -p values as YAML: not a value
    proc = subprocess.run([*cmd[:-1], inline], env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    ours = [ln for ln in proc.stderr.splitlines() if ln.startswith("ompn_node:")]  # rcl logs its own too
    assert len(ours) == 1 and "observation_spec" in ours[0], proc.stderr


def test_declared_size_must_match_the_checkpoint(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, spec=SPEC_TEXT.replace("size: 2", "size: 3"))
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert "12 values" in node.last_error and f"obs_dim={OBS_DIM}" in node.last_error
    assert "\n" not in node.last_error and node.assembled is None
    node.destroy_node()


def test_undeclared_size_is_checked_on_the_first_kept_step(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, spec=SPEC_RECEIVE.replace(", size: 2", ""))
    feed(node, [(WRENCH, wrench(0, 1000)), (GRIP, serialize_message(Float32MultiArray(data=[1.0])))])
    feed(node, [(STEP, joint_state(k, 0)) for k in range(3)], start_ms=1010)
    counters = node.counters()
    assert counters["obs_size_mismatch"] == 1 and counters["obs.kept"] == 3
    assert counters["rejected_wrong_length"] == 3 and counters["accepted"] == 0
    node.destroy_node()


def test_assembled_steps_equal_the_offline_rule(ctx, ckpt: Path) -> None:
    """The node steps exactly what assemble_stream gives for the same messages and receive times;
    drops are counted by reason."""
    node = active_node(ctx, ckpt)
    pis: list[np.ndarray] = []
    node.outputs.pubs["pi"].publish = lambda raw: pis.append(np.asarray(parse_float32_array(raw)))
    messages: list[tuple[str, bytes]] = []
    for k in range(60):
        if k >= 3 and not 20 <= k < 50:  # no wrench at first (missing), then a 90 ms gap (stale)
            messages.append((WRENCH, wrench(k, 0)))
        messages.append((GRIP, gripper(k)))
        messages.append((STEP, joint_state(k, 0)))
    feed(node, messages)
    spec = ObservationSpec.from_param(SPEC_RECEIVE).with_namespace(NS)
    offline = assemble_stream(((t, (1000 + i) * MS, raw) for i, (t, raw) in enumerate(messages)), spec)
    counters = node.counters()
    assert counters["obs.steps"] == 60 and counters["obs.kept"] == len(offline.observations)
    assert counters["obs.dropped.missing"] == 3 and counters["obs.dropped.stale"] > 0
    assert counters["obs.dropped.stale"] == offline.stats.dropped["stale"]
    assert counters["accepted"] == len(pis) == counters["obs.kept"]
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig())
    expected = []
    for x in offline.observations:
        so = seg.step(x).step_output
        expected.append(np.concatenate([so.pi, [so.expected_position, so.pi_end]]).astype(np.float32))
    np.testing.assert_allclose(np.stack(pis), np.stack(expected), rtol=1e-5, atol=1e-6)
    node.destroy_node()


def test_wrong_type_is_one_line_and_a_counter(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    other = rclpy.context.Context()  # another participant: one participant cannot hold both types
    rclpy.init(context=other)
    peer = rclpy.create_node("wrong_type_peer", context=other)
    peer.create_publisher(PoseStamped, WRENCH, 10)
    lines: list[str] = []
    node.get_logger().error = lines.append  # type: ignore[method-assign]
    for _ in range(200):
        node.inputs.spec.check_topic_types()
        if lines:
            break
        time.sleep(0.02)
    assert len(lines) == 1 and "/arm9/wrench" in lines[0] and "PoseStamped" in lines[0], lines
    node.inputs.spec.check_topic_types()  # polled again: no new line, no new count
    feed(node, [(GRIP, gripper(0)), (WRENCH, wrench(0, 1000)), (STEP, joint_state(0, 1001))])
    counters = node.counters()
    assert len(lines) == 1 and counters["obs_type_reports"] == 1
    assert counters["obs.dropped.wrong_type"] == 1 and counters["accepted"] == 0
    assert counters[f"obs.rejected.{WRENCH}.wrong_type"] == 2  # the report and the message
    assert node.inputs.active
    peer.destroy_node()
    rclpy.try_shutdown(context=other)
    node.destroy_node()


def test_reset_forgets_partners_episode_markers_do_not(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt)
    feed(node, [(GRIP, gripper(0)), (WRENCH, wrench(0, 1000)), (STEP, joint_state(0, 1001))])
    node.stream.markers.start_marker("")  # an episode start marker keeps the partners
    feed(node, [(STEP, joint_state(1, 0))], start_ms=1010)
    assert node.counters()["obs.kept"] == 2
    assert node._on_reset(Trigger.Request(), Trigger.Response()).success
    feed(node, [(STEP, joint_state(2, 0))], start_ms=1020)
    counters = node.counters()
    assert counters["obs.kept"] == 2 and counters["obs.dropped.missing"] == 1
    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    node.inputs.spec.on_step(b"\x00\x01\x00\x00garbage")  # undecodable: counted, never fatal
    assert node.counters()["obs.dropped.malformed"] == 1
    node.destroy_node()


def test_a_step_waits_for_a_late_wrench_and_markers_step_the_held(ctx, ckpt: Path) -> None:
    """Header stamps: a step is stepped once the wrench topic offered a message stamped at or after it,
    with the wrench stamped before it even when delivered after it; the wait ends on the node's clock;
    an episode marker or ~/reset first steps what is held."""
    from episode_markers import marker

    node = active_node(ctx, ckpt, spec=SPEC_TEXT)
    seen: list[tuple[np.ndarray, int]] = []
    node.inputs.spec.step = lambda data, stamp, now=None: seen.append((data, stamp))  # type: ignore
    feed(node, [(GRIP, gripper(0)), (WRENCH, wrench(0, 1000)), (STEP, joint_state(1, 1002))])
    feed(node, [(WRENCH, wrench(1, 1001))], start_ms=1003)  # stamped before the step, delivered after
    assert seen == [] and node.assembled is not None and node.assembled.asm.held == 1
    feed(node, [(WRENCH, wrench(2, 1003))], start_ms=1004)  # stamped after the step: it is decided
    (obs, stamp), = seen
    assert stamp == 1002 * MS and obs[5] == 0.25 and obs[10] == -0.5  # wrench 1, not 0 or 2
    feed(node, [(STEP, joint_state(3, 1010))], start_ms=1010)  # no later wrench comes
    node.get_clock().nanoseconds = 1109 * MS
    node.inputs.spec.release_held(None)  # the timer's call: wait_s (0.1 s) not over yet
    assert len(seen) == 1
    node.get_clock().nanoseconds = 1110 * MS
    node.inputs.spec.release_held(None)
    assert len(seen) == 2 and node.counters()["obs.late"] == 1
    feed(node, [(GRIP, gripper(4)), (WRENCH, wrench(4, 1199)), (STEP, joint_state(4, 1200))], start_ms=1198)
    node.inputs.markers.on_episode(marker("end"))
    feed(node, [(GRIP, gripper(5)), (WRENCH, wrench(5, 1299)), (STEP, joint_state(5, 1300))], start_ms=1298)
    assert node._on_reset(Trigger.Request(), Trigger.Response()).success
    assert [s // MS for _, s in seen] == [1002, 1010, 1200, 1300] and node.counters()["obs.late"] == 3
    node.destroy_node()


def test_empty_spec_keeps_the_single_topic_path(ctx, ckpt: Path) -> None:
    node = make_node(ctx, ckpt, spec="", obs_dim=OBS_DIM)
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.assembled is None and not any(k.startswith("obs.") for k in node.counters())
    node.destroy_node()


def test_qos_mismatch_on_a_spec_topic_is_one_line_and_a_counter(ctx, ckpt: Path) -> None:
    node = active_node(ctx, ckpt, obs_qos="reliable")
    lines: list[str] = []
    node.get_logger().error = lines.append  # type: ignore[method-assign]
    peer = rclpy.create_node("best_effort_arm", context=ctx)
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    peer.create_publisher(WrenchStamped, WRENCH, best_effort)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    deadline = time.monotonic() + 10
    while not node.counters()["qos_incompatible"] and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert node.counters()["qos_incompatible"] >= 1 and node.inputs.active
    assert WRENCH in lines[0] and "obs_qos" in lines[0] and "\n" not in lines[0], lines
    executor.shutdown()
    peer.destroy_node()
    node.destroy_node()
