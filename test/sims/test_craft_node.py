"""craft_sim as a subprocess, observed from this process with rclpy on its own Context."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from node_process import node_command  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray, String  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.data.episode import observation_copies  # noqa: E402
from sim_nodes import derive_seed  # noqa: E402
from sim_nodes.craft.expert import generate_episode, rollout  # noqa: E402
from sim_nodes.craft.human import generate_human_episode  # noqa: E402
from sim_nodes.human import parse_human  # noqa: E402
from sim_nodes.ros_common import SIM_QOS  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TOPICS = {
    layout.OBSERVATION: Float32MultiArray,
    layout.SUBTASK: Int32,
    layout.ACTION: Int32,
    layout.SKETCH: Int32MultiArray,
    layout.EPISODE: DiagnosticArray,
    layout.RENDER: String,
}


def start_sim(*params: str) -> subprocess.Popen:
    env = dict(os.environ)  # keeps LD_LIBRARY_PATH and the DDS containment set by conftest
    env["PYTHONUNBUFFERED"] = "1"
    return subprocess.Popen(node_command(*params, module="sim_nodes.craft.node"), cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


class Listener:
    """Subscribes to every craft topic; records (source stamp, receive order, topic, message)."""

    def __init__(self, answers: bool = True) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("craft_test_listener", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.events: list[tuple[int, int, str, object]] = []
        for topic, msg_type in TOPICS.items():
            self.node.create_subscription(msg_type, topic, self._callback(topic), SIM_QOS)
        self.cmd = self.node.create_publisher(Int32, layout.CMD_ACTION, SIM_QOS) if answers else None

    def _callback(self, topic: str) -> Callable:
        def callback(msg: object, info: dict) -> None:
            self.events.append((int(info["source_timestamp"]), len(self.events), topic, msg))

        return callback

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def of(self, topic: str) -> list:
        return [e[3] for e in self.events if e[2] == topic]

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture
def listener():
    lis = Listener()
    yield lis
    lis.close()


def finish(proc: subprocess.Popen, timeout: float = 10.0) -> tuple[int, str]:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.terminate()
        out, _ = proc.communicate(timeout=5)
        return -999, out
    return proc.returncode, out


def marker(msg: DiagnosticArray) -> tuple[str, dict[str, str]]:
    status = msg.status[0]
    assert status.name == layout.EPISODE_STATUS_NAME
    return status.message, {kv.key: kv.value for kv in status.values}


def test_expert_mode_topics_order_content_and_rate(listener):
    proc = start_sim("task:=makeaxe", "seed:=5", "rate:=25.0", "episodes:=2", "wait_for_subscribers:=1")
    try:
        ok = listener.spin_until(lambda: len(listener.of(layout.EPISODE)) >= 4, timeout=18.0)
        listener.spin_until(lambda: False, timeout=1.0)  # other topics' last messages may still be queued
        code, out = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert ok, f"did not receive 2 episodes; sim output:\n{out}"
    assert code == 0, out
    contract = {layout.OBSERVATION: "o", layout.SUBTASK: "s", layout.ACTION: "a", layout.SKETCH: "k"}
    ordered = sorted(listener.events, key=lambda e: (e[0], e[1]))
    letters = []
    for _, _, topic, msg in ordered:
        if topic == layout.EPISODE:
            letters.append("[" if marker(msg)[0] == layout.EPISODE_START else "]")
        elif topic in contract:
            letters.append(contract[topic])
    text = "".join(letters)
    episodes = [generate_episode(derive_seed(5, i), task="makeaxe") for i in range(2)]
    expected = "".join("[ko" + "sao" * ep.length + "]" for ep in episodes)
    assert text == expected  # markers bracket the steps; obs, subtask, action in contract order

    obs = np.array([m.data for m in listener.of(layout.OBSERVATION)], dtype=np.float32)
    assert listener.of(layout.OBSERVATION)[0].layout.dim[0].label == "obs"
    assert listener.of(layout.OBSERVATION)[0].layout.dim[0].size == 1075
    assert np.array_equal(obs, np.concatenate([ep.observations for ep in episodes]))
    actions = [m.data for m in listener.of(layout.ACTION)]
    assert actions == np.concatenate([ep.actions for ep in episodes]).tolist()
    assert [m.data for m in listener.of(layout.SUBTASK)] == np.concatenate(
        [ep.subtask for ep in episodes]
    ).tolist()
    assert [list(m.data) for m in listener.of(layout.SKETCH)] == [[7, 8, 5, 6]] * 2
    assert (
        len(listener.of(layout.RENDER)) == len(obs) and "task=makeaxe" in listener.of(layout.RENDER)[0].data
    )

    markers = [marker(m) for m in listener.of(layout.EPISODE)]
    (p0, start0), (p1, end0) = markers[0], markers[1]
    assert (p0, p1) == ("start", "end")
    assert start0 == {"episode": "0", "task": "makeaxe", "seed": str(episodes[0].seed), "sketch": "7,8,5,6"}
    assert end0["steps"] == str(episodes[0].length) and end0["success"] == "true"

    stamps = np.array([e[0] for e in listener.events if e[2] == layout.OBSERVATION], dtype=np.float64) * 1e-9
    first_episode_gaps = np.diff(stamps[: episodes[0].length + 1])
    assert 0.02 < np.median(first_episode_gaps) < 0.08  # 25 Hz = 40 ms per step


@pytest.mark.parametrize(
    ("param", "name"), [("task:=nonsense", "task"), ("rate:=-1.0", "rate"), ("mode:=autopilot", "mode")]
)
def test_bad_parameter_exits_nonzero_naming_it(param, name):
    proc = start_sim(param)
    code, out = finish(proc, timeout=15.0)
    assert code not in (0, -999), out
    assert f"invalid parameter '{name}'" in out


def pick_first_try_seed(task: str) -> int:
    for base in range(100):
        seed = derive_seed(base, 0)
        if rollout(seed, task, full_obs=True).success:
            return base
    raise AssertionError("no first-try seed")


def test_policy_mode_holds_then_steps_on_cmd_action(listener):
    base = pick_first_try_seed("makebed")
    demo = rollout(derive_seed(base, 0), "makebed", full_obs=True)
    proc = start_sim(
        "task:=makebed", f"seed:={base}", "mode:=policy", "rate:=0.0", "episodes:=1",
        "policy_timeout:=0.3", "wait_for_subscribers:=1",
    )  # fmt: skip
    try:
        assert listener.spin_until(lambda: len(listener.of(layout.OBSERVATION)) >= 1, timeout=12.0)
        listener.cmd.publish(Int32(data=17))  # invalid: ignored with a warning
        listener.spin_until(lambda: False, timeout=1.0)  # no command: the sim must hold
        assert len(listener.of(layout.OBSERVATION)) == 1 and not listener.of(layout.ACTION)
        for t, action in enumerate(demo.actions):
            listener.cmd.publish(Int32(data=int(action)))
            assert listener.spin_until(lambda t=t: len(listener.of(layout.OBSERVATION)) >= t + 2, timeout=5.0)
        assert listener.spin_until(lambda: len(listener.of(layout.EPISODE)) >= 2, timeout=5.0)
        listener.spin_until(lambda: False, timeout=0.5)
        code, out = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 0, out
    assert "ignoring cmd_action" in out and "no cmd_action" in out
    assert [m.data for m in listener.of(layout.ACTION)] == demo.actions.tolist()
    obs = np.array([m.data for m in listener.of(layout.OBSERVATION)], dtype=np.float32)
    assert np.array_equal(obs, demo.observations)
    phase, end = marker(listener.of(layout.EPISODE)[-1])
    assert phase == "end" and end["success"] == "true" and end["steps"] == str(demo.length)


def test_policy_mode_waits_for_a_cmd_action_publisher_before_its_first_observation():
    """An answer published before the sim's cmd_action subscription matched would be lost and the sim
    would hold forever: with wait_for_subscribers it starts only once something can answer."""
    silent = Listener(answers=False)
    proc = start_sim("task:=makebed", "seed:=3", "mode:=policy", "rate:=0.0", "episodes:=1",
                     "policy_timeout:=0.3", "wait_for_subscribers:=1")  # fmt: skip
    try:
        seen = silent.spin_until(lambda: silent.node.count_publishers(layout.OBSERVATION) >= 1, timeout=15.0)
        assert seen, "the sim's observation publisher was never discovered"
        silent.spin_until(lambda: False, timeout=2.0)  # matched, settled, but nobody can answer
        assert not silent.of(layout.OBSERVATION)
        silent.cmd = silent.node.create_publisher(Int32, layout.CMD_ACTION, SIM_QOS)
        assert silent.spin_until(lambda: len(silent.of(layout.OBSERVATION)) >= 1, timeout=12.0)
    finally:
        proc.kill()
        proc.communicate(timeout=5)
        silent.close()


def test_human_demonstrator_publishes_its_episode_with_drops_and_duplicates(listener):
    """demonstrator:=human: the episode of generate_human_episode, each observation as often as its
    observation_copies say (a dropped one is never published, a duplicated one twice)."""
    human = ["drop_rate=0.1", "duplicate_rate=0.1"]
    proc = start_sim("task:=makeaxe", "seed:=6", "rate:=0.0", "episodes:=1", "wait_for_subscribers:=1",
                     "demonstrator:=human", f"human:=[{','.join(human)}]")  # fmt: skip
    try:
        ok = listener.spin_until(lambda: len(listener.of(layout.EPISODE)) >= 2, timeout=18.0)
        listener.spin_until(lambda: False, timeout=0.5)
        code, out = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert ok and code == 0, out
    demo = generate_human_episode(derive_seed(6, 0), parse_human("craft", human), task="makeaxe")
    copies = observation_copies(demo)
    assert (copies == 0).any() and (copies == 2).any()
    obs = np.array([m.data for m in listener.of(layout.OBSERVATION)], dtype=np.float32)
    np.testing.assert_array_equal(obs, np.repeat(demo.observations, copies, axis=0))
    assert [m.data for m in listener.of(layout.ACTION)] == demo.actions.tolist()
    assert [m.data for m in listener.of(layout.SUBTASK)] == demo.subtask.tolist()


@pytest.mark.parametrize(
    ("params", "name"),
    [(("demonstrator:=human", "human:=[pause_rate=3.0]"), "human"), (("human:=[pause_rate=0.1]",), "human"),
     (("demonstrator:=human", "mode:=policy"), "demonstrator")],
)  # fmt: skip
def test_bad_human_parameter_exits_naming_it(params, name):
    code, out = finish(start_sim(*params), timeout=15.0)
    assert code not in (0, -999), out
    assert f"invalid parameter '{name}'" in out
