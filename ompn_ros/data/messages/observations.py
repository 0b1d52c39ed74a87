"""Fast parsers of the per-step messages: observations, actions and the multi-topic observation rule.

Little-endian messages are read in place (``struct``/``np.frombuffer``, no message object) under the
framing and length rule of :mod:`.cdr`; big-endian ones go through the ``rosbags`` typestore under the
same rule.  Every parser raises :class:`~.cdr.CdrError` on bytes that do not fit its type.  Layouts
(offsets after the 4-byte header, alignment relative to it)::

    Float32/Int32/Float64MultiArray
                        u32 n_dims, dims (u32 len, label+NUL, pad 4, u32 size, u32 stride),
                        u32 data_offset, u32 n, (pad 8 for float64) n x element
    JointState          i32 sec, u32 nanosec, u32 len + frame_id + NUL, u32 n + n names (pad 4),
                        then position, velocity, effort: u32 n, (pad 8) n x f64 each
    WrenchStamped       i32 sec, u32 nanosec, u32 len + frame_id + NUL, pad 8, 6 x f64
    PoseStamped         i32 sec, u32 nanosec, u32 len + frame_id + NUL, pad 8, 7 x f64
    Int32 / Float32 / Float64   i32 / f32 / (pad 8) f64

``layout.data_offset`` elements at the front of a MultiArray's ``data`` are not elements of the array
(std_msgs/MultiArrayLayout): every parser skips them.  Complexity: O(message size).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Final, NamedTuple

import numpy as np

from ompn_ros import layout

from ..errors import CorruptBagError, VectorLengthError
from .cdr import (
    CDR_LE_HEADER,
    I32,
    LITTLE_ENDIAN,
    MAX_TRAILING,
    STAMP,
    U32,
    CdrError,
    align,
    check_end,
    deserialize,
    little_endian,
    stamp_to_ns,
    too_short,
)

_U32_PAIR = struct.Struct("<II")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_JOINT_STATE: Final = layout.JOINT_STATE


def _short(typename: str) -> str:
    """``std_msgs/msg/Float64`` -> ``Float64`` (the name errors use)."""
    return typename[typename.rfind("/") + 1:]


# --- MultiArrays ----------------------------------------------------------------------------------
def after_data_offset(data: np.ndarray, data_offset: int, what: str) -> np.ndarray:
    """``data`` without the ``layout.data_offset`` padding elements at its front."""
    if data_offset > len(data):
        raise CdrError(f"{what} layout.data_offset {data_offset} exceeds the {len(data)} data elements")
    return data[data_offset:]


def multiarray_data(raw: bytes | memoryview, itemsize: int, typename: str) -> tuple[int, int]:
    """``(offset of the first element, element count)`` of a little-endian MultiArray ``typename`` whose
    elements have ``itemsize`` bytes, ``layout.data_offset`` padding skipped; :class:`CdrError` otherwise."""
    size, field = len(raw), "layout.dim"
    try:
        (ndim,) = U32.unpack_from(raw, 4)
        pos = 8
        if ndim > (size - pos) // 12:  # a dimension takes 12 bytes at least
            raise too_short(_short(typename), field, size)
        for _ in range(ndim):
            (slen,) = U32.unpack_from(raw, pos)
            pos = ((pos + slen + 7) & ~3) + 8  # label (u32 length, bytes, pad to 4), size and stride
        field = "data"
        offset, n = _U32_PAIR.unpack_from(raw, pos)
    except struct.error:
        raise too_short(_short(typename), field, size) from None
    pos += 8
    if n and itemsize == 8:
        pos = align(pos, 8)
    end = pos + itemsize * n
    if end > size or size - end > MAX_TRAILING:
        check_end(raw, end, _short(typename), "data")
    if offset > n:
        raise CdrError(f"{_short(typename)} layout.data_offset {offset} exceeds the {n} data elements")
    return pos + itemsize * offset, n - offset


def _multiarray(raw: bytes | memoryview, typename: str, dtype: str, itemsize: int) -> np.ndarray:
    """The elements of one MultiArray: a read-only view into little-endian ``raw``, else the
    typestore's array."""
    if raw[:2] == LITTLE_ENDIAN:
        start, n = multiarray_data(raw, itemsize, typename)
        return np.frombuffer(raw, dtype=dtype, count=n, offset=start)
    msg = deserialize(raw, typename)
    return after_data_offset(np.asarray(msg.data), int(msg.layout.data_offset), _short(typename))


def parse_float32_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``Float32MultiArray`` as a float32 vector (a copy)."""
    return _multiarray(raw, layout.FLOAT32_ARRAY, "<f4", 4).astype(np.float32)


def parse_int32_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``Int32MultiArray`` as an int64 vector."""
    return _multiarray(raw, layout.INT32_ARRAY, "<i4", 4).astype(np.int64)


def parse_float64_array(raw: bytes | memoryview) -> np.ndarray:
    """Data of one ``std_msgs/Float64MultiArray`` as float64 (a read-only view into little-endian
    ``raw``), for the bag reader and the live node alike."""
    return np.asarray(_multiarray(raw, layout.FLOAT64_ARRAY, "<f8", 8), dtype=np.float64)


# --- scalars --------------------------------------------------------------------------------------
def _scalar(raw: bytes | memoryview, fmt: struct.Struct, end: int, typename: str) -> float | int:
    if raw[:2] == LITTLE_ENDIAN:
        if len(raw) < end or len(raw) - end > MAX_TRAILING:
            check_end(raw, end, _short(typename), "data")
        return fmt.unpack_from(raw, end - fmt.size)[0]  # type: ignore[no-any-return]
    return deserialize(raw, typename).data  # type: ignore[no-any-return]


def parse_int32(raw: bytes | memoryview) -> int:
    """Value of one ``std_msgs/Int32``."""
    return int(_scalar(raw, I32, 8, layout.INT32))


def parse_float32(raw: bytes | memoryview) -> float:
    """Value of one ``std_msgs/Float32``."""
    return float(_scalar(raw, _F32, 8, layout.FLOAT32))


def parse_float64(raw: bytes | memoryview) -> float:
    """Value of one ``std_msgs/Float64``."""
    return float(_scalar(raw, _F64, 12, layout.FLOAT64))


# --- stamped messages -----------------------------------------------------------------------------
def header_stamp(raw: bytes | memoryview, typename: str) -> int:
    """``header.stamp`` (ns) of a little-endian message that starts with a ``std_msgs/Header``."""
    try:
        sec, nsec = STAMP.unpack_from(raw, 4)
    except struct.error:
        raise too_short(_short(typename), "header.stamp", len(raw)) from None
    if nsec >= 1_000_000_000:
        raise CdrError(f"{_short(typename)} header.stamp.nanosec {nsec} is not below 1e9")
    return int(sec) * 1_000_000_000 + int(nsec)


def parse_stamped_doubles(raw: bytes | memoryview, count: int, typename: str) -> tuple[int, np.ndarray]:
    """``(header_stamp_ns, float64 [count])`` of a message made of a Header and ``count`` float64
    (``WrenchStamped``: force xyz, torque xyz; ``PoseStamped``: position xyz, orientation xyzw).
    The vector is a read-only view into little-endian ``raw``."""
    if not little_endian(raw):
        return _stamped_doubles_typestore(raw, typename)
    stamp = header_stamp(raw, typename)
    try:
        (flen,) = U32.unpack_from(raw, 12)
    except struct.error:
        raise too_short(_short(typename), "header.frame_id", len(raw)) from None
    pos = align(16 + flen, 8)
    end, size = pos + 8 * count, len(raw)
    if end > size or size - end > MAX_TRAILING:
        check_end(raw, end, _short(typename), _short(typename).removesuffix("Stamped").lower())
    return stamp, np.frombuffer(raw, dtype="<f8", count=count, offset=pos)


def _stamped_doubles_typestore(raw: bytes | memoryview, typename: str) -> tuple[int, np.ndarray]:
    msg = deserialize(raw, typename)
    stamp = stamp_to_ns(msg.header.stamp)
    if typename == layout.WRENCH_STAMPED:
        f, t = msg.wrench.force, msg.wrench.torque
        values = [f.x, f.y, f.z, t.x, t.y, t.z]
    else:
        p, q = msg.pose.position, msg.pose.orientation
        values = [p.x, p.y, p.z, q.x, q.y, q.z, q.w]
    return stamp, np.asarray(values, dtype=np.float64)


# --- JointState -----------------------------------------------------------------------------------
class JointStateLayout(NamedTuple):
    """Where the fields of one little-endian ``JointState`` CDR are."""

    names: list[str]
    key_end: int
    """Bytes ``12:key_end`` hold ``header.frame_id`` and the names."""
    structure: list[tuple[int, int]]
    """Byte ranges of lengths, counts and strings: everything but the stamp, padding and float data."""
    counts: list[tuple[int, int]]
    """``(offset of each array's u32 count, its value)``, position, velocity, effort."""
    fields: dict[str, tuple[int, int]]
    """``field -> (offset, count)`` of the float64 data."""


def joint_state_layout(raw: bytes | memoryview) -> JointStateLayout:
    """The layout of one little-endian ``JointState`` CDR; :class:`CdrError` naming the field at fault.

    Padding is never read (rclpy's serializer leaves it uninitialised)."""
    size, field = len(raw), "header.frame_id"
    structure: list[tuple[int, int]] = []
    names: list[str] = []
    try:
        pos = 12  # header.stamp occupies bytes 4..12
        (flen,) = U32.unpack_from(raw, pos)
        structure.append((pos, pos + 4 + flen))
        pos, field = align(pos + 4 + flen, 4), "name"
        (count,) = U32.unpack_from(raw, pos)
        if count > (size - pos - 4) // 5:  # a name takes 5 bytes at least
            raise too_short("JointState", field, size)
        structure.append((pos, pos + 4))
        pos += 4
        for i in range(count):
            pos = (pos + 3) & ~3  # 4-byte alignment (the header is 4 bytes long)
            (slen,) = U32.unpack_from(raw, pos)
            if slen == 0 or pos + 4 + slen > size:
                raise too_short("JointState", f"name[{i}]", size)
            structure.append((pos, pos + 4 + slen))
            names.append(bytes(raw[pos + 4:pos + 3 + slen]).decode())
            pos += 4 + slen
        key_end, counts, fields, field = pos, [], {}, "position"
        for field in layout.JOINT_FIELDS:
            pos = (pos + 3) & ~3
            (n,) = U32.unpack_from(raw, pos)
            counts.append((pos, n))
            structure.append((pos, pos + 4))
            pos += 4
            if n:
                pos = align(pos, 8)
            fields[field] = (pos, n)
            pos += 8 * n
            if pos > size:
                raise too_short("JointState", field, size)
    except struct.error:  # a length or count word lies past the end
        raise too_short("JointState", field, size) from None
    except UnicodeDecodeError as err:
        raise CdrError(f"JointState name[{len(names)}] is not UTF-8: {err}") from None
    check_end(raw, pos, "JointState", "effort")
    return JointStateLayout(names, key_end, structure, counts, fields)


def parse_joint_state(raw: bytes | memoryview) -> tuple[list[str], int, dict[str, np.ndarray]]:
    """One JointState: ``(names, header_stamp_ns, {field: float64 [count]})``."""
    if not little_endian(raw):
        msg = deserialize(raw, layout.JOINT_STATE)
        return (list(msg.name), stamp_to_ns(msg.header.stamp),
                {f: np.asarray(getattr(msg, f), dtype=np.float64) for f in layout.JOINT_FIELDS})
    lay = joint_state_layout(raw)
    sec, nsec = STAMP.unpack_from(raw, 4)
    values = {f: np.frombuffer(raw, dtype="<f8", count=n, offset=o).astype(np.float64)
              for f, (o, n) in lay.fields.items()}
    return lay.names, sec * 1_000_000_000 + nsec, values


def stack_joint_states(
    raws: Sequence[bytes | memoryview],
) -> tuple[list[str], np.ndarray, dict[str, np.ndarray]] | None:
    """Bulk-decode JointState messages that share one layout (same joints, same array sizes).

    Returns ``(names, header_stamps_ns [N], {field: float64 [N, count]})``, or ``None`` when the
    messages differ in structure (callers then decode message by message).  Padding bytes are
    ignored (rclpy's serializer leaves them uninitialised), everything else is checked.
    """
    if not raws or not little_endian(raws[0]):
        return None
    try:
        lay = joint_state_layout(raws[0])
    except CdrError:
        return None
    size = len(raws[0])
    if any(len(r) != size for r in raws):
        return None
    block = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(len(raws), size)
    for a, b in lay.structure:
        part = block[:, a:b]
        if not np.array_equal(part, np.broadcast_to(part[0], part.shape)):
            return None
    sec = np.ascontiguousarray(block[:, 4:8]).view("<i4")[:, 0].astype(np.int64)
    nsec = np.ascontiguousarray(block[:, 8:12]).view("<u4")[:, 0].astype(np.int64)
    out = {}
    for name, (offset, count) in lay.fields.items():
        data = np.ascontiguousarray(block[:, offset:offset + 8 * count])
        out[name] = data.view("<f8").reshape(len(raws), count)
    return lay.names, sec * 1_000_000_000 + nsec, out


class JointStateParser:
    """``sensor_msgs/JointState`` reader that remembers the last message's layout.

    A driver publishes the same joints in every message, so after the first message the joint names,
    array sizes and offsets are known: a message of the same length with the same bytes from
    ``frame_id`` to the last name and the same array counts is read with three ``np.frombuffer``
    views (the returned ``names`` tuple is then the same object as before).  Other messages are
    parsed fully (big-endian ones through the ``rosbags`` typestore).
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
                and all(U32.unpack_from(raw, p)[0] == c for p, c in self._counts)):
            return header_stamp(raw, _JOINT_STATE), self._views(raw), self._names
        if not little_endian(raw):
            names, stamp, values = parse_joint_state(raw)
            return stamp, values, tuple(names)
        self._learn(raw)
        return header_stamp(raw, _JOINT_STATE), self._views(raw), self._names

    def _views(self, raw: bytes | memoryview) -> dict[str, np.ndarray]:
        return {f: np.frombuffer(raw, dtype="<f8", count=n, offset=o) for f, (o, n) in self._fields.items()}

    def _learn(self, raw: bytes | memoryview) -> None:
        self._len = -1  # invalid until the whole layout is read
        lay = joint_state_layout(raw)
        self._key, self._names = bytes(raw[12:lay.key_end]), tuple(lay.names)
        self._counts, self._fields, self._len = tuple(lay.counts), lay.fields, len(raw)


# --- many messages of one topic -------------------------------------------------------------------
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
    start = -1
    if little_endian(first):
        try:
            start, dim = multiarray_data(first, 4, layout.FLOAT32_ARRAY)
        except CdrError:
            start = -1
    if start < 0:  # not our little-endian layout: decode message by message
        dim = len(parse_float32_array_checked(first, path, topic, 0, stamps))
    if expected_dim is not None and dim != expected_dim:
        raise VectorLengthError(f"vector has {dim} elements, expected {expected_dim}",
                                path=path, topic=topic, index=0,
                                stamp=None if stamps is None else int(stamps[0]))
    if start >= 0:
        block = _same_prefix_block(raws, start, dim)
        if block is not None:
            return block
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


def _same_prefix_block(raws: Sequence[bytes | memoryview], start: int, dim: int) -> np.ndarray | None:
    """float32 ``[N, dim]`` of messages of one length whose bytes before ``start`` (header, layout and
    padding elements) are the same; ``None`` otherwise.  Joined :data:`BLOCK_MESSAGES` at a time and
    written into the result in place, so the messages' bytes are never held twice."""
    size = len(raws[0])
    if any(len(r) != size for r in raws):
        return None
    out = np.empty((len(raws), dim), dtype=np.float32)
    first = np.frombuffer(bytes(raws[0][:start]), dtype=np.uint8)
    for at in range(0, len(raws), BLOCK_MESSAGES):
        part = raws[at:at + BLOCK_MESSAGES]
        block = np.frombuffer(b"".join(part), dtype=np.uint8).reshape(len(part), size)
        if not np.array_equal(block[:, :start], np.broadcast_to(first, (len(part), start))):
            return None
        out[at:at + len(part)] = block[:, start:start + 4 * dim].view("<f4")
    return out


BLOCK_MESSAGES = 4096
"""Messages joined at once by :func:`_same_prefix_block` (a few MB for the usual sizes)."""


def parse_float32_array_checked(
    raw: bytes | memoryview, path: str | None, topic: str | None, index: int,
    stamps: Sequence[int] | np.ndarray | None,
) -> np.ndarray:
    """:func:`parse_float32_array` raising :class:`CorruptBagError` on undecodable bytes."""
    try:
        return parse_float32_array(raw)
    except CdrError as err:
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
        except CdrError as err:
            raise CorruptBagError(f"cannot decode Int32: {err}", path=path, topic=topic, index=i,
                                  stamp=None if stamps is None else int(stamps[i])) from err
    return out
