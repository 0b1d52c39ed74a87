"""ompn_node assembles its observation from three topics of a foreign namespace, over DDS.

An arm driver process publishes ``/arm1/joint_states`` (JointState, BEST_EFFORT, the step topic),
``/arm1/gripper`` (Float32MultiArray) and ``/arm1/wrench`` (WrenchStamped, absent for the first steps);
``ompn_node`` runs in its own process and namespace with ``observation_spec``.  This process records
every arm message with its receive time and the node's ``~/pi``.  The node must publish one ``~/pi``
per step the assembler keeps, count the dropped ones by reason, and its outputs must equal an offline
replay of ``assemble_stream`` over the recorded messages through the same StreamingSegmenter.
"""

from __future__ import annotations

import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import WrenchStamped  # noqa: E402
from node_process import NodeProcess, Peer  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_ros.data.messages import parse_float32_array  # noqa: E402
from ompn_ros.data.obs import ObservationSpec, assemble_stream  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

torch.set_num_threads(1)
STEPS, NO_WRENCH = 200, 5
# receive stamps and a tolerance far above the publishing gaps: the rule then depends only on the
# order the messages arrive in, which both processes see alike (staleness is tested in process)
SPEC_TEXT = (
    "{step_topic: /arm1/joint_states, tolerance_s: 1.0, stamp: receive, fields: ["
    "{topic: /arm1/joint_states, type: sensor_msgs/msg/JointState, field: position, names: [j1, j2, j3]},"
    "{topic: /arm1/gripper, type: std_msgs/msg/Float32MultiArray, field: data, size: 2},"
    "{topic: /arm1/wrench, type: geometry_msgs/msg/WrenchStamped, field: wrench}]}"
)
SPEC = ObservationSpec.from_param(SPEC_TEXT)
OBS_DIM = 3 + 2 + 6
BEST = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

DRIVER = textwrap.dedent(f"""
    import time
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float32MultiArray

    rclpy.init()
    node = rclpy.create_node("arm_driver", namespace="arm1")
    best = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    js = node.create_publisher(JointState, "joint_states", best)
    grip = node.create_publisher(Float32MultiArray, "gripper", reliable)
    ft = node.create_publisher(WrenchStamped, "wrench", reliable)
    deadline = time.monotonic() + 30
    while min(p.get_subscription_count() for p in (js, grip, ft)) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    for k in range({STEPS}):
        if k >= {NO_WRENCH} and k % 9 != 4:
            w = WrenchStamped()
            w.header.stamp = node.get_clock().now().to_msg()
            w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = 0.05 * k, -1.0, 2.0
            w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = 0.25, 0.01 * k, -3.0
            ft.publish(w)
        grip.publish(Float32MultiArray(data=[0.01 * k, 1.0 - 0.01 * k]))
        time.sleep(0.005)
        msg = JointState()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.name = ["j1", "j2", "j3"] if k % 2 else ["j3", "j2", "j1", "j4"]
        values = {{"j1": 0.1 * k, "j2": 0.2 * k, "j3": -0.1 * k, "j4": 9.0}}
        msg.position = [values[n] for n in msg.name]
        msg.velocity = [0.5 * values[n] for n in msg.name]
        js.publish(msg)
        time.sleep(0.005)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "nodeobs2", seed=5,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=3, slot_size=16)


def replay_pi(ckpt: Path, observations: np.ndarray) -> np.ndarray:
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig())
    rows = []
    for x in observations:
        so = seg.step(x).step_output
        rows.append(np.concatenate([so.pi, [so.expected_position, so.pi_end]]).astype(np.float32))
    return np.stack(rows)


def test_node_assembles_three_topics(ckpt: Path, ros_env: dict[str, str], tmp_path: Path) -> None:
    ns = f"/obs2p_{os.getpid()}"
    spec_file = tmp_path / "arm1.yaml"
    spec_file.write_text(f"observation: {SPEC_TEXT}\n")
    node_proc = NodeProcess(ros_env, f"checkpoint:={ckpt}", f"observation_spec:={spec_file}",
                            "qos_depth:=1000", "diagnostics_period:=0.1", "max_stamp_lead:=0.0", ns=ns)
    driver = None
    recorded: list[tuple[str, int, bytes]] = []
    pis: list[np.ndarray] = []
    peer = Peer(node_proc, name="observer")
    try:
        sub = peer.node
        diags = peer.statuses(node_proc.status_name)
        def record(topic: str):
            # stamped with the DDS reception time, not the callback's: this executor serves ready
            # subscriptions in creation order, so under load a gripper message that arrived after a
            # joint state could otherwise be served, and stamped, before it
            def on_message(raw: bytes, info: dict) -> None:
                recorded.append((topic, int(info["received_timestamp"]), raw))
            return on_message

        # partners first, as the node does (a wait set serves ready subscriptions in creation order)
        for cls, topic, qos in ((Float32MultiArray, "/arm1/gripper", RELIABLE),
                                (WrenchStamped, "/arm1/wrench", RELIABLE),
                                (JointState, "/arm1/joint_states", BEST)):
            sub.create_subscription(cls, topic, record(topic), qos, raw=True)
        sub.create_subscription(Float32MultiArray, node_proc.topic("ompn_node/pi"),
                                lambda raw: pis.append(np.asarray(parse_float32_array(raw))), RELIABLE,
                                raw=True)
        pump = peer.pump

        peer.wait_active(node_proc, 60)
        driver = NodeProcess(ros_env, program=[sys.executable, "-c", DRIVER])
        assert pump(lambda: not driver.running(), 90), "the arm driver did not finish"
        steps = sum(t == SPEC.step_topic for t, _, _ in recorded)
        pump(lambda: int(diags[-1].get("obs.steps", 0)) >= steps and len(pis) >= int(diags[-1]["obs.kept"]),
             10)
        pump(lambda: False, 0.5)
    finally:
        peer.close()
        driver_out = driver.stop() if driver is not None else ""
        node_out = node_proc.stop()
    assert driver is not None and driver.returncode == 0, driver_out
    assert node_proc.returncode == 0, node_out
    assert "Traceback" not in node_out and "FATAL" not in node_out

    counters = diags[-1]
    recorded.sort(key=lambda item: item[1])  # reception order (stable for equal stamps)
    offline = assemble_stream(recorded, SPEC)
    assert offline.stats.steps >= 0.9 * STEPS, f"only {offline.stats.steps} of {STEPS} joint states arrived"
    assert int(counters["obs.steps"]) == offline.stats.steps, (counters, offline.stats)
    assert int(counters["obs.dropped.missing"]) == offline.stats.dropped["missing"] >= 1
    assert int(counters["obs.kept"]) == offline.stats.kept == int(counters["accepted"]) == len(pis)
    np.testing.assert_allclose(np.stack(pis), replay_pi(ckpt, offline.observations), rtol=1e-5, atol=1e-6)
    assert node_out.count("step dropped: missing on '/arm1/wrench'") == 1, node_out  # throttled: one line
