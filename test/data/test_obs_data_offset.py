"""``layout.data_offset`` of a Float64MultiArray in the live observation rule: the padding elements at
the front of ``data`` are not data, as in the bag reader (docs/bags.md); one parser for both."""

from __future__ import annotations

import numpy as np
import pytest
from padded_arrays import _padded

from ompn_ros import layout
from ompn_ros.data.messages import parse_float64_array
from ompn_ros.data.obs import ObservationSpec, assemble_stream
from ompn_ros.data.reader.vectors import stack_float64_arrays

F64 = "std_msgs/msg/Float64MultiArray"
SPEC = ObservationSpec.from_dict({
    "step_topic": "/arm/effort", "stamp": "receive",
    "fields": [{"topic": "/arm/effort", "type": F64, "field": "data", "size": 3},
               {"topic": "/arm/gripper", "type": layout.FLOAT32_ARRAY, "field": "data", "size": 2}],
})


@pytest.mark.parametrize("dims", [1, 2])
def test_padding_is_skipped_by_the_live_assembler(dims: int) -> None:
    """Was: the assembler read the two padding elements as data (a wrong_size drop, or wrong values)."""
    rows = np.asarray([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])
    grip = np.asarray([0.25, 0.5])
    messages = []
    for k, row in enumerate(rows):
        t = 10**9 + k * 40_000_000
        messages.append(("/arm/gripper", t, _padded(layout.FLOAT32_ARRAY, grip + k, 1)))
        messages.append(("/arm/effort", t + 1000, _padded(F64, row[:3] if dims == 1 else row, 2, dims)))
    fields = SPEC.to_dict()["fields"]
    spec = SPEC if dims == 1 else ObservationSpec.from_dict(
        {**SPEC.to_dict(), "fields": [{**fields[0], "size": 4}, fields[1]]})
    stream = assemble_stream(messages, spec)
    want = np.asarray([[*(row[:3] if dims == 1 else row), *(grip + k)] for k, row in enumerate(rows)])
    np.testing.assert_array_equal(stream.observations, want.astype(np.float32))


def test_one_rule_for_the_reader_and_the_node() -> None:
    raw = _padded(F64, np.asarray([1.5, -2.0, 3.25]), 2)
    np.testing.assert_array_equal(parse_float64_array(raw), [1.5, -2.0, 3.25])
    stamps = np.asarray([1])
    stacked = stack_float64_arrays([raw], 3, "bag", "/arm/effort", stamps)  # the reader's path
    np.testing.assert_array_equal(stacked, [[1.5, -2.0, 3.25]])
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    beyond = ts.types[F64](layout=ts.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=5),
                           data=np.ones(2))
    with pytest.raises(ValueError, match="data_offset 5 exceeds the 2"):
        parse_float64_array(bytes(ts.serialize_cdr(beyond, F64)))
