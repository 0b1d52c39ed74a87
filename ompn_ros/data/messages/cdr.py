"""CDR framing shared by every encoder and parser of the package (ROS-free).

* **Encapsulation header**: 4 bytes.  Bytes 0–1 give the representation (``00 01``: little-endian
  CDR, the one the encoders write and the fast parsers read); bytes 2–3 are options, written as
  ``00 00`` and ignored when read (DDS uses them for the payload's padding count).  Big-endian
  messages (``00 00``) are decoded by the ``rosbags`` typestore (:func:`deserialize`), under the same
  length rule.
* **Alignment**: an ``n``-byte primitive starts at a multiple of ``n`` counted from the end of the
  header; padding is written as zeros and never read.
* **Length rule** (:func:`check_end`, every parser): a message must hold every field of its layout,
  else :class:`CdrError` "… ends inside <field>"; after the last field at most :data:`MAX_TRAILING`
  bytes may follow, else :class:`CdrError` "… bytes after the last field".
* **Stamps**: ``builtin_interfaces/Time`` is ``(int32 sec, uint32 nanosec)``; :func:`split_stamp` and
  :func:`join_stamp` refuse what does not fit with :class:`StampRangeError`.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import lru_cache
from typing import Any, Final

import numpy as np

from ompn_ros.errors import OMPNError

CDR_LE_HEADER: Final = b"\x00\x01\x00\x00"
LITTLE_ENDIAN: Final = CDR_LE_HEADER[:2]
"""The representation bytes of little-endian CDR (the options after them are ignored)."""
MAX_TRAILING: Final = 12
"""Bytes accepted after the last field.  Fast CDR (rclpy, rclcpp, hence rosbag2) sizes a message with an
8-byte alignment before every float64 sequence, written or empty, and keeps that size: up to 4 bytes
per float64 sequence (12 for a ``JointState``'s three) end a message it writes; DDS rounds a payload
to 4 bytes (up to 3).  ``rosbags`` writes none."""
U32: Final = struct.Struct("<I")
I32: Final = struct.Struct("<i")
STAMP: Final = struct.Struct("<iI")
INT32_MIN: Final = -(2**31)
INT32_MAX: Final = 2**31 - 1
STAMP_NS_MIN: Final = INT32_MIN * 1_000_000_000
STAMP_NS_MAX: Final = INT32_MAX * 1_000_000_000 + 999_999_999


class CdrError(OMPNError, ValueError):
    """Bytes that are not a message of the expected type: one line naming the type and the field."""


class StampRangeError(OMPNError, ValueError):
    """A stamp does not fit ``builtin_interfaces/Time`` (int32 seconds, nanoseconds below 1e9)."""


def little_endian(raw: bytes | memoryview) -> bool:
    """Whether ``raw`` starts with the little-endian CDR encapsulation (options ignored)."""
    return raw[:2] == LITTLE_ENDIAN


def align(pos: int, n: int) -> int:
    """``pos`` (a byte offset in the message) moved up to the next ``n``-byte boundary of the body."""
    return 4 + ((pos - 4 + n - 1) // n) * n


def too_short(what: str, field: str, size: int) -> CdrError:
    """The error of a ``what`` message of ``size`` bytes that ends before ``field`` is complete."""
    return CdrError(f"{what} CDR of {size} bytes ends inside {field}")


def check_end(raw: bytes | memoryview, end: int, what: str, field: str) -> None:
    """The length rule: ``raw`` holds its last field (``field``, ending at byte ``end``) and at most
    :data:`MAX_TRAILING` bytes after it; :class:`CdrError` otherwise."""
    if end > len(raw):
        raise too_short(what, field, len(raw))
    if len(raw) - end > MAX_TRAILING:
        raise CdrError(f"{what} CDR of {len(raw)} bytes has {len(raw) - end} bytes after the last field "
                       f"{field} (at most {MAX_TRAILING})")


# --- stamps ---------------------------------------------------------------------------------------
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


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


# --- the rosbags typestore ------------------------------------------------------------------------
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
    """Decode CDR bytes of ``typename`` (either byte order) into a ``rosbags`` message object, under
    the length rule of :func:`check_end`; :class:`CdrError` naming the type otherwise."""
    from rosbags.serde import SerdeError

    what = typename.rsplit("/", 1)[-1]
    if len(raw) < 4 or raw[:2] not in (b"\0\0", b"\0\1"):
        raise CdrError(f"{what} CDR of {len(raw)} bytes does not start with a CDR encapsulation header")
    store = typestore()
    msgdef = store.get_msgdef(typename)
    decode = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    try:
        message, pos = decode(raw[4:], 0, msgdef.cls, store)
    except (struct.error, SerdeError) as err:  # SerdeError: a string or sequence past the end
        raise too_short(what, "a field", len(raw)) from err
    except (UnicodeDecodeError, ValueError) as err:
        raise CdrError(f"{what} CDR of {len(raw)} bytes: {err}") from err
    check_end(raw, pos + 4, what, "the last field")
    return message


# --- writing --------------------------------------------------------------------------------------
class CdrWriter:
    """Little-endian CDR writer: the header, then fields aligned relative to its end."""

    def __init__(self) -> None:
        self.out = bytearray(CDR_LE_HEADER)

    def _align(self, n: int) -> None:
        self.out += b"\0" * (-(len(self.out) - 4) % n)

    def u32(self, value: int) -> None:
        self._align(4)
        self.out += U32.pack(value)

    def i32(self, value: int) -> None:
        self._align(4)
        self.out += I32.pack(value)

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
