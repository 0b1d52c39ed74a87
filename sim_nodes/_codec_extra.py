"""CDR encoders the sims need beyond :mod:`ompn_ros.data.messages` (ROS-free, byte-tested).

Each function returns the little-endian CDR bytes (4-byte encapsulation header first) of one message,
exactly what ``rosbags``' serializer writes for the same values; an rclpy publisher sends such ``bytes``
as an already serialized message.  Alignment follows CDR: every primitive is aligned to its size,
relative to the end of the encapsulation header; an empty float64 sequence adds no 8-byte padding.

The fixed part of a message (joint names, labels, array sizes) is encoded once and cached, so that the
per-step cost is a few ``bytes`` joins (``sensor_msgs/JointState`` with 9 joints: ~3 µs).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from ompn_ros.data.messages import CDR_LE_HEADER

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_NS_PER_S = 1_000_000_000


class _Writer:
    """Little-endian CDR body with alignment relative to the end of the encapsulation header."""

    def __init__(self, start: int = 0) -> None:
        self.out = bytearray()
        self.pos = start  # body offset of out[0]

    def align(self, n: int) -> None:
        pad = -(self.pos + len(self.out)) % n
        self.out += b"\0" * pad

    def u32(self, value: int) -> None:
        self.align(4)
        self.out += _U32.pack(value)

    def string(self, text: str) -> None:
        data = text.encode() + b"\0"
        self.u32(len(data))
        self.out += data

    def end(self) -> int:
        return self.pos + len(self.out)


def _stamp(stamp_ns: int) -> bytes:
    """``builtin_interfaces/Time`` fields (int32 sec, uint32 nanosec) of ``stamp_ns``."""
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    return _STAMP.pack(sec, nanosec)


def encode_clock(stamp_ns: int) -> bytes:
    """CDR of ``rosgraph_msgs/Clock`` at ``stamp_ns`` (what ``/clock`` carries)."""
    return CDR_LE_HEADER + _stamp(stamp_ns)


def encode_string(text: str) -> bytes:
    """CDR of ``std_msgs/String``."""
    w = _Writer()
    w.string(text)
    return CDR_LE_HEADER + bytes(w.out)


@lru_cache(maxsize=16)
def _joint_state_parts(names: tuple[str, ...], sizes: tuple[int, int, int]) -> tuple[bytes, bytes, bytes]:
    """The constant bytes of a JointState after its stamp: (up to the position data, between position
    and velocity data, between velocity and effort data).  Stamps occupy body bytes 0..8."""
    w = _Writer(start=8)
    w.string("")  # header.frame_id
    w.u32(len(names))
    for name in names:
        w.string(name)
    parts = []
    for count in sizes:
        w.u32(count)
        if count:
            w.align(8)
        parts.append(bytes(w.out))
        w = _Writer(start=w.end() + 8 * count)
    return parts[0], parts[1], parts[2]


def encode_joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: np.ndarray | Sequence[float] = (),
    velocity: np.ndarray | Sequence[float] = (),
    effort: np.ndarray | Sequence[float] = (),
) -> bytes:
    """CDR of ``sensor_msgs/JointState`` stamped at ``stamp_ns`` (empty ``frame_id``).

    The same bytes as ``messages.serialize(messages.joint_state(...))``, without a message object.
    """
    arrays = [np.ascontiguousarray(a, dtype="<f8").reshape(-1) for a in (position, velocity, effort)]
    sizes = (int(arrays[0].size), int(arrays[1].size), int(arrays[2].size))
    head, mid, tail = _joint_state_parts(tuple(names), sizes)
    return b"".join((CDR_LE_HEADER, _stamp(stamp_ns), head, arrays[0].tobytes(), mid, arrays[1].tobytes(),
                     tail, arrays[2].tobytes()))


@lru_cache(maxsize=32)
def _multiarray_prefix(label: str, n: int, element_size: int) -> bytes:
    """CDR body of a one-dimension MultiArray up to its first element: dim (label, n, n), data_offset
    0, element count n, then the padding that aligns the elements."""
    w = _Writer()
    w.u32(1)
    w.string(label)
    for value in (n, n, 0, n):  # size, stride, data_offset, element count
        w.u32(value)
    if n:
        w.align(element_size)
    return bytes(w.out)


def encode_int32_array(values: np.ndarray | Sequence[int], label: str = "sketch") -> bytes:
    """CDR of ``std_msgs/Int32MultiArray`` with one dimension ``(label, n, n)``."""
    data = np.ascontiguousarray(values, dtype="<i4").reshape(-1)
    return CDR_LE_HEADER + _multiarray_prefix(label, int(data.size), 4) + data.tobytes()


def encode_float64_array(values: np.ndarray | Sequence[float], label: str) -> bytes:
    """CDR of ``std_msgs/Float64MultiArray`` with one dimension ``(label, n, n)``."""
    data = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
    return CDR_LE_HEADER + _multiarray_prefix(label, int(data.size), 8) + data.tobytes()
