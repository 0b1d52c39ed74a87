"""sim_nodes.ros_common helpers that need no running graph: messages, action parsing, parameter rules."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
from builtin_interfaces.msg import Time
from std_msgs.msg import Float32MultiArray, Int32

from ompn_ros import layout
from ompn_ros.nodes.params import ParameterError, ParamSpec
from sim_nodes.ros_common import (
    COMMON_PARAMS,
    action_msg,
    episode_marker,
    observation_msg,
    parse_action,
    sketch_msg,
)


def test_observation_and_sketch_messages():
    obs = np.arange(1075, dtype=np.float32) / 7
    msg = observation_msg(obs)
    dim = msg.layout.dim[0]
    assert (dim.label, dim.size, dim.stride) == ("obs", 1075, 1075)
    assert np.array_equal(np.asarray(msg.data, dtype=np.float32), obs)
    sk = sketch_msg(np.array([7, 6, 4, 8]))
    assert list(sk.data) == [7, 6, 4, 8] and sk.layout.dim[0].size == 4


def test_action_messages_per_domain():
    assert action_msg(layout.CRAFT, np.int64(4)).data == 4
    dial = action_msg(layout.DIAL, np.ones(9))
    assert isinstance(dial, Float32MultiArray) and dial.layout.dim[0].label == "action"
    assert len(dial.data) == 9


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
    msg = episode_marker(Time(sec=3, nanosec=5), "start", {"task": "x", "episode": 2})
    assert msg.header.stamp.sec == 3
    status = msg.status[0]
    assert status.name == layout.EPISODE_STATUS_NAME and status.message == "start"
    assert [(kv.key, kv.value) for kv in status.values] == [("task", "x"), ("episode", "2")]


def test_param_rules_name_the_parameter():
    specs = {s.name: s for s in COMMON_PARAMS}
    with pytest.raises(ParameterError, match="'mode'"):
        specs["mode"].validate("autopilot")
    with pytest.raises(ParameterError, match="'rate'"):
        specs["rate"].validate(-1.0)
    specs["rate"].validate(0.0)
    spec = ParamSpec("k", 1, "test", int_range=(0, 3))
    desc = spec.descriptor()
    assert desc.integer_range[0].from_value == 0 and desc.integer_range[0].to_value == 3 and desc.read_only
    with pytest.raises(ParameterError, match="'k'"):
        spec.validate(4)
