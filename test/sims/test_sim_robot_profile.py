"""dial_sim profile:=robot: only a real arm's topics (JointState best effort, skill id, effort), pauses."""

from __future__ import annotations

import uuid

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.qos import ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from sim_listener import RELIABLE, Listener, finish, launch, stamp_ns  # noqa: E402
from std_msgs.msg import Float32MultiArray, Float64MultiArray, Int32  # noqa: E402

from ompn_ros import layout  # noqa: E402

SKETCH = [1, 7, 3, 9]


def test_robot_profile_publishes_only_robot_topics(ros_env: dict[str, str]) -> None:
    ns = f"robot_{uuid.uuid4().hex[:6]}"
    names = ("joint_states", "skill_id", "effort_command")
    js_topic, skill_topic, effort_topic = (f"/{ns}/jaco/{t}" for t in names)
    lis = Listener()
    lis.listen(js_topic, JointState, qos_profile_sensor_data)
    lis.listen(skill_topic, Int32, RELIABLE)
    lis.listen(effort_topic, Float64MultiArray, RELIABLE)
    proc = launch(ros_env, ns, "profile:=robot", "rate:=100.0", "episodes:=2", f"sketch:={SKETCH}",
                  "wait_for_subscribers:=1", "noise:=0.0")  # fmt: skip
    try:
        lis.spin_until(lambda: len(lis.of(skill_topic)) > 0, timeout=60)
        topics = dict(lis.node.get_publisher_names_and_types_by_node("dial_sim", f"/{ns}"))
        js_qos = [i.qos_profile.reliability for i in lis.node.get_publishers_info_by_topic(js_topic)]
        lis.spin_until(lambda: proc.poll() is not None, timeout=90)
        lis.spin_until(lambda: False, timeout=0.3)
        code, err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        lis.close()
    assert code == 0, err
    ours = {t for t in topics if t not in ("/rosout", "/parameter_events", f"/{ns}/clock")}
    assert ours == {js_topic, skill_topic, effort_topic}, topics  # no markers, sketch or observation
    assert js_qos == [ReliabilityPolicy.BEST_EFFORT]

    joints = [(m, src) for t, m, src in lis.log if t == js_topic]
    skills = [m.data for m in lis.of(skill_topic)]
    efforts = lis.of(effort_topic)
    assert len(skills) == len(efforts) > 40  # reliable: one per step
    # best effort may drop a few JointStates (T + 1 per episode are published), not most of them
    assert len(skills) + 2 >= len(joints) > 0.9 * len(skills)
    # episodes are split by a pause of >= 1 s, in wall time and in the stamps
    wall = np.diff([src for _, src in joints])
    header = np.diff([stamp_ns(m.header.stamp) for m, _ in joints])
    assert (wall >= 1e9).sum() == 1 and (header >= 1e9).sum() == 1
    steps = header[header < 1e9]
    assert np.all(steps % layout.STEP_NS == 0) and np.median(steps) == layout.STEP_NS  # 25 Hz sim time
    # skill ids: the digits pressed, in sketch order (ids, not ordinals), in both episodes
    changes = [s for i, s in enumerate(skills) if i == 0 or s != skills[i - 1]]
    assert changes == SKETCH + SKETCH
    # the effort command is what the arm executed: the effort of the JointState after each step
    assert efforts[0].layout.dim[0].label == "effort" and len(efforts[0].data) == 9
    commanded = {tuple(e.data) for e in efforts}
    after_step = [m for (m, _), gap in zip(joints[1:], header) if gap < 1e9]
    assert all(tuple(m.effort) in commanded for m in after_step)
    assert len(joints[0][0].name) == len(joints[0][0].position) == 9


def test_robot_profile_refuses_policy_mode(ros_env: dict[str, str]) -> None:
    proc = launch(ros_env, "robot_bad", "profile:=robot", "mode:=policy")
    code, err = finish(proc, timeout=60)
    assert code == 2 and "'profile'" in err, err


def test_effort_command_type_float32(ros_env: dict[str, str]) -> None:
    ns = f"robot32_{uuid.uuid4().hex[:6]}"
    lis = Listener()
    topic = f"/{ns}/jaco/effort_command"
    lis.listen(topic, Float32MultiArray, RELIABLE)
    proc = launch(ros_env, ns, "profile:=robot", "rate:=50.0", "effort_command_type:=float32")
    try:
        lis.spin_until(lambda: len(lis.of(topic)) >= 2, timeout=60)
    finally:
        proc.terminate()
        _, err = finish(proc)
        lis.close()
    efforts = lis.of(topic)
    assert len(efforts) >= 2 and len(efforts[0].data) == 9, err
