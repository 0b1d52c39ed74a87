"""The encoders the sims use: the same bytes as rosbags' serializer, readable by rclpy's deserializer."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data import messages as m

c = m  # the encoders under test

NAMES9 = [f"joint_{i}" for i in range(9)]
JOINT_CASES = [  # names, position, velocity, effort: full, partial and empty arrays, odd name lengths
    (NAMES9, np.arange(9) / 3, np.arange(9) / 7, np.arange(9) / 11),
    (["a", "bcd"], [1.0, 2.0], [], []),
    (["abc"], [], [], [3.0]),
    ([], [], [], []),
]


@pytest.mark.parametrize(("names", "pos", "vel", "eff"), JOINT_CASES)
def test_joint_state_bytes(names: list[str], pos: list[float], vel: list[float], eff: list[float]) -> None:
    stamp = 1_234_567_891_234
    raw = c.encode_joint_state(stamp, names, pos, vel, eff)
    assert raw == m.serialize(m.joint_state(stamp, names, pos, vel, eff))
    got_names, got_stamp, fields = m.parse_joint_state(raw)
    assert (got_names, got_stamp) == (names, stamp)
    np.testing.assert_array_equal(fields["velocity"], np.asarray(vel, dtype=np.float64))


def _msg(typename: str, **kw: object) -> object:
    return m.msg_class(typename)(**kw)


def test_clock_string_and_arrays_bytes() -> None:
    stamp = 5_000_000_001
    clock = _msg("rosgraph_msgs/msg/Clock", clock=_msg("builtin_interfaces/msg/Time", sec=5, nanosec=1))
    assert c.encode_clock(stamp) == m.serialize(clock)
    for text in ("", "a", "héllo\nworld"):
        assert c.encode_string(text) == m.serialize(_msg("std_msgs/msg/String", data=text))
    assert c.encode_int32_array([7, 6, 4, 8]) == m.serialize(m.int32_array([7, 6, 4, 8], label="sketch"))
    for label, n in (("effort", 9), ("x", 0), ("ab", 3)):
        data = np.arange(n) / 3.0
        dim = _msg("std_msgs/msg/MultiArrayDimension", label=label, size=n, stride=n)
        lay = _msg("std_msgs/msg/MultiArrayLayout", dim=[dim], data_offset=0)
        expected = m.serialize(_msg("std_msgs/msg/Float64MultiArray", layout=lay, data=data))
        assert c.encode_float64_array(data, label) == expected


def test_rclpy_reads_the_bytes() -> None:
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, String

    raw = c.encode_joint_state(3_500_000_000, NAMES9, np.arange(9), [], np.ones(9))
    js = deserialize_message(raw, JointState)
    assert (js.header.stamp.sec, js.header.stamp.nanosec) == (3, 500_000_000)
    assert list(js.name) == NAMES9 and list(js.position) == list(range(9)) and len(js.velocity) == 0
    arr = deserialize_message(c.encode_float64_array([1.5, -2.0], "effort"), Float64MultiArray)
    assert arr.layout.dim[0].label == "effort" and list(arr.data) == [1.5, -2.0]
    clock = deserialize_message(c.encode_clock(7_000_000_005), Clock).clock
    assert (clock.sec, clock.nanosec) == (7, 5)
    assert deserialize_message(c.encode_string("ab"), String).data == "ab"
