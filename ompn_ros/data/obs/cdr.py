"""Fast little-endian CDR parsers for the observation message types ``messages.py`` has no fast path for.

``Float64MultiArray``, ``WrenchStamped``, ``PoseStamped``, ``Float32`` and ``Float64`` are read in
place (``struct``/``np.frombuffer``, no message object); anything else (big-endian or unusual bytes)
falls back to the ``rosbags`` typestore.  Layouts (offsets after the 4-byte encapsulation header,
alignment relative to it)::

    Float64MultiArray   u32 n_dims, dims (u32 len, label+NUL, pad 4, u32 size, u32 stride),
                        u32 data_offset, u32 n, pad 8, n x f64
    WrenchStamped       i32 sec, u32 nanosec, u32 len + frame_id + NUL, pad 8, 6 x f64
    PoseStamped         i32 sec, u32 nanosec, u32 len + frame_id + NUL, pad 8, 7 x f64
    Float32 / Float64   f32 / (pad 8) f64

Every parser raises ``ValueError`` (or ``struct.error``) on bytes that do not fit the layout, or
whatever ``rosbags`` raises in the fallback; callers treat any exception as a malformed message.
Complexity: O(message size).
"""

from __future__ import annotations

import struct

import numpy as np

from ompn_ros.data import messages as m

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
MAX_PADDING = 31
"""Trailing bytes accepted after the last field: rclpy/Fast CDR size the buffer with an 8-byte alignment
for every float64 sequence, written or empty (a JointState with names only ends 12 bytes early)."""


def _little_endian(raw: bytes | memoryview) -> bool:
    return bytes(raw[:4]) == m.CDR_LE_HEADER


def _align(pos: int, n: int) -> int:
    return 4 + ((pos - 4 + n - 1) // n) * n


def _check_end(raw: bytes | memoryview, end: int, what: str) -> None:
    if end > len(raw) or len(raw) - end > MAX_PADDING:
        raise ValueError(f"{what} CDR length {len(raw)} does not match its layout ({end} bytes)")


def header_stamp(raw: bytes | memoryview) -> int:
    """``header.stamp`` (ns) of a little-endian message that starts with a ``std_msgs/Header``."""
    sec, nsec = _STAMP.unpack_from(raw, 4)
    if nsec >= 1_000_000_000:
        raise ValueError(f"header.stamp.nanosec {nsec} is not below 1e9")
    return int(sec) * 1_000_000_000 + int(nsec)


def parse_float64_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``std_msgs/Float64MultiArray`` as float64 (a read-only view into ``raw``); the
    ``layout.data_offset`` padding elements at the front of ``data`` are not elements of the array
    (std_msgs/MultiArrayLayout): they are skipped, by the bag reader and the live node alike."""
    if not _little_endian(raw):
        msg = m.deserialize(raw, "std_msgs/msg/Float64MultiArray")
        return m.after_data_offset(np.asarray(msg.data, dtype=np.float64), int(msg.layout.data_offset))
    pos = 4
    (ndim,) = _U32.unpack_from(raw, pos)
    pos += 4
    if ndim > 64:
        raise ValueError(f"implausible number of dimensions {ndim}")
    for _ in range(ndim):
        (slen,) = _U32.unpack_from(raw, pos)
        pos = _align(pos + 4 + slen, 4) + 8  # label, then size and stride
    offset, n = struct.unpack_from("<II", raw, pos)
    pos += 8
    if n:
        pos = _align(pos, 8)
    _check_end(raw, pos + 8 * n, "Float64MultiArray")
    return m.after_data_offset(np.frombuffer(raw, dtype="<f8", count=n, offset=pos), offset)



def parse_stamped_doubles(raw: bytes | memoryview, count: int, typename: str) -> tuple[int, np.ndarray]:
    """``(header_stamp_ns, float64 [count])`` of a message made of a Header and ``count`` float64
    (``WrenchStamped``: force xyz, torque xyz; ``PoseStamped``: position xyz, orientation xyzw).
    The vector is a read-only view into ``raw``."""
    if not _little_endian(raw):
        return _stamped_doubles_fallback(raw, typename)
    stamp = header_stamp(raw)
    (flen,) = _U32.unpack_from(raw, 12)
    pos = _align(16 + flen, 8)
    _check_end(raw, pos + 8 * count, typename.rsplit("/", 1)[-1])
    return stamp, np.frombuffer(raw, dtype="<f8", count=count, offset=pos)


def _stamped_doubles_fallback(raw: bytes | memoryview, typename: str) -> tuple[int, np.ndarray]:
    msg = m.deserialize(raw, typename)
    stamp = m.stamp_to_ns(msg.header.stamp)
    if typename.endswith("WrenchStamped"):
        f, t = msg.wrench.force, msg.wrench.torque
        values = [f.x, f.y, f.z, t.x, t.y, t.z]
    else:
        p, q = msg.pose.position, msg.pose.orientation
        values = [p.x, p.y, p.z, q.x, q.y, q.z, q.w]
    return stamp, np.asarray(values, dtype=np.float64)


def parse_float32(raw: bytes | memoryview) -> float:
    """Value of one ``std_msgs/Float32``."""
    if _little_endian(raw):
        _check_end(raw, 8, "Float32")
        return float(_F32.unpack_from(raw, 4)[0])
    return float(m.deserialize(raw, "std_msgs/msg/Float32").data)


def parse_float64(raw: bytes | memoryview) -> float:
    """Value of one ``std_msgs/Float64``."""
    if _little_endian(raw):
        _check_end(raw, 12, "Float64")
        return float(_F64.unpack_from(raw, 4)[0])
    return float(m.deserialize(raw, "std_msgs/msg/Float64").data)


JOINT_FIELDS = ("position", "velocity", "effort")


class JointStateParser:
    """``sensor_msgs/JointState`` reader that remembers the last message's layout.

    A driver publishes the same joints in every message, so after the first message the joint names,
    array sizes and offsets are known: a message of the same length with the same bytes from
    ``frame_id`` to the last name and the same array counts is read with three ``np.frombuffer``
    views (the returned ``names`` tuple is then the same object as before).  Other messages are
    parsed fully (big-endian or otherwise unusual bytes through the ``rosbags`` typestore).
    """

    def __init__(self) -> None:
        self._len = -1
        self._key = b""
        self._names: tuple[str, ...] = ()
        self._counts: tuple[tuple[int, int], ...] = ()  # (offset of a u32 count, its value)
        self._fields: dict[str, tuple[int, int]] = {}  # field -> (offset, count)

    def parse(self, raw: bytes | memoryview) -> tuple[int, dict[str, np.ndarray], tuple[str, ...]]:
        """``(header stamp ns, {field: float64 [count]}, joint names)``."""
        end = 12 + len(self._key)
        if (len(raw) == self._len and raw[12:end] == self._key
                and all(_U32.unpack_from(raw, p)[0] == c for p, c in self._counts)):
            return header_stamp(raw), self._views(raw), self._names
        if not _little_endian(raw):
            names, stamp, values = m.parse_joint_state(raw)
            return stamp, values, tuple(names)
        self._learn(raw)
        return header_stamp(raw), self._views(raw), self._names

    def _views(self, raw: bytes | memoryview) -> dict[str, np.ndarray]:
        return {f: np.frombuffer(raw, dtype="<f8", count=n, offset=o) for f, (o, n) in self._fields.items()}

    def _learn(self, raw: bytes | memoryview) -> None:
        self._len = -1  # invalid until the whole layout is read
        pos = 12
        (flen,) = _U32.unpack_from(raw, pos)
        pos = _align(pos + 4 + flen, 4)
        (count,) = _U32.unpack_from(raw, pos)
        if count > 100_000:
            raise ValueError(f"implausible number of joints {count}")
        pos += 4
        names = []
        for _ in range(count):
            pos = _align(pos, 4)
            (slen,) = _U32.unpack_from(raw, pos)
            if slen == 0 or pos + 4 + slen > len(raw):
                raise ValueError("joint name runs past the message")
            names.append(bytes(raw[pos + 4:pos + 3 + slen]).decode())
            pos += 4 + slen
        key_end = pos
        counts, fields = [], {}
        for name in JOINT_FIELDS:
            pos = _align(pos, 4)
            (n,) = _U32.unpack_from(raw, pos)
            counts.append((pos, n))
            pos += 4
            if n:
                pos = _align(pos, 8)
            fields[name] = (pos, n)
            pos += 8 * n
        _check_end(raw, pos, "JointState")
        self._key, self._names = bytes(raw[12:key_end]), tuple(names)
        self._counts, self._fields, self._len = tuple(counts), fields, len(raw)
