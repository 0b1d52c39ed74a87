"""dial_sim in a subprocess: topics, rate, step contract, expert data == generate_episodes, bad params."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from sim_listener import launch  # noqa: E402
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.data.episode import observation_copies  # noqa: E402
from sim_nodes import derive_seed  # noqa: E402
from sim_nodes.dial import generate_episodes  # noqa: E402
from sim_nodes.dial.human import generate_human_episode  # noqa: E402
from sim_nodes.human import parse_human  # noqa: E402

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


class Recorder:
    """Subscribes to every dial_sim topic in its own context and logs (topic, message, time)."""

    def __init__(self, namespace: str) -> None:
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("dial_test_recorder", context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.log: list[tuple[str, object, float, int]] = []  # topic, msg, receive time, source stamp
        types = {
            layout.OBSERVATION: Float32MultiArray, layout.JOINT_STATES: JointState, layout.SUBTASK: Int32,
            layout.ACTION: Float32MultiArray, layout.SKETCH: Int32MultiArray, layout.EPISODE: DiagnosticArray,
        }  # fmt: skip
        for topic, msg_type in types.items():
            self.node.create_subscription(
                msg_type, f"/{namespace}/{topic}",
                lambda m, info, t=topic: self.log.append((t, m, time.monotonic(), info["source_timestamp"])),
                qos_profile_sensor_data if topic == layout.JOINT_STATES else RELIABLE,  # as a driver's
            )  # fmt: skip

    def spin_until(self, done, timeout: float) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not done():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)

    def of(self, topic: str) -> list:
        return [m for t, m, _, _ in self.log if t == topic]

    def published_order(self) -> list[str]:
        """Topics in publish order (DDS source timestamps; receive order differs across topics)."""
        return [t for t, _, _, _ in sorted(self.log, key=lambda e: e[3])]


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.terminate()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err


def test_topics_arrive_at_rate_in_contract_order(ros_env: dict[str, str]) -> None:
    rec = Recorder("dial_rate")
    proc = launch(ros_env, "dial_rate", "rate:=25.0", "sketch:=[1,2,3,4]", "wait_for_subscribers:=1",
                  "seed:=2")  # fmt: skip
    try:
        rec.spin_until(lambda: len(rec.of(layout.OBSERVATION)) >= 40, timeout=30)
    finally:
        err = stop(proc)
        rec.close()
    obs_times = [t for topic, _, t, _ in rec.log if topic == layout.OBSERVATION]
    assert len(obs_times) >= 40, err
    rate = (len(obs_times) - 11) / (obs_times[-1] - obs_times[10])
    assert 15.0 < rate < 35.0, f"observation rate {rate:.1f} Hz, configured 25"
    topics = rec.published_order()
    assert topics[:2] == [layout.EPISODE, layout.SKETCH]
    step = list(layout.DIAL.step_topics)
    assert topics[2:2 + 4 * 10] == step * 10
    start = rec.of(layout.EPISODE)[0].status[0]
    assert start.message == layout.EPISODE_START
    assert {kv.key: kv.value for kv in start.values}[layout.KEY_SKETCH] == "1,2,3,4"
    assert list(rec.of(layout.SKETCH)[0].data) == [1, 2, 3, 4]
    assert rec.of(layout.SKETCH)[0].layout.dim[0].label == "sketch"  # as in collected bags
    obs = rec.of(layout.OBSERVATION)[0]
    assert len(obs.data) == 39 and obs.layout.dim[0].label == "obs"
    js = rec.of(layout.JOINT_STATES)
    assert len(js[0].name) == len(js[0].position) == len(js[0].velocity) == len(js[0].effort) == 9
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in js[:5]]
    np.testing.assert_allclose(np.diff(stamps), 0.04, atol=1e-6)  # sim time, 25 Hz
    np.testing.assert_allclose(js[3].position, np.array(rec.of(layout.OBSERVATION)[3].data[:9]), atol=1e-5)
    assert len(rec.of(layout.ACTION)[0].data) == 9
    assert rec.of(layout.SUBTASK)[0].data == 0


def one_episode(ros_env: dict[str, str], ns: str, *params: str) -> Recorder:
    """Run dial_sim in namespace ``ns`` for one episode (seed 9, as fast as it can) with ``params``;
    what it published, once it exited with code 0."""
    rec = Recorder(ns)
    proc = launch(ros_env, ns, "rate:=0.0", "episodes:=1", "seed:=9", "wait_for_subscribers:=1", *params)
    try:
        rec.spin_until(lambda: len(rec.of(layout.EPISODE)) >= 2, timeout=60)
        rec.spin_until(lambda: False, timeout=0.3)
        code = proc.wait(timeout=30)
    finally:
        err = stop(proc)
        rec.close()
    assert code == 0, err
    return rec


def test_expert_episode_matches_generate_episodes(ros_env: dict[str, str]) -> None:
    expected = next(iter(generate_episodes(1, seed=9)))
    rec = one_episode(ros_env, "dial_full")
    end = {kv.key: kv.value for kv in rec.of(layout.EPISODE)[1].status[0].values}
    assert end[layout.KEY_SUCCESS] == "true" and int(end[layout.KEY_STEPS]) == expected.length
    obs = np.array([m.data for m in rec.of(layout.OBSERVATION)], dtype=np.float32)
    assert obs.shape == expected.observations.shape  # T + 1 including the final observation
    np.testing.assert_allclose(obs, expected.observations, atol=1e-6)
    actions = np.array([m.data for m in rec.of(layout.ACTION)], dtype=np.float32)
    np.testing.assert_allclose(actions, expected.actions, atol=1e-6)
    assert [m.data for m in rec.of(layout.SUBTASK)] == expected.subtask.tolist()
    assert list(rec.of(layout.SKETCH)[0].data) == expected.sketch.tolist()


def test_human_demonstrator_publishes_its_episode(ros_env: dict[str, str]) -> None:
    """demonstrator:=human: generate_human_episode's noisy rows, observations as often as their copies."""
    human = ["drop_rate=0.05", "duplicate_rate=0.05"]
    expected = generate_human_episode(derive_seed(9, 0), parse_human("dial", human))
    rec = one_episode(ros_env, "dial_human", "demonstrator:=human", f"human:=[{','.join(human)}]")
    copies = observation_copies(expected)
    assert (copies == 0).any() and (copies == 2).any()
    obs = np.array([m.data for m in rec.of(layout.OBSERVATION)], dtype=np.float32)
    np.testing.assert_array_equal(obs, np.repeat(expected.observations, copies, axis=0))
    actions = np.array([m.data for m in rec.of(layout.ACTION)], dtype=np.float32)
    np.testing.assert_allclose(actions, expected.actions, atol=1e-6)
    assert [m.data for m in rec.of(layout.SUBTASK)] == expected.subtask.tolist()
    positions = np.array([m.position for m in rec.of(layout.JOINT_STATES)])  # best effort: a subset
    gap = np.abs(positions[:, None, :] - expected.extras["joint_position"][None]).max(axis=2).min(axis=1)
    assert len(positions) > 0 and gap.max() < 1e-9  # the noisy joint states of the episode


@pytest.mark.parametrize(
    ("param", "name"),
    [("press_tolerance:=5.0", "press_tolerance"), ("sketch:=[3,3,1,2]", "sketch"), ("mode:=teleop", "mode")],
)
def test_bad_parameter_exits_nonzero(ros_env: dict[str, str], param: str, name: str) -> None:
    proc = launch(ros_env, "dial_bad", param)
    try:
        code = proc.wait(timeout=60)
    finally:
        err = stop(proc)
    assert code != 0
    assert f"'{name}'" in err, err


def test_policy_mode_steps_only_on_cmd_action(ros_env: dict[str, str]) -> None:
    rec = Recorder("dial_policy")
    cmd = rec.node.create_publisher(Float32MultiArray, "/dial_policy/cmd_action", RELIABLE)
    proc = launch(ros_env, "dial_policy", "mode:=policy", "rate:=0.0", "policy_timeout:=0.3",
                  "wait_for_subscribers:=1", "sketch:=[0,1,2,3]")  # fmt: skip
    sent: list[list[float]] = []
    try:
        for i in range(5):
            rec.spin_until(lambda i=i: len(rec.of(layout.OBSERVATION)) >= i + 1, timeout=30)
            sent.append([0.05 * (i + 1)] * 9)
            cmd.publish(Float32MultiArray(data=sent[-1]))
        rec.spin_until(lambda: len(rec.of(layout.OBSERVATION)) >= 6, timeout=10)
        rec.spin_until(lambda: False, timeout=1.5)  # no command: the sim must hold and warn
    finally:
        err = stop(proc)
        rec.close()
    assert len(rec.of(layout.OBSERVATION)) == 6, err
    np.testing.assert_allclose([m.data for m in rec.of(layout.ACTION)], sent, atol=1e-6)
    assert [m.data for m in rec.of(layout.SUBTASK)] == [0] * 5
    assert "no cmd_action" in err


def test_reliable_joint_state_subscriber_is_told_the_parameter(ros_env: dict[str, str]) -> None:
    """JointState is best effort like a driver's: a RELIABLE-only subscriber gets one line naming the fix."""
    rec = Recorder("dial_qos")
    rec.node.create_subscription(JointState, "/dial_qos/joint_states", lambda m: None, RELIABLE)
    proc = launch(ros_env, "dial_qos", "rate:=5.0")
    try:
        rec.spin_until(lambda: len(rec.of(layout.OBSERVATION)) >= 3, timeout=60)
    finally:
        err = stop(proc)
        rec.close()
    assert "joint_states_qos:=reliable" in err, err
