"""The package's one CDR message codec (ROS-free): import it as ``ompn_ros.data.messages``.

* :mod:`.cdr`: the framing every encoder and parser shares (encapsulation header, alignment), the
  length rule (at most :data:`MAX_TRAILING` bytes after the last field), the one error type
  :class:`CdrError`, stamps, and the ``rosbags`` Jazzy typestore.
* :mod:`.std`: builders and direct encoders of the topic layout's standard messages, episode markers.
* :mod:`.observations`: fast parsers of the per-step messages (MultiArrays, Int32, Float32/64,
  JointState, WrenchStamped, PoseStamped) for the bag reader, the node and the observation rule.
* :mod:`.interfaces`: ``ompn_interfaces``' ``SubtaskBoundary`` and ``SubtaskState``.
* :mod:`.fieldpath`: any numeric or string field of any registered type by path
  (``points[-1].positions``), read from raw CDR along the type's definition (docs/specs.md).
* :mod:`.types`: registering types from a bag's definitions, a ``.msg`` folder or a package.
"""

from .cdr import (
    CDR_LE_HEADER,
    INT32_MAX,
    INT32_MIN,
    MAX_TRAILING,
    STAMP_NS_MAX,
    STAMP_NS_MIN,
    CdrError,
    StampRangeError,
    deserialize,
    join_stamp,
    little_endian,
    msg_class,
    serialize,
    split_stamp,
    stamp_to_ns,
    typestore,
)
from .interfaces import (
    INTERFACE_MESSAGES,
    INTERFACES_PACKAGE,
    SUBTASK_BOUNDARY,
    SUBTASK_ID_UNKNOWN,
    SUBTASK_STATE,
    DetectedBoundary,
    SubtaskBoundary,
    decode_subtask_boundary,
    encode_subtask_boundary,
    encode_subtask_state,
    register_interfaces,
)
from .observations import (
    JointStateParser,
    multiarray_data,
    parse_float32,
    parse_float32_array,
    parse_float64,
    parse_float64_array,
    parse_int32,
    parse_int32_array,
    parse_joint_state,
    parse_stamped_doubles,
    stack_float32_arrays,
    stack_int32,
    stack_joint_states,
)
from .std import (
    encode_clock,
    encode_diagnostic_status,
    encode_episode_marker,
    encode_float32_array,
    encode_float64_array,
    encode_int32,
    encode_int32_array,
    encode_joint_state,
    encode_string,
    end_marker_values,
    episode_marker,
    float32_array,
    header,
    int32,
    int32_array,
    joint_state,
    marker_value,
    parse_marker,
    parse_sketch_value,
    start_marker_values,
)

__all__ = [
    "CDR_LE_HEADER", "INT32_MAX", "INT32_MIN", "INTERFACES_PACKAGE", "INTERFACE_MESSAGES", "MAX_TRAILING",
    "STAMP_NS_MAX", "STAMP_NS_MIN", "SUBTASK_BOUNDARY", "SUBTASK_ID_UNKNOWN", "SUBTASK_STATE", "CdrError",
    "DetectedBoundary", "JointStateParser", "StampRangeError", "SubtaskBoundary", "decode_subtask_boundary",
    "deserialize", "encode_clock", "encode_diagnostic_status", "encode_episode_marker",
    "encode_float32_array", "encode_float64_array", "encode_int32", "encode_int32_array",
    "encode_joint_state", "encode_string", "encode_subtask_boundary", "encode_subtask_state",
    "end_marker_values", "episode_marker", "float32_array", "header", "int32", "int32_array", "join_stamp",
    "joint_state", "little_endian", "marker_value", "msg_class", "multiarray_data", "parse_float32",
    "parse_float32_array",
    "parse_float64", "parse_float64_array", "parse_int32", "parse_int32_array", "parse_joint_state",
    "parse_marker", "parse_sketch_value", "parse_stamped_doubles", "register_interfaces", "serialize",
    "split_stamp", "stack_float32_arrays", "stack_int32", "stack_joint_states", "stamp_to_ns",
    "start_marker_values", "typestore",
]
