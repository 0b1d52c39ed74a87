"""Any message type from the bag's own definitions (or a .msg folder), read by field path, and topics
recorded under two types; each bag written as another lab would (test/type_corpus.py), read back value
for value."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import type_corpus as tc
from compat_corpus import edit_metadata, old_metadata, old_sqlite_schema, storage_file

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.errors import LabelError, ReaderSpecError, TopicTypeError, UnknownTypeError

LENGTHS = [6, 9, 7]


@pytest.fixture(autouse=True)
def _fresh_types() -> Iterator[None]:
    """Each test learns the lab's types itself (from its bag or its .msg folder)."""
    tc.forget_lab_types()
    yield
    tc.forget_lab_types()


@pytest.fixture(scope="module")
def store() -> Any:
    return tc.lab_typestore()


def _spec(command: tc.Command, **extra: Any) -> ReaderSpec:
    return ReaderSpec.from_dict(
        {
            "observation": {"topic": tc.STATE, "type": tc.ARM_STATE, "field": "positions"},
            "action": {"topic": tc.CMD, "type": command.msgtype, "field": command.path},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
            "time_gap": 0.5,
            **extra,
        }
    )


@pytest.mark.parametrize("name", sorted(tc.COMMANDS))
@pytest.mark.parametrize(
    "storage,version", [("mcap", 9), ("sqlite3", 9), ("sqlite3", 8), ("mcap", 6), ("sqlite3", 5)]
)
def test_custom_state_and_command_types_read_from_the_bags_definitions(
    tmp_path: Path, store: Any, name: str, storage: str, version: int
) -> None:
    command = tc.COMMANDS[name]
    demo = tc.demos(store, command, LENGTHS)
    bag = tc.write_rosbags(
        tmp_path / "bag", store, demo, storage=storage, version=version if version >= 8 else 9
    )
    if version < 8:  # metadata.yaml as older rosbag2 wrote it (the storage keeps its definitions)
        edit_metadata(bag, lambda info: old_metadata(info, version))
    tc.check(read_episodes(bag, spec=_spec(command)).episodes, demo)


@pytest.mark.parametrize("name", ["joint_trajectory", "servo_jog"])
def test_foxglove_mcap_with_embedded_schemas(tmp_path: Path, store: Any, name: str) -> None:
    command = tc.COMMANDS[name]
    demo = tc.demos(store, command, LENGTHS, seed=3)
    bag = tc.write_foxglove(tmp_path / "robot.mcap", store, demo)
    tc.check(read_episodes(bag, spec=_spec(command)).episodes, demo)


def test_bag_without_definitions_needs_the_msg_folder(tmp_path: Path, store: Any) -> None:
    command = tc.COMMANDS["joint_trajectory"]
    demo = tc.demos(store, command, LENGTHS, seed=5)
    bag = tc.write_rosbags(tmp_path / "bag", store, demo, storage="sqlite3")
    edit_metadata(bag, lambda info: old_metadata(info, 5))
    old_sqlite_schema(storage_file(bag), 3)  # a Humble-era schema: no message_definitions table
    with pytest.raises(UnknownTypeError) as err:
        read_episodes(bag, spec=_spec(command))
    line = str(err.value)
    assert tc.ARM_STATE in line and "`types: DIR`" in line and "\n" not in line
    folder = tc.write_msg_folder(tmp_path / "src")
    tc.check(read_episodes(bag, spec=_spec(command, types=[str(folder)])).episodes, demo)


def test_header_stamp_of_a_custom_type_is_the_clock(tmp_path: Path, store: Any) -> None:
    """The recording PC logs every message 1 ms apart (no gap between demonstrations); the robot's
    header stamps keep the 2 s gaps: ``stamps: header`` on the custom state and the TwistStamped command
    splits at them, the log clock cannot."""
    command = tc.COMMANDS["servo_twist"]
    demo = tc.demos(store, command, LENGTHS, seed=7)
    demo.messages = [(10**9 + k * 1_000_000, *rest) for k, (_, *rest) in enumerate(demo.messages)]
    bag = tc.write_rosbags(tmp_path / "bag", store, demo)
    header = _spec(command, stamps={tc.STATE: "header", tc.CMD: "header"}, tolerance=0.01)
    tc.check(read_episodes(bag, spec=header).episodes, demo)
    assert len(read_episodes(bag, spec=_spec(command)).episodes) == 1


def test_assembled_observation_takes_nested_fields(tmp_path: Path, store: Any) -> None:
    command = tc.COMMANDS["servo_twist"]
    demo = tc.demos(store, command, LENGTHS, seed=11)
    bag = tc.write_rosbags(tmp_path / "bag", store, demo)
    spec = ReaderSpec.from_dict(
        {
            "assemble": {
                "step_topic": tc.STATE,
                "stamp": "receive",
                "fields": [
                    {"topic": tc.STATE, "type": tc.ARM_STATE, "field": "positions"},
                    {"topic": tc.STATE, "type": tc.ARM_STATE, "field": "gripper.width"},
                ],
            },
            "action": {"topic": tc.CMD, "type": command.msgtype, "field": command.path},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
            "time_gap": 0.5,
        }
    )
    result = read_episodes(bag, spec=spec)
    tc.check(result.episodes, demo, gripper=True)
    names = result.episodes[0].extras["obs_names"]
    assert list(names) == [
        "arm/state/positions/0",
        "arm/state/positions/1",
        "arm/state/positions/2",
        "arm/state/gripper.width/width",
    ]


@pytest.mark.parametrize(
    "path,words",
    [
        ("positons", ["has no field 'positons'", "positions", "gripper"]),
        ("gripper.width.x", ["gripper.width is not a message"]),
        ("joint_names", ["string[]", "not a number"]),
    ],
)
def test_a_wrong_path_names_type_path_and_fields(
    tmp_path: Path, store: Any, path: str, words: list[str]
) -> None:
    command = tc.COMMANDS["forward_command"]
    bag = tc.write_rosbags(tmp_path / "bag", store, tc.demos(store, command, LENGTHS))
    spec = ReaderSpec.from_dict(
        {
            "observation": {"topic": tc.STATE, "type": tc.ARM_STATE, "field": path},
            "action": {"topic": tc.CMD, "type": command.msgtype},
            "subtask": None,
            "sketch": None,
            "episode": None,
        }
    )
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=spec)
    assert tc.ARM_STATE in str(err.value) and all(w in str(err.value) for w in words), str(err.value)


def test_a_type_without_a_path_names_the_key() -> None:
    with pytest.raises(ReaderSpecError, match="needs a field path"):
        ReaderSpec.from_dict({"observation": {"topic": "/s", "type": tc.ARM_STATE}})


# --- one topic under two types (a split bag where the command changed type) ------------------------------
def _two_type_bag(tmp_path: Path, first: str, second: str) -> tuple[Path, list[np.ndarray], list[np.ndarray]]:
    """One mcap where ``/arm/cmd`` is ``first`` for the first demonstration and ``second`` after, as a
    split bag whose command changed type reads; returns (bag, observations, actions)."""
    from rosbags.rosbag2 import Writer

    from ompn_ros.data import messages as m

    store = m.typestore()
    rng = np.random.default_rng(2)
    obs_all, act_all, t = [], [], 10**9
    with Writer(tmp_path / "bag", version=9) as writer:
        state = writer.add_connection(tc.STATE, "std_msgs/msg/Float32MultiArray", typestore=store)
        cmds = {ty: writer.add_connection(tc.CMD, ty, typestore=store) for ty in (first, second)}
        for k, steps in enumerate(LENGTHS):
            msgtype = first if k == 0 else second
            obs = rng.standard_normal((steps + 1, 2)).astype(np.float32)
            act = np.round(rng.standard_normal((steps, 3)), 2)
            act[0] = [1.0, 2.0, 0.0]
            for i in range(steps + 1):
                stamp = t + i * tc.STEP_NS
                writer.write(state, stamp, m.serialize(m.float32_array(obs[i], "s")))
                if i < steps:
                    writer.write(cmds[msgtype], stamp + 2_000_000, _array(store, msgtype, act[i]))
            obs_all.append(obs)
            act_all.append(act.astype(np.float32))
            t += steps * tc.STEP_NS + tc.GAP_NS
    return tmp_path / "bag", obs_all, act_all


def _array(store: Any, msgtype: str, values: np.ndarray) -> bytes:
    """A command of ``msgtype``; MultiArrays carry a 1-D layout labelled 'joint' (as a driver that
    names its dimension), which puts a Float64MultiArray's data where a Float32MultiArray's would be."""
    dim = store.types["std_msgs/msg/MultiArrayDimension"](label="joint", size=3, stride=3)
    layout = store.types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)
    if msgtype == "sensor_msgs/msg/JointState":
        msg = store.types[msgtype](
            header=tc._header(store, 1),
            name=list(tc.JOINTS),
            position=values,
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
    else:
        dtype = np.float32 if "32" in msgtype else np.float64
        msg = store.types[msgtype](layout=layout, data=values.astype(dtype))
    return bytes(store.serialize_cdr(msg, msgtype))


def test_float64_then_float32_commands_are_decoded_per_connection(tmp_path: Path) -> None:
    bag, obs, act = _two_type_bag(
        tmp_path, "std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray"
    )
    spec = ReaderSpec.from_dict(
        {
            "observation": {"topic": tc.STATE, "type": "std_msgs/msg/Float32MultiArray"},
            "action": {"topic": tc.CMD, "type": None},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
        }
    )
    got = read_episodes(bag, spec=spec).episodes
    assert len(got) == len(LENGTHS)
    for ep, o, a in zip(got, obs, act):
        np.testing.assert_array_equal(ep.observations, o)
        np.testing.assert_array_equal(ep.actions, a)
    np.testing.assert_array_equal(got[1].actions[0], [1.0, 2.0, 0.0])  # not [0.0, 1.875, 0.0]


def test_a_spec_type_that_fits_one_connection_names_both_and_the_change(tmp_path: Path) -> None:
    bag, _, _ = _two_type_bag(tmp_path, "sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray")
    spec = ReaderSpec.from_dict(
        {
            "observation": {"topic": tc.STATE, "type": "std_msgs/msg/Float32MultiArray"},
            "action": {"topic": tc.CMD, "type": "sensor_msgs/msg/JointState"},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
        }
    )
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=spec)
    line = str(err.value)
    assert "sensor_msgs/msg/JointState" in line and "std_msgs/msg/Float64MultiArray" in line, line
    first_change = LENGTHS[0]  # the first command of the second demonstration
    assert f"message #{first_change}" in line and "\n" not in line, line


def test_string_labels_by_field_path_are_names_turned_into_ids(tmp_path: Path, store: Any) -> None:
    command = tc.COMMANDS["forward_command"]
    demo = tc.demos(store, command, LENGTHS, seed=13)
    string = store.types["std_msgs/msg/String"]
    skills: list[tuple[int, str, str, Any]] = []
    names: list[str] = []
    for stamp, topic, _, _ in list(demo.messages):
        if topic == tc.STATE:
            k = len(names)
            names.append("reach" if k % 10 < 4 else "grasp")
            skills.append((stamp + 500_000, "/arm/skill", "std_msgs/msg/String", string(data=names[-1])))
    demo.messages = sorted(demo.messages + skills, key=lambda x: x[0])
    bag = tc.write_rosbags(tmp_path / "bag", store, demo)
    spec = _spec(
        command, subtask={"topic": "/arm/skill", "type": "std_msgs/msg/String", "field": "data"}, labels="id"
    )
    result = read_episodes(bag, spec=spec)
    tc.check(result.episodes, demo)
    start = 0
    for ep in result.episodes:
        want = np.asarray([0 if n == "reach" else 1 for n in names[start : start + ep.length + 1]])
        np.testing.assert_array_equal(ep.extras["subtask_id"][: ep.length], want[: ep.length])
        start += ep.length + 1
    assert any("'reach': 0" in note and "'grasp': 1" in note for note in result.report.bags[0].notes)
    with pytest.raises(LabelError, match=r"holds names .*set labels: id"):
        read_episodes(
            bag,
            spec=_spec(
                command,
                subtask={"topic": "/arm/skill", "type": "std_msgs/msg/String", "field": "data"},
                labels="ordinal",
            ),
        )


CONFIG = Path(__file__).resolve().parents[2] / "config"


@pytest.mark.parametrize(
    "name", ["reader_joint_trajectory", "reader_moveit_servo", "reader_custom_arm", "reader_ur_style"]
)
def test_example_specs_load(name: str) -> None:
    spec = ReaderSpec.from_yaml(CONFIG / f"{name}.yaml")
    assert spec.action.field is not None


def test_the_custom_arm_example_reads_a_labs_bag(tmp_path: Path, store: Any) -> None:
    command = tc.COMMANDS["joint_trajectory"]
    demo = tc.demos(store, command, LENGTHS, seed=17)
    string = store.types["std_msgs/msg/String"]
    demo.messages = sorted(
        demo.messages
        + [
            (s + 500_000, "/arm/skill", "std_msgs/msg/String", string(data="reach"))
            for s, t, _, _ in demo.messages
            if t == tc.STATE
        ],
        key=lambda x: x[0],
    )
    bag = tc.write_rosbags(tmp_path / "bag", store, demo, storage="sqlite3")
    result = read_episodes(bag, spec=ReaderSpec.from_yaml(CONFIG / "reader_custom_arm.yaml"))
    tc.check(result.episodes, demo, gripper=True)


def test_an_assembled_topic_under_two_types_names_both(tmp_path: Path) -> None:
    """Only where the assemble block cannot read one of the types (JointState has no ``data``); two
    types it reads are decoded per connection (test_bag_two_types)."""
    bag, _, _ = _two_type_bag(tmp_path, "sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray")
    spec = ReaderSpec.from_dict({
        "assemble": {"step_topic": tc.STATE, "stamp": "receive", "tolerance_s": 0.5, "fields": [
            {"topic": tc.STATE, "type": "std_msgs/msg/Float32MultiArray", "field": "data"},
            {"topic": tc.CMD, "type": "std_msgs/msg/Float64MultiArray", "field": "data"}]},
        "action": {"topic": tc.CMD, "type": None}, "subtask": None, "sketch": None, "episode": None,
        "split": "gaps"})
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=spec)
    line = str(err.value)
    assert "JointState to std_msgs/msg/Float64MultiArray" in line, line
    assert f"message #{LENGTHS[0]}" in line, line


def test_a_ros2idl_schema_of_a_custom_type(tmp_path: Path, store: Any) -> None:
    command = tc.COMMANDS["servo_jog"]
    demo = tc.demos(store, command, LENGTHS, seed=19)
    bag = tc.write_idl_mcap(tmp_path / "robot.mcap", store, demo)
    tc.check(read_episodes(bag, spec=_spec(command)).episodes, demo)


def test_two_bags_defining_one_type_differently_are_refused(tmp_path: Path, store: Any) -> None:
    """Two labs' ``my_robot_msgs/msg/GripperState`` in one run: never one read as the other."""
    command = tc.COMMANDS["forward_command"]
    demo = tc.demos(store, command, LENGTHS)
    tc.check(read_episodes(tc.write_rosbags(tmp_path / "a", store, demo), spec=_spec(command)).episodes, demo)
    other = tc.lab_typestore(gripper="float32 width\nfloat64 force\nbool grasped\n")
    bag = tc.write_rosbags(tmp_path / "b", other, tc.demos(other, command, LENGTHS))
    with pytest.raises(UnknownTypeError) as err:
        read_episodes(bag, spec=_spec(command))
    assert tc.GRIPPER_STATE in str(err.value) and "separate runs" in str(err.value), str(err.value)


def test_a_label_topic_under_two_types_is_read_per_connection(tmp_path: Path) -> None:
    """Skill ids published as Int32, then (after a driver update) as Int64 with values past 2**32."""
    from rosbags.rosbag2 import Writer

    from ompn_ros.data import messages as m

    store = m.typestore()
    rng = np.random.default_rng(4)
    t, want = 10**9, []
    with Writer(tmp_path / "bag", version=9) as writer:
        state = writer.add_connection(tc.STATE, "std_msgs/msg/Float32MultiArray", typestore=store)
        cmd = writer.add_connection(tc.CMD, "std_msgs/msg/Float32MultiArray", typestore=store)
        skills = {ty: writer.add_connection("/arm/skill", ty, typestore=store)
                  for ty in ("std_msgs/msg/Int32", "std_msgs/msg/Int64")}
        for k, steps in enumerate(LENGTHS):
            msgtype = "std_msgs/msg/Int32" if k == 0 else "std_msgs/msg/Int64"
            ids = [7 + k * 2**33 if i < 3 else 9 for i in range(steps)] if k else [4] * 3 + [5] * (steps - 3)
            want.append(ids)
            for i in range(steps + 1):
                stamp = t + i * tc.STEP_NS
                writer.write(state, stamp, m.serialize(m.float32_array(rng.standard_normal(2), "s")))
                if i < steps:
                    command = m.serialize(m.float32_array(rng.standard_normal(2), "c"))
                    writer.write(cmd, stamp + 2_000_000, command)
                    label = bytes(store.serialize_cdr(store.types[msgtype](data=ids[i]), msgtype))
                    writer.write(skills[msgtype], stamp + 1_000_000, label)
            t += steps * tc.STEP_NS + tc.GAP_NS
    spec = ReaderSpec.from_dict({
        "observation": {"topic": tc.STATE, "type": "std_msgs/msg/Float32MultiArray"},
        "action": {"topic": tc.CMD, "type": "std_msgs/msg/Float32MultiArray"},
        "subtask": {"topic": "/arm/skill", "type": None, "field": "data"}, "labels": "id",
        "sketch": None, "episode": None, "split": "gaps"})
    got = read_episodes(tmp_path / "bag", spec=spec).episodes
    assert [list(ep.extras["subtask_id"][:ep.length]) for ep in got] == want
