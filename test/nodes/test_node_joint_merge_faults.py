"""``joint_merge`` when a driver misbehaves: the gripper's publisher goes silent (named once, every
dropped step counted), a malformed message (the advice fits the fault), values stamped an hour ahead
(refused and counted live, never merged offline)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from node_in_process import active_node  # noqa: E402 (publishers that record)
from sensor_msgs.msg import JointState  # noqa: E402

from ompn_ros.data.joint_merge import JointMerger, MalformedJointState  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402

S, MS = 1_000_000_000, 1_000_000
ARM, GRIPPER = ["j1", "j2", "j3"], ["finger"]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(4)
    path = tmp_path_factory.mktemp("merge") / "ckpt"
    save_checkpoint(path, OMPNPolicy(OMPNConfig(obs_dim=4, action_type="continuous", action_dim=3,
                                                n_slots=3, slot_size=16)))
    return path


def msg(head: int, names: list[str], position: Any) -> JointState:
    out = JointState(name=names, position=[float(v) for v in position])
    out.header.stamp.sec, out.header.stamp.nanosec = divmod(head, S)
    return out


def _node(ctx: Any, ckpt: Path, lines: list[str]) -> Any:
    node = active_node(ctx, ckpt, obs_source="joint_state", joint_names=ARM + GRIPPER, joint_merge=0.05)
    node.outputs.warn_throttled = lambda text, with_total=True: lines.append(text)  # type: ignore[method-assign]
    logger = node.get_logger()
    logger.warning = lambda text, *a, **k: lines.append(text)  # type: ignore[method-assign]
    return node


def test_a_silent_gripper_is_named_once_and_every_dropped_step_counted(ctx: Any, ckpt: Path) -> None:
    lines: list[str] = []
    node = _node(ctx, ckpt, lines)
    t = time.time_ns()
    for k in range(10):  # both drivers at 50 Hz
        node.inputs.joint_states.on_joint_state(msg(t + k * 20 * MS, GRIPPER, [0.01 * k]))
        node.inputs.joint_states.on_joint_state(msg(t + k * 20 * MS + MS, ARM, [0.1 * k, 0.2, 0.3]))
    assert node.counters()["accepted"] == 10
    for k in range(10, 40):  # the gripper's driver died
        node.inputs.joint_states.on_joint_state(msg(t + k * 20 * MS + MS, ARM, [0.1 * k, 0.2, 0.3]))
    counters = node.counters()
    assert counters["accepted"] == 10 + 2  # its last value is fresh for 50 ms
    assert counters["joint_missing"] == 28
    named = [x for x in lines if "finger" in x]
    assert len(named) == 1 and "silent" in named[0] and "joint_missing" in named[0], lines
    node.inputs.joint_states.on_joint_state(msg(t + 40 * 20 * MS, GRIPPER, [0.5]))  # back: steps again
    node.inputs.joint_states.on_joint_state(msg(t + 40 * 20 * MS + MS, ARM, [4.0, 0.2, 0.3]))
    assert node.counters()["accepted"] == 13
    for k in range(41, 45):  # silent again: named again, once
        node.inputs.joint_states.on_joint_state(msg(t + k * 20 * MS + MS, ARM, [0.1 * k, 0.2, 0.3]))
    assert len([x for x in lines if "finger" in x]) == 2
    node.destroy_node()


def test_a_malformed_message_is_refused_with_its_own_fault(ctx: Any, ckpt: Path) -> None:
    lines: list[str] = []
    node = _node(ctx, ckpt, lines)
    t = time.time_ns()
    node.inputs.joint_states.on_joint_state(msg(t, GRIPPER, [0.0]))
    # four positions for three joints
    node.inputs.joint_states.on_joint_state(msg(t + MS, ARM, [0.1, 0.2, 0.3, 0.4]))
    counters = node.counters()
    assert counters["accepted"] == 0 and counters["rejected_malformed"] == 1
    assert len(lines) == 1 and "position has 4 values for 3 joint names" in lines[0], lines
    assert "remove" not in lines[0]
    node.inputs.joint_states.on_joint_state(msg(t + 2 * MS, ARM, [0.1, 0.2, 0.3]))  # the next good one steps
    assert node.counters()["accepted"] == 1
    node.destroy_node()


def test_a_value_stamped_an_hour_ahead_is_refused_and_never_merged(ctx: Any, ckpt: Path) -> None:
    lines: list[str] = []
    node = _node(ctx, ckpt, lines)
    t = time.time_ns()
    node.inputs.joint_states.on_joint_state(msg(t + 3600 * S, GRIPPER, [0.7]))
    for k in range(5):
        node.inputs.joint_states.on_joint_state(msg(t + k * 20 * MS, ARM, [0.1 * k, 0.2, 0.3]))
    counters = node.counters()
    assert counters["rejected_future_stamp"] == 1
    assert counters["accepted"] == 0 and counters["joint_missing"] == 5
    node.destroy_node()


def test_the_merge_rule_alone() -> None:
    """Offline (the reader) too: a value stamped far after the step is not fresh, and a malformed
    message raises before anything of it is taken."""
    merger = JointMerger(ARM + GRIPPER, 50 * MS)
    merger.push(3600 * S, GRIPPER, {"position": np.array([0.7])})
    assert merger.push(0, ARM, {"position": np.array([0.1, 0.2, 0.3])}) is None
    line = merger.silence_line()
    assert line is not None and "'finger' (stamped 3.6e+03 s after the step)" in line
    assert merger.silence_line() is None
    with pytest.raises(MalformedJointState, match="velocity has 2 values for 3 joint names"):
        merger.push(MS, ARM, {"position": np.array([9.0, 9.0, 9.0]), "velocity": np.zeros(2)})
    merger.push(2 * MS, GRIPPER, {"position": np.array([0.5])})
    step = merger.push(3 * MS, ARM, {"position": np.array([0.1, 0.2, 0.3])})
    assert step is not None and step.values["position"].tolist() == [0.1, 0.2, 0.3, 0.5]
