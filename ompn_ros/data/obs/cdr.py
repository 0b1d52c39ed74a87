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
MAX_PADDING = 7
"""Trailing bytes accepted after the last field (rclpy/Fast CDR may pad the serialized size)."""


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
    """Data of one ``std_msgs/Float64MultiArray`` as float64."""
    if not _little_endian(raw):
        return np.asarray(m.deserialize(raw, "std_msgs/msg/Float64MultiArray").data, dtype=np.float64)
    pos = 4
    (ndim,) = _U32.unpack_from(raw, pos)
    pos += 4
    if ndim > 64:
        raise ValueError(f"implausible number of dimensions {ndim}")
    for _ in range(ndim):
        (slen,) = _U32.unpack_from(raw, pos)
        pos = _align(pos + 4 + slen, 4) + 8  # label, then size and stride
    (n,) = _U32.unpack_from(raw, pos + 4)  # after data_offset
    pos += 8
    if n:
        pos = _align(pos, 8)
    _check_end(raw, pos + 8 * n, "Float64MultiArray")
    return np.frombuffer(raw, dtype="<f8", count=n, offset=pos).astype(np.float64)


def parse_stamped_doubles(raw: bytes | memoryview, count: int, typename: str) -> tuple[int, np.ndarray]:
    """``(header_stamp_ns, float64 [count])`` of a message made of a Header and ``count`` float64
    (``WrenchStamped``: force xyz, torque xyz; ``PoseStamped``: position xyz, orientation xyzw)."""
    if not _little_endian(raw):
        return _stamped_doubles_fallback(raw, typename)
    stamp = header_stamp(raw)
    (flen,) = _U32.unpack_from(raw, 12)
    pos = _align(16 + flen, 8)
    _check_end(raw, pos + 8 * count, typename.rsplit("/", 1)[-1])
    return stamp, np.frombuffer(raw, dtype="<f8", count=count, offset=pos).astype(np.float64)


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
