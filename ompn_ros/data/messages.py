"""Build and parse the messages of the topic layout with the ``rosbags`` Jazzy typestore (ROS-free).

Builders return ``rosbags`` message objects (serialise them with :func:`serialize`); the sim nodes
mirror the same field choices with rclpy classes.  Parsers come in two speeds:

* exact per-message decoders built on ``Typestore.deserialize_cdr`` (markers, JointState), and
* bulk fast paths for the per-step vectors (``Float32MultiArray``, ``Int32``) that parse the
  little-endian CDR layout directly and stack many messages with one ``np.frombuffer`` call.

CDR layout of ``std_msgs/msg/Float32MultiArray`` (little endian, 4-byte encapsulation header)::

    00 01 00 00 | u32 n_dims | n_dims x (u32 len, label bytes + NUL, pad to 4, u32 size, u32 stride)
                | u32 data_offset | u32 n | n x f32
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from functools import lru_cache
from typing import Any

import numpy as np

from ompn_ros import layout
from ompn_ros.validate import parse_sketch_text

from .errors import CorruptBagError, VectorLengthError

CDR_LE_HEADER = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The ``rosbags`` typestore of ROS 2 Jazzy (shared, created once)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def msg_class(typename: str) -> Any:
    """Message class of ``typename`` (e.g. ``std_msgs/msg/Int32``) in the Jazzy typestore."""
    return typestore().types[typename]


def serialize(msg: Any) -> bytes:
    """CDR bytes of a ``rosbags`` message object."""
    return bytes(typestore().serialize_cdr(msg, msg.__msgtype__))


def deserialize(raw: bytes | memoryview, typename: str) -> Any:
    """Decode CDR bytes of ``typename`` into a ``rosbags`` message object."""
    return typestore().deserialize_cdr(raw, typename)


# --- builders -------------------------------------------------------------------------------------
def _time(stamp_ns: int) -> Any:
    sec, nanosec = split_stamp(stamp_ns)
    return msg_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str = "") -> Any:
    """``std_msgs/Header`` stamped at ``stamp_ns``."""
    return msg_class("std_msgs/msg/Header")(stamp=_time(stamp_ns), frame_id=frame_id)


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def float32_array(values: np.ndarray | Sequence[float], label: str = "obs") -> Any:
    """``Float32MultiArray`` with ``layout.dim=[MultiArrayDimension(label, size=D, stride=D)]``."""
    data = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    n = int(data.size)
    dim = msg_class("std_msgs/msg/MultiArrayDimension")(label=label, size=n, stride=n)
    lay = msg_class("std_msgs/msg/MultiArrayLayout")(dim=[dim], data_offset=0)
    return msg_class(layout.FLOAT32_ARRAY)(layout=lay, data=data)


def int32_array(values: np.ndarray | Sequence[int], label: str = "sketch") -> Any:
    """``Int32MultiArray`` with one labelled dimension."""
    data = np.ascontiguousarray(values, dtype=np.int32).reshape(-1)
    n = int(data.size)
    dim = msg_class("std_msgs/msg/MultiArrayDimension")(label=label, size=n, stride=n)
    lay = msg_class("std_msgs/msg/MultiArrayLayout")(dim=[dim], data_offset=0)
    return msg_class(layout.INT32_ARRAY)(layout=lay, data=data)


def int32(value: int) -> Any:
    """``std_msgs/Int32``."""
    return msg_class(layout.INT32)(data=int(value))


def joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: np.ndarray | Sequence[float] = (),
    velocity: np.ndarray | Sequence[float] = (),
    effort: np.ndarray | Sequence[float] = (),
) -> Any:
    """``sensor_msgs/JointState`` stamped at ``stamp_ns`` (sim time)."""
    return msg_class(layout.JOINT_STATE)(
        header=header(stamp_ns),
        name=list(names),
        position=np.asarray(position, dtype=np.float64).reshape(-1),
        velocity=np.asarray(velocity, dtype=np.float64).reshape(-1),
        effort=np.asarray(effort, dtype=np.float64).reshape(-1),
    )


def episode_marker(kind: str, stamp_ns: int, values: Mapping[str, object]) -> Any:
    """Episode start/end marker: ``DiagnosticArray`` with one status named ``episode``.

    ``kind`` is ``layout.EPISODE_START`` or ``layout.EPISODE_END``; ``values`` become key/value
    pairs (``layout.KEY_*``), converted with :func:`marker_value`.
    """
    kv = msg_class("diagnostic_msgs/msg/KeyValue")
    status = msg_class("diagnostic_msgs/msg/DiagnosticStatus")(
        level=0,
        name=layout.EPISODE_STATUS_NAME,
        message=kind,
        hardware_id="",
        values=[kv(key=k, value=marker_value(v)) for k, v in values.items()],
    )
    return msg_class(layout.DIAGNOSTIC_ARRAY)(header=header(stamp_ns), status=[status])


def marker_value(value: object) -> str:
    """String form of a marker value: bools as 'true'/'false', sequences comma-separated."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (list, tuple, np.ndarray)):
        return ",".join(str(int(v)) for v in value)
    return str(value)


def start_marker_values(episode_index: int, task: str, seed: int, sketch: np.ndarray | None) -> dict:
    """Key/values of an episode start marker."""
    return {
        layout.KEY_EPISODE: episode_index,
        layout.KEY_TASK: task,
        layout.KEY_SEED: seed,
        layout.KEY_SKETCH: [] if sketch is None else list(np.asarray(sketch).reshape(-1)),
    }


def end_marker_values(episode_index: int, task: str, seed: int, steps: int, success: bool) -> dict:
    """Key/values of an episode end marker."""
    return {
        layout.KEY_EPISODE: episode_index,
        layout.KEY_TASK: task,
        layout.KEY_SEED: seed,
        layout.KEY_STEPS: steps,
        layout.KEY_SUCCESS: bool(success),
    }


# --- direct encoders (same bytes as serialize(builder(...)), several times faster) -----------------
class StampRangeError(ValueError):
    """A stamp does not fit ``builtin_interfaces/Time`` (int32 seconds, nanoseconds below 1e9)."""


INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
STAMP_NS_MIN = INT32_MIN * 1_000_000_000
STAMP_NS_MAX = INT32_MAX * 1_000_000_000 + 999_999_999


def split_stamp(stamp_ns: int) -> tuple[int, int]:
    """``stamp_ns`` -> ``(sec, nanosec)`` of ``builtin_interfaces/Time``; :class:`StampRangeError` if the
    seconds do not fit an int32 (O(1))."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if not INT32_MIN <= sec <= INT32_MAX:
        raise StampRangeError(
            f"stamp {int(stamp_ns)} ns does not fit builtin_interfaces/Time (int32 seconds)"
        )
    return sec, nanosec


def join_stamp(sec: int, nanosec: int) -> int:
    """``builtin_interfaces/Time`` fields -> ns; :class:`StampRangeError` if ``nanosec`` >= 1e9 or a field
    is outside its CDR type (int32 / uint32)."""
    if not INT32_MIN <= int(sec) <= INT32_MAX or not 0 <= int(nanosec) < 1_000_000_000:
        raise StampRangeError(f"stamp sec={sec} nanosec={nanosec} is not a valid time "
                              "(nanosec must be below 1e9)")
    return int(sec) * 1_000_000_000 + int(nanosec)


class _CdrWriter:
    """Little-endian CDR body writer (alignment relative to the end of the encapsulation header)."""

    def __init__(self) -> None:
        self.out = bytearray(CDR_LE_HEADER)

    def _align(self, n: int) -> None:
        self.out += b"\0" * (-(len(self.out) - 4) % n)

    def u32(self, value: int) -> None:
        self._align(4)
        self.out += _U32.pack(value)

    def i32(self, value: int) -> None:
        self._align(4)
        self.out += _I32.pack(value)

    def string(self, text: str) -> None:
        data = text.encode() + b"\0"
        self.u32(len(data))
        self.out += data

    def stamp(self, stamp_ns: int) -> None:
        sec, nanosec = split_stamp(stamp_ns)
        self.i32(sec)
        self.u32(nanosec)

    def float64s(self, values: np.ndarray | Sequence[float]) -> None:
        data = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
        self.u32(int(data.size))
        if data.size:
            self._align(8)
            self.out += data.tobytes()


@lru_cache(maxsize=64)
def _multiarray_prefix(label: str, n: int, dim_size: int | None = None) -> bytes:
    """CDR bytes of a one-dimension MultiArray up to (and including) the element count ``n``.

    The dimension's size and stride are ``dim_size`` (default ``n``).
    """
    size = n if dim_size is None else dim_size
    w = _CdrWriter()
    w.u32(1)  # one dimension
    w.string(label)
    for value in (size, size, 0, n):  # size, stride, data_offset, element count
        w.u32(value)
    return bytes(w.out)


def encode_float32_array(
    values: np.ndarray | Sequence[float], label: str = "obs", dim_size: int | None = None
) -> bytes:
    """CDR of a ``Float32MultiArray`` with one dimension ``(label, dim_size, dim_size)`` (``dim_size``
    defaults to the number of values) without building a message object."""
    data = np.ascontiguousarray(values, dtype="<f4").reshape(-1)
    return _multiarray_prefix(label, int(data.size), dim_size) + data.tobytes()


def encode_int32_array(values: np.ndarray | Sequence[int], label: str = "sketch") -> bytes:
    """CDR of :func:`int32_array` ``(values, label)``: an ``Int32MultiArray`` with one dimension.

    Raises ``OverflowError`` naming the value when one does not fit an int32."""
    data = np.asarray(values).reshape(-1)
    if data.size and (int(data.min()) < INT32_MIN or int(data.max()) > INT32_MAX):
        raise OverflowError(f"Int32MultiArray value out of int32 range: {data.tolist()}")
    return _multiarray_prefix(label, int(data.size), None) + data.astype("<i4").tobytes()


def encode_float64_array(values: np.ndarray | Sequence[float], label: str) -> bytes:
    """CDR of a ``Float64MultiArray`` with one dimension ``(label, n, n)`` (e.g. an effort command)."""
    data = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
    head = _multiarray_prefix(label, int(data.size), None)
    pad = b"\0" * (-(len(head) - 4) % 8) if data.size else b""
    return head + pad + data.tobytes()


def encode_string(text: str) -> bytes:
    """CDR of ``std_msgs/String``."""
    w = _CdrWriter()
    w.string(text)
    return bytes(w.out)


def encode_int32(value: int) -> bytes:
    """CDR of :func:`int32` ``(value)``."""
    return CDR_LE_HEADER + _I32.pack(int(value))


def encode_clock(stamp_ns: int) -> bytes:
    """CDR of ``rosgraph_msgs/Clock`` at ``stamp_ns`` (:class:`StampRangeError` if out of range)."""
    w = _CdrWriter()
    w.stamp(stamp_ns)
    return bytes(w.out)


def encode_joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: np.ndarray | Sequence[float] = (),
    velocity: np.ndarray | Sequence[float] = (),
    effort: np.ndarray | Sequence[float] = (),
    frame_id: str = "",
) -> bytes:
    """CDR of :func:`joint_state` (``sensor_msgs/JointState``), the bytes ``rosbags`` writes.

    rclpy's serializer may append up to 12 padding bytes after empty arrays; both forms parse
    with :func:`parse_joint_state`."""
    w = _CdrWriter()
    w.stamp(stamp_ns)
    w.string(frame_id)
    w.u32(len(names))
    for name in names:
        w.string(name)
    for values in (position, velocity, effort):
        w.float64s(values)
    return bytes(w.out)


def encode_diagnostic_status(
    stamp_ns: int, name: str, message: str, values: Mapping[str, object], level: int = 0
) -> bytes:
    """CDR of a ``DiagnosticArray`` holding one status (``values`` as strings), built directly.

    The same bytes as ``serialize`` of the rosbags message (tested); used where a message object per
    event would cost more than the event itself (``ompn_node``'s boundary events).  Values are
    converted with :func:`marker_value`.  :class:`StampRangeError` if ``stamp_ns`` does not fit.
    """
    w = _CdrWriter()
    w.stamp(stamp_ns)
    w.string("")  # header.frame_id
    w.u32(1)  # one status
    w.out += bytes([level & 0xFF])
    w.string(name)
    w.string(message)
    w.string("")  # hardware_id
    w.u32(len(values))
    for key, value in values.items():
        w.string(key)
        w.string(marker_value(value))
    return bytes(w.out)


def encode_episode_marker(kind: str, stamp_ns: int, values: Mapping[str, object]) -> bytes:
    """CDR of :func:`episode_marker` ``(kind, stamp_ns, values)``: the stamped start/end marker."""
    return encode_diagnostic_status(stamp_ns, layout.EPISODE_STATUS_NAME, kind, values)


# --- parsers --------------------------------------------------------------------------------------
def parse_marker(raw: bytes | memoryview) -> tuple[str, dict[str, str]] | None:
    """Decode an episode marker: ``(kind, values)`` or ``None`` if it is not an episode status."""
    msg = deserialize(raw, layout.DIAGNOSTIC_ARRAY)
    for status in msg.status:
        if status.name == layout.EPISODE_STATUS_NAME:
            return str(status.message), {kv.key: kv.value for kv in status.values}
    return None


def parse_sketch_value(text: str, vocab: int | None = None) -> np.ndarray:
    """Comma-separated subtask ids (marker ``sketch`` key) -> int64 array ('' -> empty).

    Delegates to :func:`ompn_ros.validate.parse_sketch_text`: raises ``SketchError`` (a ``ValueError``)
    on anything else, huge numbers included."""
    return parse_sketch_text(text, vocab)


def after_data_offset(data: np.ndarray, data_offset: int) -> np.ndarray:
    """``data`` without the ``layout.data_offset`` padding elements at its front."""
    if data_offset > len(data):
        raise ValueError(f"layout.data_offset {data_offset} exceeds the {len(data)} data elements")
    return data[data_offset:]


def multiarray_data_start(raw: bytes | memoryview) -> tuple[int, int]:
    """Offset of the first element and element count of a little-endian MultiArray CDR message
    (4-byte elements).  ``layout.data_offset`` padding elements at the front of ``data`` are not
    elements of the array (std_msgs/MultiArrayLayout): they are skipped."""
    if bytes(raw[:4]) != CDR_LE_HEADER:
        raise ValueError("not a little-endian CDR message")
    pos = 4
    (ndim,) = _U32.unpack_from(raw, pos)
    pos += 4
    if ndim > 64:
        raise ValueError(f"implausible number of dimensions {ndim}")
    for _ in range(ndim):
        (slen,) = _U32.unpack_from(raw, pos)
        pos += 4 + slen
        pos = (pos + 3) & ~3
        pos += 8  # size, stride
    (offset, n) = struct.unpack_from("<II", raw, pos)
    pos += 8
    if pos + 4 * n != len(raw):
        raise ValueError(f"CDR length {len(raw)} does not match {n} elements starting at byte {pos}")
    if offset > n:
        raise ValueError(f"layout.data_offset {offset} exceeds the {n} data elements")
    return pos + 4 * offset, n - offset


def parse_float32_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``Float32MultiArray`` as a float32 vector."""
    try:
        start, n = multiarray_data_start(raw)
    except (ValueError, struct.error):
        msg = deserialize(raw, layout.FLOAT32_ARRAY)
        return after_data_offset(np.asarray(msg.data, dtype=np.float32), int(msg.layout.data_offset))
    return np.frombuffer(raw, dtype="<f4", count=n, offset=start).astype(np.float32)


def parse_int32_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``Int32MultiArray`` as an int64 vector."""
    try:
        start, n = multiarray_data_start(raw)
    except (ValueError, struct.error):
        msg = deserialize(raw, layout.INT32_ARRAY)
        return after_data_offset(np.asarray(msg.data, dtype=np.int64), int(msg.layout.data_offset))
    return np.frombuffer(raw, dtype="<i4", count=n, offset=start).astype(np.int64)


def parse_int32(raw: bytes | memoryview) -> int:
    """Value of one ``std_msgs/Int32``."""
    if len(raw) == 8 and bytes(raw[:4]) == CDR_LE_HEADER:
        return int(_I32.unpack_from(raw, 4)[0])
    return int(deserialize(raw, layout.INT32).data)


def stack_float32_arrays(
    raws: Sequence[bytes | memoryview],
    *,
    expected_dim: int | None = None,
    path: str | None = None,
    topic: str | None = None,
    stamps: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """Stack many ``Float32MultiArray`` messages into a float32 ``[N, D]`` array.

    Fast path: when every message has the same byte length and the same header/layout prefix
    (always true for one topic of our bags), the messages are joined and viewed with a single
    ``np.frombuffer``.  Otherwise each message is parsed and the first one whose length differs
    raises :class:`VectorLengthError` naming ``path``/``topic`` and its index.
    """
    n_msgs = len(raws)
    if n_msgs == 0:
        return np.zeros((0, expected_dim or 0), dtype=np.float32)
    first = raws[0]
    try:
        start, dim = multiarray_data_start(first)
    except (ValueError, struct.error):  # not our little-endian layout: decode message by message
        start, dim = -1, len(parse_float32_array_checked(first, path, topic, 0, stamps))
    if expected_dim is not None and dim != expected_dim:
        raise VectorLengthError(f"vector has {dim} elements, expected {expected_dim}",
                                path=path, topic=topic, index=0,
                                stamp=None if stamps is None else int(stamps[0]))
    size = len(first)
    if start >= 0 and all(len(r) == size for r in raws):
        block = np.frombuffer(b"".join(raws), dtype="<u4").reshape(n_msgs, size // 4)
        prefix_words = start // 4
        prefix = block[:, :prefix_words]
        if np.array_equal(prefix, np.broadcast_to(prefix[0], prefix.shape)):
            return block[:, prefix_words:].view("<f4").astype(np.float32)
    out = np.empty((n_msgs, dim), dtype=np.float32)
    for i, raw in enumerate(raws):
        vec = parse_float32_array_checked(raw, path, topic, i, stamps)
        if len(vec) != dim:
            raise VectorLengthError(
                f"vector has {len(vec)} elements, expected {dim}"
                + ("" if expected_dim is not None else " (the length of the topic's first message)"),
                path=path, topic=topic, index=i, stamp=None if stamps is None else int(stamps[i]),
            )
        out[i] = vec
    return out


def parse_float32_array_checked(
    raw: bytes | memoryview, path: str | None, topic: str | None, index: int,
    stamps: Sequence[int] | np.ndarray | None,
) -> np.ndarray:
    """:func:`parse_float32_array` raising :class:`CorruptBagError` on undecodable bytes."""
    try:
        return parse_float32_array(raw)
    except Exception as err:  # rosbags raises several types on bad CDR
        raise CorruptBagError(f"cannot decode Float32MultiArray: {err}", path=path, topic=topic,
                              index=index, stamp=None if stamps is None else int(stamps[index])) from err


def stack_int32(
    raws: Sequence[bytes | memoryview],
    *,
    path: str | None = None,
    topic: str | None = None,
    stamps: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """Values of many ``std_msgs/Int32`` messages as int64 ``[N]`` (one ``np.frombuffer`` call)."""
    n_msgs = len(raws)
    if n_msgs == 0:
        return np.zeros(0, dtype=np.int64)
    if all(len(r) == 8 for r in raws):
        block = np.frombuffer(b"".join(raws), dtype="<i4").reshape(n_msgs, 2)
        if np.all(block[:, 0] == block[0, 0]) and bytes(raws[0][:4]) == CDR_LE_HEADER:
            return block[:, 1].astype(np.int64)
    out = np.empty(n_msgs, dtype=np.int64)
    for i, raw in enumerate(raws):
        try:
            out[i] = parse_int32(raw)
        except Exception as err:
            raise CorruptBagError(f"cannot decode Int32: {err}", path=path, topic=topic, index=i,
                                  stamp=None if stamps is None else int(stamps[i])) from err
    return out


def _align(pos: int, n: int) -> int:
    """CDR alignment (relative to the payload after the 4-byte encapsulation header)."""
    return 4 + ((pos - 4 + n - 1) // n) * n


def _joint_state_layout(raw: bytes | memoryview) -> tuple[list[str], list[tuple[int, int]],
                                                            dict[str, tuple[int, int]]]:
    """Parse one little-endian JointState CDR: joint names, structural byte ranges (lengths,
    strings: everything but stamp, padding and float data) and ``field -> (offset, count)``.

    Unlike ``rosbags`` this accepts the trailing padding Fast CDR (rclpy/rclcpp) writes after an
    empty last array (rosbags raises "CDR message size mismatch" on such messages)."""
    if bytes(raw[:4]) != CDR_LE_HEADER:
        raise ValueError("not a little-endian CDR message")
    struct_ranges: list[tuple[int, int]] = []
    pos = 12  # header.stamp (sec, nanosec) occupies bytes 4..12
    (flen,) = _U32.unpack_from(raw, pos)
    struct_ranges.append((pos, pos + 4 + flen))
    pos += 4 + flen
    pos = _align(pos, 4)
    (count,) = _U32.unpack_from(raw, pos)
    struct_ranges.append((pos, pos + 4))
    pos += 4
    names = []
    for _ in range(count):
        pos = _align(pos, 4)
        (slen,) = _U32.unpack_from(raw, pos)
        struct_ranges.append((pos, pos + 4 + slen))
        names.append(bytes(raw[pos + 4:pos + 3 + slen]).decode())
        pos += 4 + slen
    fields: dict[str, tuple[int, int]] = {}
    for name in ("position", "velocity", "effort"):
        pos = _align(pos, 4)
        (count,) = _U32.unpack_from(raw, pos)
        struct_ranges.append((pos, pos + 4))
        pos += 4
        if count:
            pos = _align(pos, 8)
        fields[name] = (pos, count)
        pos += 8 * count
    if pos > len(raw) or len(raw) - pos >= 16:  # rclpy/Fast CDR appends up to 12 padding bytes
        raise ValueError(f"JointState CDR length {len(raw)} does not match its layout ({pos} bytes)")
    return names, struct_ranges, fields


def stack_joint_states(
    raws: Sequence[bytes | memoryview],
) -> tuple[list[str], np.ndarray, dict[str, np.ndarray]] | None:
    """Bulk-decode JointState messages that share one layout (same joints, same array sizes).

    Returns ``(names, header_stamps_ns [N], {field: float64 [N, count]})``, or ``None`` when the
    messages differ in structure (callers then decode message by message).  Padding bytes are
    ignored (rclpy's serializer leaves them uninitialised), everything else is checked.
    """
    if not raws:
        return None
    try:
        names, struct_ranges, fields = _joint_state_layout(raws[0])
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    size = len(raws[0])
    if any(len(r) != size for r in raws):
        return None
    block = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(len(raws), size)
    for a, b in struct_ranges:
        part = block[:, a:b]
        if not np.array_equal(part, np.broadcast_to(part[0], part.shape)):
            return None
    sec = np.ascontiguousarray(block[:, 4:8]).view("<i4")[:, 0].astype(np.int64)
    nsec = np.ascontiguousarray(block[:, 8:12]).view("<u4")[:, 0].astype(np.int64)
    out = {}
    for name, (offset, count) in fields.items():
        data = np.ascontiguousarray(block[:, offset:offset + 8 * count])
        out[name] = data.view("<f8").reshape(len(raws), count)
    return names, sec * 1_000_000_000 + nsec, out


def parse_joint_state(raw: bytes | memoryview) -> tuple[list[str], int, dict[str, np.ndarray]]:
    """One JointState: ``(names, header_stamp_ns, {field: float64 [count]})``."""
    try:
        names, _, fields = _joint_state_layout(raw)
    except (ValueError, struct.error, UnicodeDecodeError):
        msg = deserialize(raw, layout.JOINT_STATE)  # big-endian or otherwise unusual bytes
        fields_ = ("position", "velocity", "effort")
        return (list(msg.name), stamp_to_ns(msg.header.stamp),
                {f: np.asarray(getattr(msg, f), dtype=np.float64) for f in fields_})
    sec = _I32.unpack_from(raw, 4)[0]
    nsec = _U32.unpack_from(raw, 8)[0]
    values = {f: np.frombuffer(raw, dtype="<f8", count=n, offset=o).astype(np.float64)
              for f, (o, n) in fields.items()}
    return names, sec * 1_000_000_000 + nsec, values
