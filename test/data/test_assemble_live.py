"""Live over DDS and offline from the bag: identical observations from the same messages.

A publisher process plays an arm on the foreign namespace ``/arm1``: ``joint_states`` (JointState,
BEST_EFFORT, the step topic), ``gripper`` (Float32MultiArray) and ``wrench`` (WrenchStamped).  This
process subscribes (raw CDR), feeds an :class:`ObservationAssembler` live and, in the same callbacks,
records every message into a rosbag2 with the receive time as log time.  Reading the bag back
through :func:`assemble_stream` must give exactly the live observations, drops and counters.  Some
wrenches are published after their step (stamped before it): the step waits for them, live and
offline.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec, assemble_stream  # noqa: E402

STEPS = 300
SPEC = ObservationSpec.from_dict({
    "step_topic": "joint_states",
    "tolerance_s": 0.05,
    "fields": [
        {"topic": "joint_states", "type": "sensor_msgs/msg/JointState", "field": "position",
         "names": ["j1", "j2", "j3"]},
        {"topic": "gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 2},
        {"topic": "joint_states", "type": "sensor_msgs/msg/JointState", "field": "velocity",
         "names": ["j3", "j1"]},
        {"topic": "wrench", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"},
    ],
}).with_namespace("/arm1")
TYPES = SPEC.topics

PUBLISHER = textwrap.dedent(f"""
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
    deadline = time.monotonic() + 20
    while min(p.get_subscription_count() for p in (js, grip, ft)) == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    for k in range({STEPS}):
        w = WrenchStamped()
        w.header.stamp = node.get_clock().now().to_msg()
        w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = 0.5 * k, -1.0, 2.0
        w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = 0.25, 0.125 * k, -3.0
        if k % 7 != 3 and k % 5 != 2:
            ft.publish(w)
        if k % 11 != 5:
            grip.publish(Float32MultiArray(data=[0.01 * k, 1.0 - 0.01 * k]))
        time.sleep(0.002)
        msg = JointState()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.name = ["j1", "j2", "j3"] if k % 2 else ["j3", "j2", "j1", "j4"]
        values = {{"j1": 1.0 * k, "j2": 2.0 * k, "j3": -1.0 * k, "j4": 9.0}}
        msg.position = [values[n] for n in msg.name]
        msg.velocity = [0.5 * values[n] for n in msg.name]
        js.publish(msg)
        if k % 7 != 3 and k % 5 == 2:  # stamped before the step, delivered after it
            time.sleep(0.001)
            ft.publish(w)
        time.sleep(0.002)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
""")


def test_live_and_bag_give_identical_observations(tmp_path: Path, ros_env: dict[str, str]) -> None:
    from rosbags.rosbag2 import Reader, Writer

    proc = subprocess.Popen([sys.executable, "-c", PUBLISHER], env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    bag = tmp_path / "arm_bag"
    writer = Writer(bag, version=9)
    writer.open()
    conns = {t: writer.add_connection(t, typ, typestore=m.typestore()) for t, typ in TYPES.items()}
    live = ObservationAssembler(SPEC)
    live_out: list[np.ndarray | Drop] = []
    last = [0]

    def callback(topic: str):
        def on_message(raw: bytes) -> None:
            now = last[0] = max(time.time_ns(), last[0] + 1)  # strictly increasing log times
            writer.write(conns[topic], now, raw)
            if topic == SPEC.step_topic:
                live.hold(now, raw)  # as ompn_node: held until the wrench caught up, then decided
            else:
                live.offer(topic, now, raw)
            live_out.extend(d.result for d in live.release(now))
        return on_message

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("recorder", context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        best = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        classes = {"/arm1/joint_states": JointState, "/arm1/gripper": Float32MultiArray,
                   "/arm1/wrench": WrenchStamped}
        for topic, cls in classes.items():
            qos = best if topic == SPEC.step_topic else reliable
            node.create_subscription(cls, topic, callback(topic), qos, raw=True)
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        live_out.extend(d.result for d in live.release(flush=True))  # the end of the recording
    finally:
        rclpy.try_shutdown(context=ctx)
        writer.close()
        if proc.poll() is None:
            proc.kill()
        out = proc.communicate()[0]
    assert proc.returncode == 0, out

    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        offline = assemble_stream(((c.topic, t, raw) for c, t, raw in reader.messages()), SPEC, types=types)

    kept = [x for x in live_out if isinstance(x, np.ndarray)]
    assert len(live_out) >= 0.8 * STEPS, f"only {len(live_out)} of {STEPS} joint states arrived"
    assert len(kept) >= 0.5 * STEPS, live.stats.as_dict()
    assert offline.kept.tolist() == [isinstance(x, np.ndarray) for x in live_out]
    np.testing.assert_array_equal(offline.observations, np.stack(kept))
    assert [(d.reason, d.topic, d.stamp_ns) for d in offline.drops] == [
        (d.reason, d.topic, d.stamp_ns) for d in live_out if isinstance(d, Drop)]
    assert offline.stats.as_dict() == live.stats.as_dict() and not offline.type_problems
    # the content is the arm's: joints picked by name whatever the message order, partners attached
    k = offline.observations[:, 0]
    np.testing.assert_array_equal(offline.observations[:, 1], 2 * k)
    np.testing.assert_array_equal(offline.observations[:, 5:7], np.stack([-0.5 * k, 0.5 * k], axis=1))
    assert offline.names[5] == "arm1/joint_states/velocity/j3" and offline.observations.shape[1] == 13
    # the gripper and wrench of a step are the latest ones at or before it: never from a later k
    assert np.all(offline.observations[:, 3] <= 0.01 * k + 1e-6)
    assert np.all(offline.observations[:, 7] <= 0.5 * k)
    # the step waits for the wrench stamped before it, even when it is delivered after it
    has_wrench = k.astype(int) % 7 != 3
    has_wrench[-1] = False  # the last step never sees a later wrench: flushed at the end, late
    np.testing.assert_array_equal(offline.observations[has_wrench, 7], 0.5 * k[has_wrench])
    assert (has_wrench & (k.astype(int) % 5 == 2)).sum() >= 0.1 * len(k)
