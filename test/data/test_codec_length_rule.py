"""One length rule for every parser of the codec: the same padded bytes are read the same way, and the
same short or over-long bytes are refused with one error type (``CdrError``) in one wording."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.errors import CorruptBagError
from ompn_ros.detect.online import BoundaryEvent

WRENCH, POSE = "geometry_msgs/msg/WrenchStamped", "geometry_msgs/msg/PoseStamped"
SHORT = r"^\w+ CDR of \d+ bytes ends inside \S+"
LONG = rf"bytes after the last field .*at most {m.MAX_TRAILING}"


def _wrench() -> bytes:
    v = m.msg_class("geometry_msgs/msg/Vector3")
    wrench = m.msg_class("geometry_msgs/msg/Wrench")(force=v(x=1.0, y=2.0, z=3.0),
                                                     torque=v(x=4.0, y=5.0, z=6.0))
    return m.serialize(m.msg_class(WRENCH)(header=m.header(7, "ft"), wrench=wrench))


def _pose() -> bytes:
    point = m.msg_class("geometry_msgs/msg/Point")(x=1.0, y=2.0, z=3.0)
    quat = m.msg_class("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.6, w=0.8)
    pose = m.msg_class("geometry_msgs/msg/Pose")(position=point, orientation=quat)
    return m.serialize(m.msg_class(POSE)(header=m.header(9, "abc"), pose=pose))


def _plain(value: Any) -> Any:
    """Comparable form of a parser's result (arrays as lists, tuples and dicts walked)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


EVENT = BoundaryEvent(step=4, detected_at=5, subtask=1, score=0.5, level=2, stamp_ns=10**9 + 3, final=True)
CASES: dict[str, tuple[bytes, Callable[[bytes], Any]]] = {
    "Float32MultiArray": (m.encode_float32_array([1.5, -2.0, 3.25]), m.parse_float32_array),
    "Int32MultiArray": (m.encode_int32_array([3, -4], "sketch"), m.parse_int32_array),
    "Float64MultiArray": (m.encode_float64_array([1.5, -2.0], "e"), m.parse_float64_array),
    "Float64MultiArray empty": (m.encode_float64_array([], "e"), m.parse_float64_array),
    "Int32": (m.encode_int32(-7), m.parse_int32),
    "Float32": (m.serialize(m.msg_class("std_msgs/msg/Float32")(data=1.5)), m.parse_float32),
    "Float64": (m.serialize(m.msg_class("std_msgs/msg/Float64")(data=2.5)), m.parse_float64),
    "WrenchStamped": (_wrench(), lambda raw: m.parse_stamped_doubles(raw, 6, WRENCH)),
    "PoseStamped": (_pose(), lambda raw: m.parse_stamped_doubles(raw, 7, POSE)),
    "JointState": (m.encode_joint_state(5, ["a", "bc"], [1.0, 2.0], [0.5, 0.25]), m.parse_joint_state),
    "JointState parser": (m.encode_joint_state(5, ["a", "bc"], [1.0, 2.0]),
                          lambda raw: m.JointStateParser().parse(raw)),
    "JointState names only": (m.encode_joint_state(5, ["j"]), m.parse_joint_state),
    "episode marker": (m.encode_episode_marker(layout.EPISODE_END, 11, {"steps": 3}), m.parse_marker),
    "SubtaskBoundary": (m.encode_subtask_boundary(m.SubtaskBoundary.from_event(EVENT, node="/n", episode=2)),
                        m.decode_subtask_boundary),
    "typestore": (m.encode_joint_state(5, ["a"], [1.0]),
                  lambda raw: m.deserialize(raw, layout.JOINT_STATE).position),
}


@pytest.mark.parametrize("name", CASES)
def test_up_to_max_trailing_bytes_are_padding(name: str) -> None:
    raw, parse = CASES[name]
    want = _plain(parse(raw))
    for extra in range(1, m.MAX_TRAILING + 1):
        for fill in (b"\0", b"\xab"):  # Fast CDR leaves its padding uninitialised: never read
            assert _plain(parse(raw + fill * extra)) == want, (name, extra, fill)


@pytest.mark.parametrize("name", CASES)
def test_more_trailing_bytes_are_refused(name: str) -> None:
    raw, parse = CASES[name]
    with pytest.raises(m.CdrError, match=LONG):
        parse(raw + b"\0" * (m.MAX_TRAILING + 1))


@pytest.mark.parametrize("name", CASES)
def test_every_cut_is_refused_naming_the_field(name: str) -> None:
    raw, parse = CASES[name]
    for size in range(4, len(raw)):
        with pytest.raises(m.CdrError, match=SHORT):
            parse(raw[:size])
    for size in range(4):
        with pytest.raises(m.CdrError):
            parse(raw[:size])


def test_the_fast_parsers_name_the_field_they_miss() -> None:
    js = m.encode_joint_state(5, ["a", "bc"], [1.0, 2.0])
    with pytest.raises(m.CdrError, match=r"ends inside name\[1\]$"):
        m.parse_joint_state(js[:37])
    with pytest.raises(m.CdrError, match=r"ends inside position$"):
        m.parse_joint_state(js[:-20])
    with pytest.raises(m.CdrError, match=r"^Float32MultiArray CDR of 20 bytes ends inside data$"):
        m.parse_float32_array(m.encode_float32_array([1.0, 2.0])[:20])
    with pytest.raises(m.CdrError, match=r"^WrenchStamped CDR of 30 bytes ends inside wrench$"):
        m.parse_stamped_doubles(_wrench()[:30], 6, WRENCH)


@pytest.mark.parametrize("typename", [layout.FLOAT32_ARRAY, layout.JOINT_STATE, "std_msgs/msg/Float64"])
def test_big_endian_bytes_follow_the_same_rule(typename: str) -> None:
    msg = {layout.FLOAT32_ARRAY: lambda: m.float32_array([1.5, 2.5]),
           layout.JOINT_STATE: lambda: m.joint_state(5, ["a"], [1.0]),
           "std_msgs/msg/Float64": lambda: m.msg_class(typename)(data=2.5)}[typename]()
    raw = bytes(m.typestore().serialize_cdr(msg, typename, little_endian=False))
    assert raw[:2] == b"\0\0"
    parse = {layout.FLOAT32_ARRAY: m.parse_float32_array, layout.JOINT_STATE: m.parse_joint_state,
             "std_msgs/msg/Float64": m.parse_float64}[typename]
    want = _plain(parse(m.serialize(msg)))
    assert _plain(parse(raw + b"\0" * m.MAX_TRAILING)) == want
    with pytest.raises(m.CdrError, match=LONG):
        parse(raw + b"\0" * (m.MAX_TRAILING + 1))
    with pytest.raises(m.CdrError, match=SHORT):
        parse(raw[:-1])


def test_the_bulk_readers_take_what_the_parsers_take() -> None:
    js = m.encode_joint_state(5, ["a"], [1.0])
    f32 = m.encode_float32_array([1.0, 2.0])
    for extra in (0, 3, m.MAX_TRAILING):
        bulk = m.stack_joint_states([js + b"\0" * extra] * 2)
        assert bulk is not None and bulk[2]["position"].tolist() == [[1.0], [1.0]]
        assert m.stack_float32_arrays([f32 + b"\0" * extra] * 2).tolist() == [[1.0, 2.0]] * 2
        assert m.stack_int32([m.encode_int32(4) + b"\0" * extra] * 2).tolist() == [4, 4]
    too_long = m.MAX_TRAILING + 1
    assert m.stack_joint_states([js + b"\0" * too_long] * 2) is None
    for stack, raw in ((m.stack_float32_arrays, f32), (m.stack_int32, m.encode_int32(4))):
        with pytest.raises(CorruptBagError) as info:
            stack([raw, raw + b"\0" * too_long])  # type: ignore[operator]
        assert isinstance(info.value.__cause__, m.CdrError)
