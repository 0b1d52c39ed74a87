"""Time bases per topic (``stamps``): labels stamped with receive time next to joint states stamped with
the robot's clock are refused in one line naming both topics and the offset, and read per topic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state, scalar

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.errors import AlignmentError, ReaderSpecError, TopicTypeError

JOINTS = ["a", "b"]
ROBOT_BEHIND = 10 * S  # the robot's clock runs 10 s behind the recording machine's


def _bag(path: Path, behind: int = ROBOT_BEHIND) -> dict:
    """Joint states and commands with header stamps on the robot's clock, skill ids (Int32) stamped
    only by the recorder's receive time; 25 Hz, one episode of 60 steps."""
    rng = np.random.default_rng(0)
    bag = BagWriter(path)
    pos, acts, ids = rng.normal(size=(61, 2)), rng.normal(size=(60, 2)), np.repeat([7, 3, 9], 20)
    for k in range(61):
        receive = 100 * S + k * 40 * MS
        head = receive - behind - int(rng.integers(1, 4)) * MS
        bag.add("/arm/joint_states", JOINT_STATE, receive, joint_state(head, JOINTS, pos[k]), BEST_EFFORT)
        if k < 60:
            bag.add("/arm/joint_command", JOINT_STATE, receive + 3 * MS,
                    joint_state(head + 2 * MS, JOINTS, (), acts[k]))
            skill = scalar("std_msgs/msg/Int32", int(ids[k]))
            bag.add("/arm/skill", "std_msgs/msg/Int32", receive + 4 * MS, skill)
    bag.write()
    return {"obs": pos, "act": acts, "ids": ids}


def _spec(**changes: object) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "namespace": "/arm", "observation": {"topic": "joint_states", "type": JOINT_STATE},
        "action": {"topic": "joint_command", "type": JOINT_STATE, "fields": ["velocity"]},
        "subtask": "skill", "labels": "id", "sketch": None, "episode": None, "tolerance": 0.02,
        "stamp": "header", **changes})


def test_labels_on_another_clock_are_one_line_with_the_offset(tmp_path: Path) -> None:
    _bag(tmp_path / "bag")
    with pytest.raises(AlignmentError) as info:
        read_episodes(tmp_path / "bag", spec=_spec())
    text = str(info.value)
    assert "'/arm/skill'" in text and "'/arm/joint_states'" in text and "+10.00" in text
    assert "60 of 60 messages" in text and "stamps" in text and "\n" not in text


def test_labels_shifted_by_steps_are_one_line_too(tmp_path: Path) -> None:
    """The robot's clock 0.4 s behind, within the tolerance: each label would silently land on the
    observation 10 steps later."""
    _bag(tmp_path / "bag", behind=400 * MS)
    with pytest.raises(AlignmentError) as info:
        read_episodes(tmp_path / "bag", spec=_spec(tolerance=5.0))
    text = str(info.value)
    assert "about 10 steps off" in text and "+0.40" in text and "'/arm/skill'" in text
    (episode,) = read_episodes(tmp_path / "bag", spec=_spec(tolerance=5.0, stamp="log")).episodes
    assert episode.subtask.tolist() == [0] * 20 + [1] * 20 + [2] * 20


def test_time_base_per_topic_reads_it(tmp_path: Path) -> None:
    truth = _bag(tmp_path / "bag")
    spec = _spec(stamps={"joint_states": "log", "joint_command": "log"})
    (episode,) = read_episodes(tmp_path / "bag", spec=spec).episodes
    np.testing.assert_allclose(episode.observations, truth["obs"].astype(np.float32))
    np.testing.assert_allclose(episode.actions, truth["act"].astype(np.float32))
    assert episode.extras["subtask_id"].tolist() == truth["ids"].tolist()
    assert episode.subtask.tolist() == [0] * 20 + [1] * 20 + [2] * 20


def test_the_same_clock_everywhere_is_not_refused(tmp_path: Path) -> None:
    truth = _bag(tmp_path / "bag")
    (episode,) = read_episodes(tmp_path / "bag", spec=_spec(stamp="log")).episodes
    np.testing.assert_allclose(episode.actions, truth["act"].astype(np.float32))


def test_stamps_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ReaderSpecError, match="'log' or 'header'"):
        _spec(stamps={"skill": "robot"})
    _bag(tmp_path / "bag")
    with pytest.raises(TopicTypeError, match="no header stamp"):
        read_episodes(tmp_path / "bag", spec=_spec(stamps={"skill": "header"}))
