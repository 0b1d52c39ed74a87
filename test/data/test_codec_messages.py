"""The message codec: every direct encoder gives the bytes of rosbags' and rclpy's serializers."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.validate import SketchError

STAMPS = [0, 1, 1_999_999_999, 1_700_000_000_123_456_789, m.STAMP_NS_MAX, -1_000_000_000, m.STAMP_NS_MIN]


def same_as_rclpy(ours: bytes, msg, typename: str) -> bool:
    """``ours`` equals rclpy's bytes of ``msg`` except padding, which Fast CDR leaves uninitialised:
    same length, and rclpy's bytes re-encoded canonically by rosbags (zero padding) are ours."""
    theirs = bytes(serialize_message(msg))
    return len(theirs) == len(ours) and m.serialize(m.deserialize(theirs, typename)) == ours


def rclpy_time(stamp_ns: int):
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


@pytest.mark.parametrize("values", [[], [3], [0, 7, 2, 2**31 - 1, -5]])
@pytest.mark.parametrize("label", ["sketch", "", "a-longer-label"])
def test_int32_array_encoder_matches_both_serializers(values: list[int], label: str) -> None:
    from std_msgs.msg import Int32MultiArray, MultiArrayDimension

    raw = m.encode_int32_array(values, label)
    assert raw == m.serialize(m.int32_array(values, label))
    msg = Int32MultiArray(data=values)
    msg.layout.dim = [MultiArrayDimension(label=label, size=len(values), stride=len(values))]
    assert same_as_rclpy(raw, msg, layout.INT32_ARRAY)
    assert m.parse_int32_array(raw).tolist() == values


def test_int32_array_encoder_refuses_values_beyond_int32() -> None:
    with pytest.raises(OverflowError, match="int32"):
        m.encode_int32_array([2**31])


@pytest.mark.parametrize("stamp", STAMPS)
def test_clock_encoder_matches_both_serializers(stamp: int) -> None:
    from rosgraph_msgs.msg import Clock

    raw = m.encode_clock(stamp)
    sec, nanosec = m.split_stamp(stamp)
    ros_time = m.msg_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)
    assert raw == m.serialize(m.msg_class("rosgraph_msgs/msg/Clock")(clock=ros_time))
    assert same_as_rclpy(raw, Clock(clock=rclpy_time(stamp)), "rosgraph_msgs/msg/Clock")


@pytest.mark.parametrize("stamp", [m.STAMP_NS_MAX + 1, m.STAMP_NS_MIN - 1, 10**30])
def test_out_of_range_stamps_raise_one_clear_error(stamp: int) -> None:
    for encode in (m.encode_clock, lambda s: m.encode_joint_state(s, ["a"], [1.0]),
                   lambda s: m.encode_episode_marker("end", s, {"steps": 3})):
        with pytest.raises(m.StampRangeError, match="does not fit"):
            encode(stamp)
    with pytest.raises(m.StampRangeError):
        m.header(stamp)


def test_join_stamp_refuses_nanoseconds_beyond_a_second() -> None:
    assert m.join_stamp(2, 5) == 2_000_000_005
    with pytest.raises(m.StampRangeError, match="nanosec"):
        m.join_stamp(2147483647, 4294967295)


@pytest.mark.parametrize("stamp", STAMPS[:4])
@pytest.mark.parametrize(
    "arrays",
    [((1.0, 2.0), (0.5, -0.5), (3.0, 4.0)), ((1.0, 2.0), (), ()), ((), (), ()), ((1.5, 2.5), (1.0, 0.0), ())],
)
def test_joint_state_encoder_matches_rosbags_and_parses_rclpy_bytes(stamp: int, arrays: tuple) -> None:
    from sensor_msgs.msg import JointState

    names = ["joint_1", "j2"]
    raw = m.encode_joint_state(stamp, names, *arrays)
    assert raw == m.serialize(m.joint_state(stamp, names, *arrays))
    msg = JointState(name=names, position=list(arrays[0]), velocity=list(arrays[1]), effort=list(arrays[2]))
    msg.header.stamp = rclpy_time(stamp)
    ros_raw = bytes(serialize_message(msg))
    # Fast CDR may pad after empty arrays and leaves padding uninitialised: rclpy's bytes,
    # cut to our length and re-encoded canonically by rosbags, are ours.
    assert 0 <= len(ros_raw) - len(raw) < 16
    assert m.serialize(m.deserialize(ros_raw[: len(raw)], layout.JOINT_STATE)) == raw
    for blob in (raw, ros_raw):
        got_names, got_stamp, fields = m.parse_joint_state(blob)
        assert got_names == names and got_stamp == stamp
        for field, values in zip(layout.JOINT_FIELDS, arrays, strict=True):
            assert fields[field].tolist() == list(values)
    back = deserialize_message(raw, JointState)
    assert list(back.position) == list(arrays[0])


@pytest.mark.parametrize("kind", [layout.EPISODE_START, layout.EPISODE_END])
@pytest.mark.parametrize("stamp", STAMPS[:4])
def test_episode_marker_encoder_matches_both_serializers(kind: str, stamp: int) -> None:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    values = m.start_marker_values(3, "makebed", 11, np.array([1, 4, 2]))
    values[layout.KEY_SUCCESS] = True
    raw = m.encode_episode_marker(kind, stamp, values)
    assert raw == m.serialize(m.episode_marker(kind, stamp, values))
    status = DiagnosticStatus(level=b"\x00", name=layout.EPISODE_STATUS_NAME, message=kind, hardware_id="",
                              values=[KeyValue(key=k, value=m.marker_value(v)) for k, v in values.items()])
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = rclpy_time(stamp)
    assert same_as_rclpy(raw, msg, layout.DIAGNOSTIC_ARRAY)
    parsed = m.parse_marker(raw)
    expected = {"episode": "3", "task": "makebed", "seed": "11", "sketch": "1,4,2", "success": "true"}
    assert parsed == (kind, expected)


@pytest.mark.parametrize("values", [np.zeros(0), np.arange(39) / 7.0])
def test_float32_and_int32_encoders_match_rclpy(values: np.ndarray) -> None:
    from std_msgs.msg import Float32MultiArray, Int32, MultiArrayDimension

    msg = Float32MultiArray(data=values.astype(np.float32).tolist())
    msg.layout.dim = [MultiArrayDimension(label="obs", size=values.size, stride=values.size)]
    assert same_as_rclpy(m.encode_float32_array(values, "obs"), msg, layout.FLOAT32_ARRAY)
    for v in (0, -7, 2**31 - 1):
        assert m.encode_int32(v) == bytes(serialize_message(Int32(data=v)))


@pytest.mark.parametrize(
    "text", ["99999999999999999999", "1,x", "1,,2", "-1", "1.5", "2147483648", " , ", "1" * 5000]
)
def test_parse_sketch_value_raises_sketch_error_only(text: str) -> None:
    with pytest.raises(SketchError):
        m.parse_sketch_value(text)


def test_parse_sketch_value_checks_the_vocabulary() -> None:
    assert m.parse_sketch_value(" 1, 4,2 ").tolist() == [1, 4, 2]
    assert m.parse_sketch_value("").size == 0
    with pytest.raises(SketchError, match=r"outside the vocabulary 0\.\.4"):
        m.parse_sketch_value("7,9", vocab=5)
