"""sim_nodes.ros_common helpers that need no running graph: messages, action parsing, parameter rules."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from std_msgs.msg import Float32MultiArray, Int32, Int32MultiArray

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.ros.params import ParameterError, ParamSpec
from sim_nodes.ros_common import (
    COMMON_PARAMS,
    encode_action,
    encode_marker,
    encode_observation,
    encode_sketch,
    parse_action,
)


def test_observation_and_sketch_messages():
    obs = np.arange(1075, dtype=np.float32) / 7
    msg = deserialize_message(encode_observation(obs), Float32MultiArray)
    dim = msg.layout.dim[0]
    assert (dim.label, dim.size, dim.stride) == ("obs", 1075, 1075)
    assert np.array_equal(np.asarray(msg.data, dtype=np.float32), obs)
    sk = deserialize_message(encode_sketch(np.array([7, 6, 4, 8])), Int32MultiArray)
    assert list(sk.data) == [7, 6, 4, 8] and sk.layout.dim[0].size == 4
    assert sk.layout.dim[0].label == "sketch"  # the label collected bags use


def test_action_messages_per_domain():
    assert deserialize_message(encode_action(layout.CRAFT, np.int64(4)), Int32).data == 4
    dial = deserialize_message(encode_action(layout.DIAL, np.ones(9) / 3), Float32MultiArray)
    assert dial.layout.dim[0].label == "action"
    np.testing.assert_array_equal(np.asarray(dial.data), np.full(9, 1 / 3, dtype=np.float32))


def test_builders_match_the_codec_builders():
    """The bytes equal rosbags' serialization of the codec's message objects."""
    obs = np.linspace(-1, 1, 39, dtype=np.float32)
    assert encode_observation(obs) == m.serialize(m.float32_array(obs, label="obs"))
    assert encode_sketch(np.array([3, 1, 4])) == m.serialize(m.int32_array([3, 1, 4], label="sketch"))
    assert encode_action(layout.CRAFT, 2) == m.serialize(m.int32(2))
    values = m.end_marker_values(2, "dial", 7, 130, True)
    assert encode_marker(5_000_000_007, layout.EPISODE_END, values) == m.serialize(
        m.episode_marker(layout.EPISODE_END, 5_000_000_007, values)
    )


def test_parse_action_validates():
    assert parse_action(layout.CRAFT, Int32(data=3)) == 3
    assert parse_action(layout.CRAFT, Int32(data=5)) == 5  # done
    with pytest.raises(ValueError, match="outside"):
        parse_action(layout.CRAFT, Int32(data=6))
    good = Float32MultiArray(data=[0.1] * 9)
    assert parse_action(layout.DIAL, good).shape == (9,)
    with pytest.raises(ValueError, match="9 finite"):
        parse_action(layout.DIAL, Float32MultiArray(data=[0.1] * 3))
    with pytest.raises(ValueError, match="9 finite"):
        parse_action(layout.DIAL, Float32MultiArray(data=[float("nan")] * 9))


def test_episode_marker_keys():
    values = m.start_marker_values(2, "x", 11, np.array([1, 2]))
    msg = deserialize_message(encode_marker(3_000_000_005, "start", values), DiagnosticArray)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 5)
    status = msg.status[0]
    assert status.name == layout.EPISODE_STATUS_NAME and status.message == "start"
    assert [(kv.key, kv.value) for kv in status.values] == [
        ("episode", "2"), ("task", "x"), ("seed", "11"), ("sketch", "1,2")
    ]


def test_param_rules_name_the_parameter():
    specs = {s.name: s for s in COMMON_PARAMS}
    with pytest.raises(ParameterError, match="'mode'"):
        specs["mode"].validate("autopilot")
    with pytest.raises(ParameterError, match="'rate'"):
        specs["rate"].validate(-1.0)
    with pytest.raises(ParameterError, match="'episode_pause'"):
        specs["episode_pause"].validate(-0.5)
    specs["rate"].validate(0.0)
    spec = ParamSpec("k", 1, "test", int_range=(0, 3))
    desc = spec.descriptor()
    assert desc.integer_range[0].from_value == 0 and desc.integer_range[0].to_value == 3 and desc.read_only
    with pytest.raises(ParameterError, match="'k'"):
        spec.validate(4)
