"""JointState as real drivers publish it: several publishers on one topic (merged by joint name,
``merge_s``), and drivers that leave ``velocity`` empty (one line naming topic and field)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.errors import ReaderSpecError, VectorLengthError
from ompn_ros.data.joint_merge import JointMerger

ARM = ["j1", "j2", "j3"]
GRIPPER = ["finger"]


def _spec(**observation: object) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "observation": {"topic": "/joint_states", "type": JOINT_STATE, "fields": ["position"], **observation},
        "action": {"topic": "/arm/cmd", "type": JOINT_STATE, "fields": ["velocity"], "joint_names": ARM},
        "subtask": None, "sketch": None, "episode": None, "tolerance": 0.008, "stamp": "header",
        "time_gap": 1.0, "final_observation": "require"})


def _two_driver_bag(path: Path, gripper_velocity: bool = True) -> dict:
    """The arm's joint_state_broadcaster at 100 Hz and the gripper driver at 25 Hz (from 0.1 s on) on
    one ``/joint_states``, BEST_EFFORT, header stamps on the robot's clock; commands from 0.2 s."""
    rng = np.random.default_rng(0)
    bag = BagWriter(path)
    t0, n = 3 * S, 150
    arm = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    grip = {}
    for k in range(10, n, 4):  # the gripper every 40 ms, 1.5 ms after the arm's tick
        head = t0 + k * 10 * MS + 1_500_000
        grip[k] = float(rng.uniform(0, 0.04))
        vel = [0.0] if gripper_velocity else []
        raw = joint_state(head, GRIPPER, [grip[k]], vel)
        bag.add("/joint_states", JOINT_STATE, head + 2 * MS, raw, BEST_EFFORT)
    rows, actions = [], []
    latest = None
    for k in range(n):
        head = t0 + k * 10 * MS
        raw = joint_state(head, ARM, arm[k], np.zeros(3))
        bag.add("/joint_states", JOINT_STATE, head + 1 * MS, raw, BEST_EFFORT)
        if k - 1 in grip:  # the gripper message 1.5 ms after the previous tick is the latest at this one
            latest = grip[k - 1]
        if 20 <= k < n - 1:  # no command after the last state
            act = rng.normal(size=3)
            bag.add("/arm/cmd", JOINT_STATE, head + 3 * MS, joint_state(head + 2 * MS, ARM, (), act))
            actions.append(act)
        if k >= 20 and latest is not None:
            rows.append(np.concatenate([arm[k], [latest]]))
    bag.write()
    return {"observations": np.asarray(rows), "actions": np.asarray(actions)}


def test_two_publishers_merge_by_joint_name(tmp_path: Path) -> None:
    truth = _two_driver_bag(tmp_path / "bag")
    spec = _spec(joint_names=ARM + GRIPPER, merge_s=0.05)
    result = read_episodes(tmp_path / "bag", spec=spec)
    report = result.report.bags[0]
    # arm ticks 0..10: no gripper state yet (dropped, counted); 11..19: merged, no command yet
    assert report.missing == {"/joint_states[finger]": 11, "/arm/cmd": 9}
    (episode,) = result.episodes
    np.testing.assert_allclose(episode.observations, truth["observations"].astype(np.float32))
    np.testing.assert_allclose(episode.actions, truth["actions"].astype(np.float32))


def test_two_publishers_without_merge_is_one_line_pointing_at_merge_s(tmp_path: Path) -> None:
    _two_driver_bag(tmp_path / "bag")
    with pytest.raises(VectorLengthError, match="merge_s") as info:
        read_episodes(tmp_path / "bag", spec=_spec(joint_names=ARM + GRIPPER))
    assert "/joint_states" in str(info.value) and "\n" not in str(info.value)


def test_a_stale_joint_drops_the_step_and_is_counted() -> None:
    merger = JointMerger(ARM + GRIPPER, 50 * MS)
    values = {"position": np.ones(3), "velocity": np.zeros(3), "effort": np.zeros(0)}
    assert merger.push(0, ARM, values) is None and merger.missing == {"finger": 1}
    assert merger.push(5 * MS, GRIPPER, {"position": np.array([0.5])}) is None  # not a step
    step = merger.push(10 * MS, ARM, values)
    assert step is not None and step.values["position"].tolist() == [1, 1, 1, 0.5]
    assert step.present == {"position": True, "velocity": False, "effort": False}
    assert merger.push(56 * MS, ARM, values) is None and merger.missing == {"finger": 2}  # 51 ms old
    with pytest.raises(ValueError, match="distinct"):
        JointMerger(["a", "a"], 0)


def test_merge_needs_joint_names() -> None:
    with pytest.raises(ReaderSpecError, match="merge_s needs joint_names"):
        _spec(merge_s=0.05)


@pytest.mark.parametrize("names", [None, ARM])
def test_empty_velocity_is_one_line_naming_topic_and_field(tmp_path: Path, names: list[str] | None) -> None:
    """A driver that publishes positions only, read with fields [position, velocity]: before, 3 values
    per observation instead of 6 without joint names, silently."""
    bag = BagWriter(tmp_path / "bag")
    for k in range(30):
        head = S + k * 10 * MS
        bag.add("/joint_states", JOINT_STATE, head + MS, joint_state(head, ARM, [0.1 * k] * 3), BEST_EFFORT)
        if k < 29:
            bag.add("/arm/cmd", JOINT_STATE, head + 3 * MS, joint_state(head, ARM, (), [1.0, 2.0, 3.0]))
    bag.write()
    spec = _spec(fields=["position", "velocity"], joint_names=names)
    with pytest.raises(VectorLengthError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    text = str(info.value)
    assert "velocity is empty" in text and "/joint_states" in text and "remove 'velocity'" in text
    assert "\n" not in text
    result = read_episodes(tmp_path / "bag", spec=_spec(fields=["position"], joint_names=names))
    assert result.episodes[0].observations.shape[1] == 3


def test_merged_gripper_without_velocity_is_one_line(tmp_path: Path) -> None:
    _two_driver_bag(tmp_path / "bag", gripper_velocity=False)
    spec = _spec(joint_names=ARM + GRIPPER, merge_s=0.05, fields=["position", "velocity"])
    with pytest.raises(VectorLengthError, match="velocity is empty"):
        read_episodes(tmp_path / "bag", spec=spec)
