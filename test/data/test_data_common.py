"""Unit tests of ``ompn_ros.data.messages`` (the data tests' shared episodes: ``synthetic_episodes``)."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros import layout
from ompn_ros.data import messages as m


# --- messages.py ----------------------------------------------------------------------------------
def test_float32_array_layout_and_fast_parse_match_rosbags() -> None:
    values = np.linspace(-1, 1, 39, dtype=np.float32)
    raw = m.serialize(m.float32_array(values, "obs"))
    msg = m.deserialize(raw, layout.FLOAT32_ARRAY)
    assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [("obs", 39, 39)]
    np.testing.assert_array_equal(m.parse_float32_array(raw), values)
    stacked = m.stack_float32_arrays([raw, raw], expected_dim=39)
    assert stacked.shape == (2, 39)
    np.testing.assert_array_equal(stacked[1], values)


def test_direct_encoders_match_rosbags_bytes() -> None:
    for label, n in (("obs", 39), ("action", 9), ("obs", 1075), ("ab", 0), ("slot", 3)):
        values = np.arange(n, dtype=np.float32) - 3.5
        assert m.encode_float32_array(values, label) == m.serialize(m.float32_array(values, label))
    for v in (0, -7, 2**31 - 1):
        assert m.encode_int32(v) == m.serialize(m.int32(v))


def test_pi_encoding_with_dimension_smaller_than_data() -> None:
    """``~/pi``: dimension ('slot', n, n) over n + 2 values; the rosbags decoder reads it back."""
    raw = m.encode_float32_array(np.array([0.25, 0.75, 1.75, 0.1], np.float32), "slot", 2)
    msg = m.deserialize(raw, "std_msgs/msg/Float32MultiArray")
    dim = msg.layout.dim[0]
    assert (dim.label, dim.size, dim.stride) == ("slot", 2, 2)
    np.testing.assert_array_equal(msg.data, np.array([0.25, 0.75, 1.75, 0.1], np.float32))


@pytest.mark.parametrize("values", [{}, {"step": 12, "score": "0.500000", "final": "false"},
                                    {"k": "ü-unicode", "x" * 5: "y" * 6}])
def test_diagnostic_encoder_matches_rosbags_bytes(values: dict) -> None:
    kv = m.msg_class("diagnostic_msgs/msg/KeyValue")
    status = m.msg_class("diagnostic_msgs/msg/DiagnosticStatus")(
        level=1, name="ompn_node/subtask_boundary", message="boundary", hardware_id="",
        values=[kv(key=k, value=str(v)) for k, v in values.items()],
    )
    array = m.msg_class("diagnostic_msgs/msg/DiagnosticArray")
    expected = m.serialize(array(header=m.header(1_700_000_000_123_456_789), status=[status]))
    got = m.encode_diagnostic_status(1_700_000_000_123_456_789, "ompn_node/subtask_boundary", "boundary",
                                     values, level=1)
    assert got == expected


def test_int32_and_marker_round_trip() -> None:
    assert m.parse_int32(m.serialize(m.int32(-7))) == -7
    np.testing.assert_array_equal(m.stack_int32([m.serialize(m.int32(v)) for v in (3, -1, 9)]), [3, -1, 9])
    raw = m.serialize(m.episode_marker(layout.EPISODE_START, 5,
                                       m.start_marker_values(4, "makeaxe", 17, np.asarray([1, 2]))))
    kind, values = m.parse_marker(raw) or ("", {})
    assert kind == layout.EPISODE_START
    assert values == {layout.KEY_EPISODE: "4", layout.KEY_TASK: "makeaxe", layout.KEY_SEED: "17",
                      layout.KEY_SKETCH: "1,2"}
    np.testing.assert_array_equal(m.parse_sketch_value(values[layout.KEY_SKETCH]), [1, 2])


def test_stack_reports_the_bad_index() -> None:
    import pytest

    from ompn_ros.data.errors import VectorLengthError

    good = m.serialize(m.float32_array(np.zeros(4)))
    bad = m.serialize(m.float32_array(np.zeros(5)))
    with pytest.raises(VectorLengthError) as info:
        m.stack_float32_arrays([good, good, bad], path="x.mcap", topic="/observation")
    assert info.value.index == 2 and info.value.topic == "/observation"
    assert "x.mcap" in str(info.value) and "message #2" in str(info.value)


def test_joint_state_bulk_and_rclpy_bytes() -> None:
    """Our JointState parser reads rosbags and rclpy (Fast CDR: garbage padding, trailing bytes)."""
    import pytest

    names = ["j1", "joint_two", "j3x"]
    ours = [m.serialize(m.joint_state(10**9 * k + 7, names, np.arange(3) + k, np.full(3, 0.5)))
            for k in range(3)]
    got = m.stack_joint_states(ours)
    assert got is not None
    assert got[0] == names
    np.testing.assert_array_equal(got[1], [10**9 * k + 7 for k in range(3)])
    np.testing.assert_array_equal(got[2]["position"][2], [2, 3, 4])
    assert got[2]["effort"].shape == (3, 0)

    serialization = pytest.importorskip("rclpy.serialization")
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    raws = []
    for k in range(3):
        js = sensor_msgs.JointState()
        js.header.stamp.sec, js.header.stamp.nanosec, js.header.frame_id = k, 3, "base"
        js.name, js.position, js.velocity = names, [1.0 * k, 2.0, 3.0], [0.5, 0.25, 1.0 * k]
        raws.append(serialization.serialize_message(js))  # empty effort: Fast CDR pads the end
    bulk = m.stack_joint_states(raws)
    assert bulk is not None
    np.testing.assert_array_equal(bulk[1], [k * 10**9 + 3 for k in range(3)])
    np.testing.assert_array_equal(bulk[2]["velocity"][:, 2], [0.0, 1.0, 2.0])
    one = m.parse_joint_state(raws[1])
    assert one[0] == names and one[1] == 10**9 + 3
    np.testing.assert_array_equal(one[2]["position"], [1.0, 2.0, 3.0])
