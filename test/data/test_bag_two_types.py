"""Topics recorded under two types in a split bag (one part of the recording publishes another type
on the same topic), for every role the reader gives a topic: episode markers, a recording switch, an
assembled observation's partner, the sketch and the joint states.  Each message is decoded with its own
type; where the spec cannot take one of the types, one line names both and where the change happens.

The bags are written as another lab's tools write them: each part by ``rosbags`` with its own
typestore (mcap and sqlite3), renamed to rosbag2's split files ``<dir>_<n>.<ext>`` beside one
metadata.yaml listing the topic under both types, as ``ros2 bag record --max-bag-duration`` leaves it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from compat_corpus import ACT_DIM, CMD, GAP_NS, OBS_DIM, STATE, STEP_NS, Demo, check_episodes, demos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import TopicTypeError

TS = get_typestore(Stores.ROS2_JAZZY)  # the lab's own typestore, not this package's codec
LENGTHS = [6, 9, 7]
F32, F64 = layout.FLOAT32_ARRAY, layout.FLOAT64_ARRAY
Message = tuple[int, str, str, bytes]  # log stamp, topic, type, CDR


def _cdr(msgtype: str, **fields: Any) -> bytes:
    return bytes(TS.serialize_cdr(TS.types[msgtype](**fields), msgtype))


def _multiarray(msgtype: str, values: np.ndarray) -> bytes:
    """A MultiArray with a labelled 1-D layout (as a driver that names its dimension)."""
    dim = TS.types["std_msgs/msg/MultiArrayDimension"](label="joint", size=len(values), stride=len(values))
    shape = TS.types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)
    dtype = {F32: np.float32, F64: np.float64, "std_msgs/msg/Int32MultiArray": np.int32,
             "std_msgs/msg/Int64MultiArray": np.int64}[msgtype]
    return _cdr(msgtype, layout=shape, data=np.asarray(values, dtype=dtype))


def _joint_state(ns: int, position: np.ndarray) -> bytes:
    stamp = TS.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    header = TS.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
    return _cdr(layout.JOINT_STATE, header=header, name=[f"j{i}" for i in range(len(position))],
                position=np.asarray(position, np.float64), velocity=np.zeros(0), effort=np.zeros(0))


def _lab(demo: Demo) -> list[Message]:
    """The lab robot's state and command messages of ``demo`` (``Float32MultiArray``)."""
    return [(stamp, topic, F32, raw) for stamp, topic, raw in demo.messages]


def _starts(demo: Demo) -> list[int]:
    """The stamp of each demonstration's first state."""
    states = sorted(stamp for stamp, topic, _ in demo.messages if topic == STATE)
    out, k = [], 0
    for obs in demo.observations:
        out.append(states[k])
        k += len(obs)
    return out


def write_split(path: Path, messages: list[Message], cut: int, storage: str) -> Path:
    """``messages`` as a split bag of two files, the second from stamp ``cut`` on; each part written by
    ``rosbags`` with the connections of its own messages, one metadata.yaml over both."""
    path.mkdir()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    infos, files = [], []
    for k, part in enumerate(([x for x in messages if x[0] < cut], [x for x in messages if x[0] >= cut])):
        tmp = path.parent / f".{path.name}_part{k}"
        with Writer(tmp, version=9, storage_plugin=plugin) as writer:  # type: ignore[arg-type]
            conns: dict[tuple[str, str], Any] = {}
            for stamp, topic, msgtype, raw in sorted(part, key=lambda x: x[0]):
                if (topic, msgtype) not in conns:
                    conns[topic, msgtype] = writer.add_connection(topic, msgtype, typestore=TS)
                writer.write(conns[topic, msgtype], stamp, raw)
        (file,) = [p for p in tmp.iterdir() if p.suffix in (".mcap", ".db3")]
        files.append(file.rename(path / f"{path.name}_{k}{file.suffix}"))
        infos.append(yaml.safe_load((tmp / "metadata.yaml").read_text())["rosbag2_bagfile_information"])
    info = infos[0]
    info["relative_file_paths"] = [f.name for f in files]
    info["files"] = [dict(i["files"][0], path=f.name) for i, f in zip(infos, files)]
    info["message_count"] = sum(i["message_count"] for i in infos)
    end = max(i["starting_time"]["nanoseconds_since_epoch"] + i["duration"]["nanoseconds"] for i in infos)
    info["duration"]["nanoseconds"] = end - info["starting_time"]["nanoseconds_since_epoch"]
    topics: dict[tuple[str, str], dict[str, Any]] = {}
    for i in infos:
        for entry in i["topics_with_message_count"]:
            meta = entry["topic_metadata"]
            key = (meta["name"], meta["type"])
            if key in topics:
                topics[key]["message_count"] += entry["message_count"]
            else:
                topics[key] = dict(entry)
    info["topics_with_message_count"] = list(topics.values())
    (path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return path


def _spec(**extra: Any) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "observation": {"topic": STATE, "type": F32, "dim": OBS_DIM},
        "action": {"topic": CMD, "type": F32, "dim": ACT_DIM},
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5, **extra})


def _cut(demo: Demo) -> int:
    """Between the first and the second demonstration (where the second file starts)."""
    return _starts(demo)[1] - GAP_NS // 2


STORAGES = ["mcap", "sqlite3"]


@pytest.mark.parametrize("storage", STORAGES)
def test_markers_of_both_forms_on_one_topic(tmp_path: Path, storage: str) -> None:
    """The first file's markers are the string-keyed DiagnosticArray, the second's the typed marker
    (a recorder upgraded between the two files): every demonstration is cut by its own markers (was:
    the typed markers decoded as DiagnosticArray, a corrupt bag)."""
    m.register_interfaces(TS)  # the writer's store learns the marker from its .msg file
    demo = demos(LENGTHS, seed=21)
    cut, messages = _cut(demo), _lab(demo)
    for k, (start, obs) in enumerate(zip(_starts(demo), demo.observations)):
        end = start + (len(obs) - 1) * STEP_NS + 5_000_000
        for kind, stamp, values in (("start", start - 5_000_000, {"episode": k}),
                                    ("end", end, {"episode": k, "steps": len(obs) - 1})):
            if stamp < cut:
                raw = m.serialize(m.episode_marker(kind, stamp, values))
                messages.append((stamp, "/lab/episode", layout.DIAGNOSTIC_ARRAY, raw))
            else:
                raw = m.encode_typed_marker(kind, stamp, values)
                messages.append((stamp, "/lab/episode", layout.EPISODE_MARKER_TYPE, raw))
    bag = write_split(tmp_path / "bag", messages, cut, storage)
    result = read_episodes(bag, spec=_spec(episode="/lab/episode", split="markers"))
    check_episodes(result.episodes, demo)
    assert not result.report.bags[0].dropped and result.report.bags[0].error is None


@pytest.mark.parametrize("storage", STORAGES)
def test_a_recording_switch_that_changes_type(tmp_path: Path, storage: str) -> None:
    """``std_msgs/Bool`` on/off in the first file, ``std_msgs/String`` 'start'/'stop' in the second:
    each read by its own type (was: the strings decoded as Bool, every message 'on': the steps made
    while recording was off became a fourth demonstration)."""
    demo = demos(LENGTHS, seed=22)
    cut, messages = _cut(demo), _lab(demo)
    for start, obs in zip(_starts(demo), demo.observations):
        for on, stamp in ((True, start - 5_000_000), (False, start + (len(obs) - 1) * STEP_NS + 5_000_000)):
            if stamp < cut:
                raw = _cdr("std_msgs/msg/Bool", data=on)
                messages.append((stamp, "/lab/recording", "std_msgs/msg/Bool", raw))
            else:
                word = "start" if on else "stop"
                messages.append((stamp, "/lab/recording", "std_msgs/msg/String",
                                 _cdr("std_msgs/msg/String", data=word)))
    # the operator moves the robot back while recording is off: states and commands of no demonstration
    for i in range(4):
        idle = _starts(demo)[2] - GAP_NS // 2 + i * STEP_NS
        state = m.serialize(m.float32_array(np.full(OBS_DIM, 9.0, np.float32), "s"))
        messages.append((idle, STATE, F32, state))
        messages.append((idle + 2_000_000, CMD, F32,
                         m.serialize(m.float32_array(np.full(ACT_DIM, 9.0, np.float32), "c"))))
    bag = write_split(tmp_path / "bag", messages, cut, storage)
    spec = _spec(split="topic", split_topic="/lab/recording")
    check_episodes(read_episodes(bag, spec=spec).episodes, demo)


def _gripper_bag(tmp_path: Path, storage: str, first: str,
                 second: str) -> tuple[Path, Demo, list[np.ndarray]]:
    """The lab robot with a gripper topic published 1 ms before each state: ``first`` in the first
    file, ``second`` in the second; returns (bag, demo, the gripper values of each demonstration)."""
    demo = demos(LENGTHS, seed=23)
    cut, messages = _cut(demo), _lab(demo)
    rng = np.random.default_rng(5)
    grips: list[np.ndarray] = []
    for start, obs in zip(_starts(demo), demo.observations):
        grip = np.round(rng.standard_normal((len(obs), 2)), 3)
        grip[0] = [1.0, 2.0]  # as Float64 bytes read as Float32: [0.0, 1.875]
        grips.append(grip.astype(np.float32))
        for i, values in enumerate(grip):
            stamp = start + i * STEP_NS - 1_000_000
            msgtype = first if stamp < cut else second
            joints = msgtype == layout.JOINT_STATE
            raw = _joint_state(stamp, values) if joints else _multiarray(msgtype, values)
            messages.append((stamp, "/lab/gripper", msgtype, raw))
    return write_split(tmp_path / "bag", messages, cut, storage), demo, grips


def _assemble(grip_type: str) -> ReaderSpec:
    return ReaderSpec.from_dict({
        "assemble": {"step_topic": STATE, "stamp": "receive", "tolerance_s": 0.01, "fields": [
            {"topic": STATE, "type": F32, "field": "data", "size": OBS_DIM},
            {"topic": "/lab/gripper", "type": grip_type, "field": "data", "size": 2}]},
        "action": {"topic": CMD, "type": F32, "dim": ACT_DIM},
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5})


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("first,second", [(F64, F32), (F32, F64)])
def test_an_assembled_partner_under_two_types_is_read_per_connection(
        tmp_path: Path, storage: str, first: str, second: str) -> None:
    """A gripper topic that is Float64MultiArray in one file and Float32MultiArray in the other, in an
    assembled observation whose spec names either type: every row is the state and the gripper as
    written (was: refused)."""
    bag, demo, grips = _gripper_bag(tmp_path, storage, first, second)
    result = read_episodes(bag, spec=_assemble(first))
    assert len(result.episodes) == len(LENGTHS)
    for ep, obs, act, grip in zip(result.episodes, demo.observations, demo.actions, grips):
        np.testing.assert_array_equal(ep.observations, np.hstack([obs, grip]))
        np.testing.assert_array_equal(ep.actions, act)
    assert result.episodes[1].observations[0, OBS_DIM:].tolist() == [1.0, 2.0]


@pytest.mark.parametrize("storage", STORAGES)
def test_an_assembled_partner_the_spec_cannot_read_names_both_types(tmp_path: Path, storage: str) -> None:
    """JointState, then Float64MultiArray: the spec's ``data`` field exists in one type only."""
    bag, demo, _ = _gripper_bag(tmp_path, storage, layout.JOINT_STATE, F64)
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=_assemble(F64))
    line = str(err.value)
    assert "changes type from sensor_msgs/msg/JointState to std_msgs/msg/Float64MultiArray" in line, line
    assert f"message #{len(demo.observations[0])}" in line and "'/lab/gripper'" in line, line
    assert "\n" not in line and "data" in line, line


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("role,first,second", [
    ("sketch", "std_msgs/msg/Int32MultiArray", "std_msgs/msg/Int64MultiArray"),
    ("joint_states", layout.JOINT_STATE, F64),
])
def test_a_fixed_type_role_under_two_types_names_both(
        tmp_path: Path, storage: str, role: str, first: str, second: str) -> None:
    """The sketch and the joint states have one type each: a topic that changes type is refused in
    one line naming both types and the message where it changes (was: the second type's bytes read as
    the first's, or called a corrupt bag)."""
    demo = demos(LENGTHS, seed=24)
    cut, messages = _cut(demo), _lab(demo)
    topic = f"/lab/{role}"
    for start in _starts(demo):
        msgtype = first if start < cut else second
        if msgtype == layout.JOINT_STATE:
            raw = _joint_state(start, np.array([0.5, 1.5]))
        else:
            raw = _multiarray(msgtype, np.array([1, 2, 3]))
        messages.append((start - 3_000_000, topic, msgtype, raw))
    bag = write_split(tmp_path / "bag", messages, cut, storage)
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=_spec(**{role: topic}))
    line = str(err.value)
    assert f"changes type from {first} to {second} at message #1" in line, line
    assert f"'{topic}'" in line and "\n" not in line, line


ARM_V1, ARM_V2 = "lab_msgs/msg/ArmState", "lab_msgs/msg/ArmStateV2"
ARM_DEFS = {ARM_V1: "std_msgs/Header header\nfloat64[] positions\n",
            ARM_V2: "std_msgs/Header header\nstring mode\nfloat64[] positions\n"}


def _header(ns: int) -> Any:
    stamp = TS.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return TS.types["std_msgs/msg/Header"](stamp=stamp, frame_id="base")


@pytest.mark.parametrize("storage", STORAGES)
def test_header_clock_of_a_custom_state_that_changes_type(tmp_path: Path, storage: str) -> None:
    """A lab's own state message, version 1 in the first file and version 2 (a new field before the
    positions) in the second, read with ``stamps: header``: each message's header by its own type.
    The recording PC logs every message 1 ms apart, so only the robot's header stamps keep the 2 s
    between demonstrations (was: refused, naming only the first type, as having no header stamp)."""
    from rosbags.typesys import get_types_from_msg

    for name, text in ARM_DEFS.items():
        TS.register(get_types_from_msg(text, name))
    rng = np.random.default_rng(6)
    robot: list[Message] = []  # robot stamp, topic, type, CDR
    want_obs: list[np.ndarray] = []
    want_act: list[np.ndarray] = []
    t = 5 * 10**9
    for k, steps in enumerate(LENGTHS):
        obs = np.round(rng.standard_normal((steps + 1, 2)), 3)
        act = np.round(rng.standard_normal((steps, 3)), 3)
        arm = ARM_V1 if k == 0 else ARM_V2
        for i in range(steps + 1):
            ns = t + i * STEP_NS
            extra = {} if arm == ARM_V1 else {"mode": "teleop"}
            robot.append((ns, "/lab/arm", arm, _cdr(arm, header=_header(ns), positions=obs[i], **extra)))
            if i < steps:
                twist = TS.types["geometry_msgs/msg/Twist"](
                    linear=TS.types["geometry_msgs/msg/Vector3"](x=act[i, 0], y=act[i, 1], z=act[i, 2]),
                    angular=TS.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
                raw = _cdr("geometry_msgs/msg/TwistStamped", header=_header(ns + 2_000_000), twist=twist)
                robot.append((ns + 2_000_000, "/lab/cmd", "geometry_msgs/msg/TwistStamped", raw))
        want_obs.append(obs.astype(np.float32))
        want_act.append(act.astype(np.float32))
        t += steps * STEP_NS + GAP_NS
    robot.sort(key=lambda x: x[0])
    logged: list[Message] = [(10**9 + n * 1_000_000, topic, msgtype, raw)
                             for n, (_, topic, msgtype, raw) in enumerate(robot)]
    cut = next(log for log, _, msgtype, _ in logged if msgtype == ARM_V2)
    bag = write_split(tmp_path / "bag", logged, cut, storage)
    spec = ReaderSpec.from_dict({
        "observation": {"topic": "/lab/arm", "type": None, "field": "positions"},
        "action": {"topic": "/lab/cmd", "type": "geometry_msgs/msg/TwistStamped", "field": "twist.linear"},
        "stamps": {"/lab/arm": "header", "/lab/cmd": "header"}, "tolerance": 0.01,
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5})
    got = read_episodes(bag, spec=spec).episodes
    assert len(got) == len(LENGTHS), [ep.length for ep in got]
    for ep, o, a in zip(got, want_obs, want_act):
        np.testing.assert_array_equal(ep.observations, o)
        np.testing.assert_array_equal(ep.actions, a)


@pytest.mark.parametrize("storage", STORAGES)
def test_an_assembled_step_topic_under_two_types(tmp_path: Path, storage: str) -> None:
    """The step topic itself changes type (the state driver publishes Float64MultiArray from the
    second file on): every step is read by its own type (was: refused)."""
    demo = demos(LENGTHS, seed=25)
    cut = _cut(demo)
    messages: list[Message] = []
    k = 0
    states = np.concatenate(demo.observations)
    for stamp, topic, raw in demo.messages:
        if topic == STATE:
            if stamp >= cut:
                raw = _multiarray(F64, states[k].astype(np.float64))
            messages.append((stamp, topic, F32 if stamp < cut else F64, raw))
            k += 1
        else:
            messages.append((stamp, topic, F32, raw))
    bag = write_split(tmp_path / "bag", messages, cut, storage)
    spec = ReaderSpec.from_dict({
        "assemble": {"step_topic": STATE, "stamp": "receive", "fields": [
            {"topic": STATE, "type": F32, "field": "data", "size": OBS_DIM}]},
        "action": {"topic": CMD, "type": F32, "dim": ACT_DIM},
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5})
    check_episodes(read_episodes(bag, spec=spec).episodes, demo)


def test_the_assembler_reads_a_declared_second_type_and_keeps_the_pinned_size() -> None:
    """``ObservationAssembler.for_type``: a partner's Float64MultiArray message gives the field of a
    Float32MultiArray spec; its size is held to the one the first message pinned; a type without the
    field is refused naming it; an undeclared type is a bug (ValueError)."""
    from ompn_ros.data.errors import ObservationSpecError
    from ompn_ros.data.obs import Drop, FieldSpec, ObservationAssembler, ObservationSpec

    spec = ObservationSpec(STATE, (FieldSpec(STATE, F32, "data"), FieldSpec("/lab/grip", F32, "data")),
                           stamp="receive", tolerance_s=1.0)
    asm = ObservationAssembler(spec)
    asm.for_type("/lab/grip", F64)
    state = m.serialize(m.float32_array(np.array([1.0, 2.0], np.float32), "s"))
    grip = m.serialize(m.float32_array(np.array([0.5, 0.25], np.float32), "g"))
    assert asm.offer("/lab/grip", 1, grip) is None
    assert np.asarray(asm.step(2, state)).tolist() == [1.0, 2.0, 0.5, 0.25]
    assert asm.offer("/lab/grip", 3, _multiarray(F64, np.array([1.0, 2.0])), F64) is None
    row = asm.step(4, state)
    assert np.asarray(row).tolist() == [1.0, 2.0, 1.0, 2.0]  # not [0.0, 1.875] (Float64 read as Float32)
    rejected = asm.offer("/lab/grip", 5, _multiarray(F64, np.array([1.0, 2.0, 3.0])), F64)
    assert isinstance(rejected, Drop) and rejected.reason == "wrong_size"
    with pytest.raises(ObservationSpecError, match=r"JointState.*data"):
        asm.for_type("/lab/grip", layout.JOINT_STATE)
    with pytest.raises(ValueError, match="Int32"):
        asm.offer("/lab/grip", 6, b"", "std_msgs/msg/Int32")


@pytest.mark.parametrize("storage", STORAGES)
def test_a_switch_then_start_events_on_one_topic_is_refused(tmp_path: Path, storage: str) -> None:
    """``Bool`` on/off in the first file, ``std_msgs/Header`` start events in the second: neither rule
    reads both, so one line names the two types and the change (was: the headers read as Bool)."""
    demo = demos(LENGTHS, seed=26)
    cut, messages = _cut(demo), _lab(demo)
    for start in _starts(demo):
        if start < cut:
            messages.append((start - 5_000_000, "/lab/recording", "std_msgs/msg/Bool",
                             _cdr("std_msgs/msg/Bool", data=True)))
        else:
            messages.append((start - 5_000_000, "/lab/recording", "std_msgs/msg/Header",
                             bytes(TS.serialize_cdr(_header(start), "std_msgs/msg/Header"))))
    bag = write_split(tmp_path / "bag", messages, cut, storage)
    with pytest.raises(TopicTypeError) as err:
        read_episodes(bag, spec=_spec(split="topic", split_topic="/lab/recording"))
    line = str(err.value)
    assert "changes type from std_msgs/msg/Bool to std_msgs/msg/Header at message #1" in line, line
    assert "separate bags" in line and "\n" not in line, line
