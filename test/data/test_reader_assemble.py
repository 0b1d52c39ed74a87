"""The bag reader with ``assemble:``: another lab's bag (namespaced JointState + gripper
Float32MultiArray + WrenchStamped, a Float64MultiArray command, skill ids, episodes by pauses, no
markers) gives the observations of ``assemble_stream`` on the same messages, with the drops reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from joint_lab_bags import JOINTS, MS, SPEC_DICT, f64, write_lab_bag
from rosbags.rosbag2 import Writer

from ompn_ros.data import ReaderSpec, ReaderSpecError, TopicTypeError, load_arrays, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.obs import assemble_stream
from ompn_ros.data.reader import iter_raw_messages
from ompn_ros.data.recorder.bag_writer import storage_plugin


@pytest.fixture(scope="module")
def lab_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("lab") / "bag"
    return path, write_lab_bag(path)


def test_observations_equal_assemble_stream(lab_bag: tuple[Path, dict]) -> None:
    path, truth = lab_bag
    spec = ReaderSpec.from_dict(SPEC_DICT)
    result = read_episodes(path, spec=spec)
    eps = result.episodes
    assert len(eps) == 3
    stream = assemble_stream(iter_raw_messages(path), spec.assemble.with_namespace("/lab"))  # type: ignore[union-attr]
    # each episode: its kept steps, then its final observation (kept) as row T
    assert np.array_equal(np.concatenate([e.observations for e in eps]), stream.observations)
    kept_truth = np.asarray(truth["obs"])[stream.kept]
    assert np.allclose(stream.observations, kept_truth)  # and those are the published values
    assert eps[0].observations.shape[1] == 3 + 3 + 2 + 6
    names = eps[0].extras["obs_names"]
    assert len(names) == 14 and names[0].endswith("position/j1") and names[-1].endswith("torque.z")
    bag = result.report.bags[0]
    assert bag.obs_dropped == {"stale": truth["stale"], "wrong_size": truth["wrong_size"]}
    assert bag.obs_rejected == {"/lab/arm/gripper: wrong_size": 1}
    assert "observation rule dropped 2 step(s)" in result.report.summary()
    assert result.report.to_dict()["obs_dropped"] == bag.obs_dropped


def test_actions_and_ids_follow_the_kept_steps(lab_bag: tuple[Path, dict]) -> None:
    path, truth = lab_bag
    eps = read_episodes(path, spec=ReaderSpec.from_dict(SPEC_DICT)).episodes
    act, ids = np.asarray(truth["act"]), np.asarray(truth["ids"])
    lengths = [20, 25, 30]  # observations per episode; the last one of each has no action
    starts = np.cumsum([0, *lengths[:-1]])
    action_rows = [start + j for start, n in zip(starts, lengths) for j in range(n - 1)]
    dropped = {20 + 7, 45 + 5}  # stale (episode 1, step 7) and wrong size (episode 2, step 5)
    kept = [k for k, row in enumerate(action_rows) if row not in dropped]
    got_act = np.concatenate([e.actions for e in eps])
    assert got_act.dtype == np.float32 and got_act.shape == (len(action_rows) - 2, 3)
    assert np.allclose(got_act, act[kept])
    assert np.array_equal(np.concatenate([e.extras["subtask_id"] for e in eps]), ids[kept])
    assert [list(np.unique(e.subtask)) for e in eps] == [[0, 1, 2]] * 3  # ordinals from the id changes
    assert all(e.task == "lab_demo" for e in eps)


def test_spec_round_trip_and_cache(lab_bag: tuple[Path, dict], tmp_path: Path) -> None:
    spec = ReaderSpec.from_dict(SPEC_DICT)
    assert ReaderSpec.from_dict(spec.to_dict()) == spec
    arrays = load_arrays([lab_bag[0]], spec=spec, cache_dir=tmp_path)
    again = load_arrays([lab_bag[0]], spec=spec, cache_dir=tmp_path)
    assert again.cache_hit and np.array_equal(again.observations, arrays.observations)


def test_wrong_type_names_the_topic(lab_bag: tuple[Path, dict]) -> None:
    data = {**SPEC_DICT, "assemble": {**SPEC_DICT["assemble"], "fields": [
        *SPEC_DICT["assemble"]["fields"][:2],
        {"topic": "arm/gripper", "type": "std_msgs/msg/Float64MultiArray", "field": "data"}]}}
    with pytest.raises(TopicTypeError, match="/lab/arm/gripper"):
        read_episodes(lab_bag[0], spec=ReaderSpec.from_dict(data))


def test_bad_field_and_both_keys_are_one_line() -> None:
    data = {**SPEC_DICT, "assemble": {**SPEC_DICT["assemble"], "fields": [
        {"topic": "arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "positon"}]}}
    with pytest.raises(ReaderSpecError, match=r"assemble: fields\[0\].*'arm/joint_states'.*positon"):
        ReaderSpec.from_dict(data)
    with pytest.raises(ReaderSpecError, match="not both"):
        ReaderSpec.from_dict({**SPEC_DICT, "observation": "arm/joint_states"})
    with pytest.raises(ReaderSpecError, match="stamp: log"):
        ReaderSpec.from_dict({**SPEC_DICT, "stamp": "header"})


def test_float64_action_wrong_length_is_named(tmp_path: Path) -> None:
    path = tmp_path / "bag"
    with Writer(path, version=9, storage_plugin=storage_plugin("mcap")) as w:
        js = w.add_connection("/r/js", "sensor_msgs/msg/JointState", typestore=m.typestore())
        cmd = w.add_connection("/r/cmd", "std_msgs/msg/Float64MultiArray", typestore=m.typestore())
        for k in range(4):
            t = 10**9 + k * 40 * MS
            w.write(js, t, m.serialize(m.joint_state(t, JOINTS, np.zeros(3), np.zeros(3))))
            w.write(cmd, t + MS, f64(np.zeros(3 if k != 2 else 4)))
    spec = ReaderSpec.from_dict({"observation": {"topic": "/r/js", "type": "sensor_msgs/msg/JointState"},
                                 "action": {"topic": "/r/cmd", "type": "std_msgs/msg/Float64MultiArray"},
                                 "split": "gaps"})
    with pytest.raises(Exception, match=r"/r/cmd.*#2|#2.*/r/cmd") as err:
        read_episodes(path, spec=spec)
    assert type(err.value).__name__ == "VectorLengthError"
