"""Field paths: any numeric (or string) part of any registered message type, read from raw CDR.

A path names fields from the message's top, ``.``-separated, each optionally indexed into an array or
a sequence (a negative index counts from its end)::

    positions              float64[] of a custom ArmState: every element
    gripper.width          a float64 of a nested message: one value
    twist.linear           a geometry_msgs/Vector3: its numeric leaves in definition order (x, y, z)
    points[-1].positions   the last point of a JointTrajectory: its positions
    header.stamp           a builtin_interfaces/Time: sec and nanosec (:meth:`FieldReader.stamps`
                           joins them into nanoseconds, the form a stamp source takes)

A path is checked against the type's definition in the typestore (:mod:`.types` registers the types
a bag or a ``.msg`` folder carries) before any message is read; :class:`FieldPathError` names the type,
the path and the fields that exist.

Reading: :class:`FieldReader` walks a message's CDR once (strings and sequences read their length
words, everything else is skipped by size) and gathers the wanted bytes with ``np.frombuffer``.  In
bulk (:meth:`FieldReader.vectors`) the messages whose length words equal a reference message's have
the same layout, so the wanted bytes sit at the same offsets: one walk per layout, then one strided
copy per field over the joined messages.  Cost: O(total bytes) for messages sharing a layout, one
walk (O(fields + sequence elements)) per other message.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from ompn_ros.errors import OMPNError

from .cdr import CdrError, typestore

NUMERIC: Final[dict[str, str]] = {
    "bool": "u1",
    "byte": "u1",
    "char": "u1",
    "octet": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "int64": "i8",
    "uint64": "u8",
    "float32": "f4",
    "float64": "f8",
    "float": "f4",
    "double": "f8",
}
"""CDR primitive -> numpy dtype (little-endian; big-endian messages swap it)."""
TIME_TYPES: Final = frozenset({"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"})
BASE, NAME, ARRAY, SEQUENCE = 1, 2, 3, 4  # rosbags' Nodetype values
_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(-?\d+)\])?$")
_U32 = struct.Struct("<I")
_U32_BE = struct.Struct(">I")


class FieldPathError(OMPNError, ValueError):
    """A field path that does not lead to a value of its type: one line naming type, path and fields."""


@dataclass(frozen=True)
class Step:
    """One ``name`` or ``name[index]`` of a path."""

    name: str
    index: int | None = None


def parse_path(text: str) -> tuple[Step, ...]:
    """``'points[-1].positions'`` -> steps; :class:`FieldPathError` on a malformed path."""
    if not isinstance(text, str) or not text.strip():
        raise FieldPathError(f"a field path must be a non-empty string like 'gripper.width', got {text!r}")
    steps = []
    for part in text.strip().split("."):
        match = _STEP.match(part)
        if match is None:
            raise FieldPathError(f"field path {text!r}: {part!r} is not 'name' or 'name[index]'")
        steps.append(Step(match.group(1), None if match.group(2) is None else int(match.group(2))))
    return tuple(steps)


FIELD_CACHE: dict[str, list[tuple[str, Any]]] = {}
SIZES: Final = {prim: np.dtype(dt).itemsize for prim, dt in NUMERIC.items()}


def fields_of(typename: str) -> list[tuple[str, Any]]:
    """``(name, node)`` of every field of ``typename`` (rosbags' parse tree; a registered name never
    changes its definition, so it is cached)."""
    out = FIELD_CACHE.get(typename)
    if out is None:
        out = FIELD_CACHE[typename] = list(typestore().fielddefs[typename][1])
    return out


@dataclass(frozen=True)
class Target:
    """What a path leads to: ``kind`` 'numeric' | 'string' | 'time'; ``labels`` per element when the
    element count is fixed by the type (``None``: decided by each message)."""

    kind: str
    labels: tuple[str, ...] | None


def describe(typename: str, path: str) -> Target:
    """Check ``path`` against ``typename``'s definition; :class:`FieldPathError` names what is wrong."""
    if typename not in typestore().fielddefs:
        raise FieldPathError(f"type {typename} is not known (not in the bag's definitions nor the typestore)")
    steps = parse_path(path)
    current: Any = (NAME, typename)
    for k, step in enumerate(steps):
        here = ".".join(_text(s) for s in steps[:k]) or "the message"
        if current[0] != NAME:
            raise FieldPathError(
                f"{typename}: field path '{path}': {here} is not a message, it has no field '{step.name}'"
            )
        sub = dict(fields_of(current[1]))
        if step.name not in sub:
            raise FieldPathError(
                f"{typename}: field path '{path}': {current[1]} has no field '{step.name}' "
                f"(fields: {', '.join(sub) or 'none'})"
            )
        current = sub[step.name]
        if step.index is not None:
            if current[0] not in (ARRAY, SEQUENCE):
                raise FieldPathError(
                    f"{typename}: field path '{path}': '{step.name}' is not an array, it takes no index"
                )
            if current[0] == ARRAY and not -current[1][1] <= step.index < current[1][1]:
                raise FieldPathError(
                    f"{typename}: field path '{path}': index {step.index} is outside "
                    f"'{step.name}' of {current[1][1]} elements"
                )
            current = current[1][0]
    return _target(typename, path, current)


def _text(step: Step) -> str:
    return step.name if step.index is None else f"{step.name}[{step.index}]"


def _target(typename: str, path: str, node: Any) -> Target:
    kind, detail = node
    if kind == BASE:
        if detail[0] in NUMERIC:
            return Target("numeric", ("",))
        if detail[0] in ("string", "wstring"):
            return Target("string", ("",))
    if kind == NAME:
        if detail in TIME_TYPES:
            return Target("time", ("sec", "nanosec"))
        labels = _leaf_labels(detail, "")
        if labels is not None and not labels:
            raise FieldPathError(f"{typename}: field path '{path}': {detail} holds no numeric field")
        return Target("numeric", labels)
    if kind in (ARRAY, SEQUENCE):
        elem = node[1][0]
        if elem[0] == BASE and elem[1][0] in NUMERIC:
            return Target("numeric", tuple(str(i) for i in range(detail[1])) if kind == ARRAY else None)
        if elem[0] == NAME:
            inner = _leaf_labels(elem[1], "")
            if kind == ARRAY and inner is not None:
                return Target("numeric", tuple(f"{i}.{lab}" for i in range(detail[1]) for lab in inner))
            return Target("numeric", None)
    raise FieldPathError(
        f"{typename}: field path '{path}' leads to {_node_name(node)}, not a number, a "
        "numeric array or a message of numbers"
    )


def _node_name(node: Any) -> str:
    kind, detail = node
    if kind == BASE:
        return str(detail[0])
    if kind == NAME:
        return str(detail)
    return f"{_node_name(detail[0])}[]"


def _leaf_labels(typename: str, prefix: str) -> tuple[str, ...] | None:
    """Labels of the numeric leaves of a message type (strings skipped); ``None`` when a sequence
    makes their count vary."""
    out: list[str] = []
    for name, (kind, detail) in fields_of(typename):
        label = f"{prefix}{name}"
        if kind == BASE:
            if detail[0] in NUMERIC:
                out.append(label)
        elif kind == NAME:
            inner = _leaf_labels(detail, label + ".")
            if inner is None:
                return None
            out.extend(inner)
        elif kind == SEQUENCE:
            if not (detail[0][0] == BASE and detail[0][1][0] not in NUMERIC):
                return None  # a numeric or message sequence: the count varies
        elif detail[0][0] == BASE:
            if detail[0][1][0] in NUMERIC:
                out.extend(f"{label}.{i}" for i in range(detail[1]))
        else:
            inner = _leaf_labels(detail[0][1], "")
            if inner is None:
                return None
            out.extend(f"{label}.{i}.{lab}" for i in range(detail[1]) for lab in inner)
    return tuple(out)


Segment = tuple[int, int, str]  # byte offset, element count, dtype ('S' = string bytes)


class _Walk:
    """One message's walk: the segments of each wanted path and the offsets of its length words."""

    def __init__(self, raw: bytes | memoryview, slots: int) -> None:
        self.raw = raw
        self.big = raw[1] == 0
        self.u32 = _U32_BE if self.big else _U32
        self.segs: list[list[Segment]] = [[] for _ in range(slots)]
        self.words: list[int] = []

    def count(self, pos: int) -> tuple[int, int]:
        pos = _align(pos, 4)
        if pos + 4 > len(self.raw):
            raise CdrError(f"CDR of {len(self.raw)} bytes ends inside a length word at byte {pos}")
        self.words.append(pos)
        return self.u32.unpack_from(self.raw, pos)[0], pos + 4


def _align(pos: int, n: int) -> int:
    return 4 + ((pos - 4 + n - 1) // n) * n


Want = tuple[tuple[Step, ...], int]  # the rest of a path and its output slot


def _walk_type(w: _Walk, typename: str, pos: int, wants: list[Want]) -> int:
    """Walk one message of ``typename`` from ``pos``: segments for ``wants`` (a want with no steps left
    takes every numeric leaf), the position after the message."""
    whole = [slot for steps, slot in wants if not steps]
    for name, node in fields_of(typename):
        here = [(steps, slot) for steps, slot in wants if steps and steps[0].name == name]
        if not here and not whole:
            pos = _skip(w, node, pos)
            continue
        end = _take_field(w, node, pos, here) if here else _skip(w, node, pos)
        if whole:
            _take_field(w, node, pos, [((Step(name),), slot) for slot in whole], leaves=True)
        pos = end
    return pos


def _take_field(w: _Walk, node: Any, pos: int, here: list[Want], leaves: bool = False) -> int:
    """Segments of one field for ``here`` (wants whose first step names it)."""
    kind, detail = node
    if kind == BASE:
        return _take_base(w, detail[0], pos, [slot for _, slot in here], leaves)
    if kind == NAME:
        end = pos
        for steps, slot in here:
            end = _walk_type(w, detail, pos, [(steps[1:], slot)])
        return end
    elem, n, pos = _sequence(w, kind, detail, pos)
    if elem[0] == BASE and elem[1][0] in NUMERIC:
        size = SIZES[elem[1][0]]
        start = _align(pos, size) if n else pos
        for steps, slot in here:
            index = steps[0].index
            if index is None:
                w.segs[slot].append((start, n, NUMERIC[elem[1][0]]))
            else:
                k = _element(index, n, steps[0].name)
                w.segs[slot].append((start + k * size, 1, NUMERIC[elem[1][0]]))
        return start + n * size
    for steps, _ in here:  # an index outside the sequence (a trajectory without points) is an error
        if steps[0].index is not None:
            _element(steps[0].index, n, steps[0].name)
    for i in range(n):  # strings or messages, element by element
        chosen = [
            (s, slot) for s, slot in here if s[0].index is None or _element(s[0].index, n, s[0].name) == i
        ]
        if not chosen or (elem[0] == BASE and leaves):
            pos = _skip(w, elem, pos)
        elif elem[0] == BASE:
            pos = _take_base(w, elem[1][0], pos, [slot for _, slot in chosen], leaves)
        else:
            end = pos
            for steps, slot in chosen:
                end = _walk_type(w, elem[1], pos, [(steps[1:], slot)])
            pos = end
    return pos


def _element(index: int, n: int, name: str) -> int:
    k = index + n if index < 0 else index
    if not 0 <= k < n:
        raise CdrError(f"index {index} is outside '{name}' of {n} elements")
    return k


def _take_base(w: _Walk, prim: str, pos: int, slots: list[int], leaves: bool) -> int:
    if prim in NUMERIC:
        size = SIZES[prim]
        start = _align(pos, size)
        for slot in slots:
            w.segs[slot].append((start, 1, NUMERIC[prim]))
        return start + size
    n, start = w.count(pos)  # a string: u32 length (NUL included), then its bytes
    if not leaves:
        for slot in slots:
            w.segs[slot].append((start, max(n - 1, 0), "S"))
    return start + n

def _sequence(w: _Walk, kind: str, detail: Any, pos: int) -> tuple[Any, int, int]:
    """An array's element type, its length (fixed, or the CDR count read at ``pos``) and where its
    elements start."""
    if kind == ARRAY:
        return detail[0], detail[1], pos
    n, pos = w.count(pos)
    return detail[0], n, pos



def _skip(w: _Walk, node: Any, pos: int) -> int:
    kind, detail = node
    if kind == BASE:
        if detail[0] in NUMERIC:
            size = SIZES[detail[0]]
            return _align(pos, size) + size
        n, pos = w.count(pos)
        return pos + n
    if kind == NAME:
        for _, sub in fields_of(detail):
            pos = _skip(w, sub, pos)
        return pos
    elem, n, pos = _sequence(w, kind, detail, pos)
    if elem[0] == BASE and elem[1][0] in NUMERIC:
        size = SIZES[elem[1][0]]
        return (_align(pos, size) + n * size) if n else pos
    for _ in range(n):
        pos = _skip(w, elem, pos)
    return pos


class FieldReader:
    """Reads ``paths`` of ``typename`` from raw CDR messages (paths checked once, on construction)."""

    def __init__(self, typename: str, paths: Sequence[str]) -> None:
        self.typename = typename
        self.paths = tuple(paths)
        self.targets = [describe(typename, p) for p in self.paths]
        self._wants: list[Want] = [(parse_path(p), k) for k, p in enumerate(self.paths)]
        self._last: _Layout | None = None  # the layout of the last message :meth:`values` walked

    def walk(self, raw: bytes | memoryview) -> _Walk:
        """The segments of every path in one message; :class:`CdrError` on bytes that do not fit."""
        if len(raw) < 4 or raw[0] != 0 or raw[1] not in (0, 1):
            raise CdrError(f"{self.typename} CDR of {len(raw)} bytes does not start with a CDR header")
        w = _Walk(raw, len(self.paths))
        try:
            end = _walk_type(w, self.typename, 4, self._wants)
        except struct.error as err:
            raise CdrError(f"{self.typename} CDR of {len(raw)} bytes ends inside a field") from err
        for segs in w.segs:
            for off, count, dtype in segs:
                if off + count * (1 if dtype == "S" else np.dtype(dtype).itemsize) > len(raw):
                    raise CdrError(f"{self.typename} CDR of {len(raw)} bytes ends inside a field")
        if end > len(raw):
            raise CdrError(f"{self.typename} CDR of {len(raw)} bytes ends inside a field")
        return w

    def values(self, raw: bytes | memoryview) -> list[np.ndarray]:
        """One float64 vector per path (strings are refused: :meth:`scalars`).  A message of the last
        one's layout (same length, header and length words: one ``struct`` call) reuses its offsets."""
        last = self._last
        if last is None or not last.fits(raw):
            w = self.walk(raw)
            last = self._last = _Layout(raw, w)
        return [_gather(raw, segs, last.big, p) for segs, p in zip(last.segs, self.paths)]

    def scalars(self, raw: bytes | memoryview) -> list[int | float | str]:
        """One value per path, each path leading to a single number or a string (labels)."""
        w = self.walk(raw)
        out: list[int | float | str] = []
        for segs, path in zip(w.segs, self.paths):
            if len(segs) == 1 and segs[0][2] == "S":
                off, n, _ = segs[0]
                out.append(bytes(raw[off : off + n]).decode("utf-8", errors="replace"))
                continue
            vec = _gather(raw, segs, w.big, path, keep=True)
            if vec.size != 1:
                raise CdrError(f"{self.typename} field '{path}' holds {vec.size} values, not one")
            out.append(vec[0].item())
        return out

    def stamps(self, raws: Sequence[bytes | memoryview], slot: int = 0) -> np.ndarray:
        """Nanoseconds of a ``builtin_interfaces/Time`` path (``header.stamp``) in every message."""
        pairs = self.vectors(raws)[slot]
        return (pairs[:, 0].astype(np.int64) * 1_000_000_000 + pairs[:, 1].astype(np.int64)).astype(np.int64)

    def vectors(self, raws: Sequence[bytes | memoryview]) -> list[np.ndarray]:
        """``[N, D]`` float64 per path over ``raws`` (bulk, see the module docstring).  Raises
        :class:`RowError` naming the first message that cannot give a path or gives another size
        than the first message."""
        n = len(raws)
        out: list[np.ndarray | None] = [None] * len(self.paths)
        lengths = np.fromiter(map(len, raws), dtype=np.int64, count=n)
        if n and np.all(lengths == lengths[0]):  # the usual case: one length, no regrouping
            block = np.frombuffer(b"".join(raws), np.uint8).reshape(n, int(lengths[0]))
            self._group(raws, np.arange(n), block, out, n)
        else:
            values, first = np.unique(lengths, return_index=True)
            for length in values[np.argsort(first)]:
                rows = np.flatnonzero(lengths == length)
                block = np.frombuffer(b"".join([raws[i] for i in rows.tolist()]), np.uint8)
                self._group(raws, rows, block.reshape(rows.size, int(length)), out, n)
        return [np.zeros((n, 0)) if o is None else o for o in out]

    def _group(
        self,
        raws: Sequence[bytes | memoryview],
        rows: np.ndarray,
        block: np.ndarray,
        out: list[np.ndarray | None],
        n: int,
    ) -> None:
        """Rows of one message length: those with the layout of the group's first message in bulk,
        the others again by the same rule (each round takes at least its first row)."""
        while rows.size:
            first = int(rows[0])
            try:
                w = self.walk(raws[first])
            except CdrError as err:
                raise RowError(first, str(err)) from err
            cols = np.concatenate(
                [np.arange(2), *(np.arange(word, word + 4) for word in sorted(set(w.words)))]
            )
            layout = block[:, cols]  # the bytes that fix the layout: header, every length word
            same = (layout == layout[0]).all(axis=1)
            taken = block if same.all() else block[same]
            for k, segs in enumerate(w.segs):
                part = _columns(taken, segs, w.big, self.paths[k])
                if out[k] is None:
                    out[k] = np.zeros((n, part.shape[1]))
                target = out[k]
                assert target is not None
                if target.shape[1] != part.shape[1]:
                    raise RowError(
                        first,
                        f"field '{self.paths[k]}' has {part.shape[1]} values, the first "
                        f"message {target.shape[1]}",
                        reason="wrong_size",
                    )
                target[rows[same]] = part
            rows, block = rows[~same], block[~same]


class _Layout:
    """The offsets of one message's walk and what decides them: its length, header and length words."""

    def __init__(self, raw: bytes | memoryview, w: _Walk) -> None:
        self.size, self.head, self.big, self.segs = len(raw), bytes(raw[:2]), w.big, w.segs
        fmt, pos = ">" if w.big else "<", 0
        for word in sorted(set(w.words)):
            fmt += f"{word - pos}xI"
            pos = word + 4
        self.words = struct.Struct(fmt)
        self.values = self.words.unpack_from(raw, 0)

    def fits(self, raw: bytes | memoryview) -> bool:
        same_head = len(raw) == self.size and raw[:2] == self.head
        return same_head and self.words.unpack_from(raw, 0) == self.values


class RowError(Exception):
    """Message ``row`` of a bulk read cannot give its fields (``reason``: 'malformed' | 'wrong_size')."""

    def __init__(self, row: int, detail: str, reason: str = "malformed") -> None:
        self.row, self.detail, self.reason = row, detail, reason
        super().__init__(detail)


def _gather(
    raw: bytes | memoryview, segs: list[Segment], big: bool, path: str, keep: bool = False
) -> np.ndarray:
    parts = []
    for off, count, dtype in segs:
        if dtype == "S":
            raise CdrError(f"field '{path}' is a string, not a number")
        dt = np.dtype(dtype).newbyteorder(">" if big else "<")
        parts.append(np.frombuffer(raw, dt, count, off))
    if not parts:
        return np.zeros(0)
    joined = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return joined if keep else joined.astype(np.float64)


def _columns(block: np.ndarray, segs: list[Segment], big: bool, path: str) -> np.ndarray:
    parts = []
    for off, count, dtype in segs:
        if dtype == "S":
            raise CdrError(f"field '{path}' is a string, not a number")
        dt = np.dtype(dtype).newbyteorder(">" if big else "<")
        cols = np.ascontiguousarray(block[:, off : off + count * dt.itemsize]).view(dt)
        parts.append(cols.astype(np.float64))
    if not parts:
        return np.zeros((block.shape[0], 0))
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)

