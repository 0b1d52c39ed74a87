"""Per-topic field extraction from raw CDR bytes, with the size and joint-order checks.

A :class:`TopicExtractor` serves every field the spec takes from one topic: one parse per message,
then one float vector per field.  What a first message decides is pinned for the extractor's life:
the size of a MultiArray field without a declared size, and the joint order of a JointState field
without ``names`` (later messages are mapped by joint name to that order, so a driver that reorders
its joints still gives the same observation layout).

Complexity per message: O(message size + joints) (joint-name lookups are cached per name list).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ompn_ros.data import messages as m
from ompn_ros.layout import (
    FLOAT32,
    FLOAT32_ARRAY,
    FLOAT64,
    FLOAT64_ARRAY,
    JOINT_STATE,
    POSE_STAMPED,
    WRENCH_STAMPED,
)

from ..errors import ObservationSpecError
from ..messages.fieldpath import NAME, FieldPathError, FieldReader, fields_of
from ..messages.types import known
from .spec import FieldSpec, ObservationSpec, canonical_type

ExtractReason = Literal["malformed", "wrong_size"]
Parsed = tuple[int | None, dict[str, np.ndarray], tuple[str, ...] | None]
"""``(header stamp or None, {field: float vector}, joint names or None)`` of one message (the vectors
may be read-only views into the message bytes)."""

_SLICES = {
    (WRENCH_STAMPED, "force"): slice(0, 3), (WRENCH_STAMPED, "torque"): slice(3, 6),
    (WRENCH_STAMPED, "wrench"): slice(0, 6), (POSE_STAMPED, "position"): slice(0, 3),
    (POSE_STAMPED, "orientation"): slice(3, 7), (POSE_STAMPED, "pose"): slice(0, 7),
}


class ExtractError(Exception):
    """A message that cannot give its fields: ``reason`` is ``'malformed'`` or ``'wrong_size'``."""

    def __init__(self, reason: ExtractReason, detail: str) -> None:
        self.reason: ExtractReason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}")


def _parse_stamped(typename: str, count: int) -> Callable[[bytes | memoryview], Parsed]:
    def parse(raw: bytes | memoryview) -> Parsed:
        stamp, values = m.parse_stamped_doubles(raw, count, typename)
        return stamp, {"all": values}, None

    return parse


def _parse_vector(fn: Callable[[bytes | memoryview], np.ndarray]) -> Callable[[bytes | memoryview], Parsed]:
    def parse(raw: bytes | memoryview) -> Parsed:
        return None, {"data": fn(raw)}, None

    return parse


def _parse_scalar(fn: Callable[[bytes | memoryview], float]) -> Callable[[bytes | memoryview], Parsed]:
    def parse(raw: bytes | memoryview) -> Parsed:
        return None, {"data": np.array([fn(raw)], dtype=np.float64)}, None

    return parse


PARSERS: Mapping[str, Callable[[bytes | memoryview], Parsed]] = {
    FLOAT32_ARRAY: _parse_vector(m.parse_float32_array),
    FLOAT64_ARRAY: _parse_vector(m.parse_float64_array),
    FLOAT32: _parse_scalar(m.parse_float32),
    FLOAT64: _parse_scalar(m.parse_float64),
    WRENCH_STAMPED: _parse_stamped(WRENCH_STAMPED, 6),
    POSE_STAMPED: _parse_stamped(POSE_STAMPED, 7),
}
"""Parser of each supported type but JointState (raw CDR -> :data:`Parsed`); JointState uses a
:class:`~ompn_ros.data.messages.JointStateParser` per extractor (it keeps the last layout)."""


@dataclass
class _FieldState:
    spec: FieldSpec
    size: int | None  # declared, or pinned by the first good message
    joints: tuple[str, ...] | None  # JointState: the joints taken, in order (spec names or pinned)
    labels: tuple[str, ...] | None = None
    index_cache: dict[tuple[str, ...], np.ndarray] = field(default_factory=dict)  # message joints -> take
    last_names: tuple[str, ...] | None = None  # the joint tuple of the last message and its take
    last_index: np.ndarray | None = None


@dataclass(frozen=True)
class _Kind:
    """How messages of one type give the fields: the parser and the fields read through a path."""

    type: str
    parse: Callable[[bytes | memoryview], Parsed]
    paths: frozenset[str]  # the fields read through the type's definition (field paths)


class TopicExtractor:
    """Extracts every spec field of one topic from raw CDR bytes (one parse per message).

    A topic recorded under several types (a split bag where a driver changed type) is read message by
    message with its own type (:meth:`extract`'s ``msgtype``); what a first message pins is shared."""

    def __init__(self, topic: str, fields: Sequence[FieldSpec]) -> None:
        if not fields or any(f.topic != topic or f.type != fields[0].type for f in fields):
            raise ValueError(f"TopicExtractor('{topic}') needs fields of that topic and one type")
        self.topic = topic
        self.type = fields[0].type
        self._specs = tuple(fields)
        main = self._kind_of(self._specs)
        self._kinds: dict[str, _Kind] = {self.type: main}
        self._main = main
        self.has_header = self.type in (JOINT_STATE, WRENCH_STAMPED, POSE_STAMPED) or (
            "header.stamp" in main.paths)
        self._fields = [_FieldState(f, f.declared_size, f.names) for f in fields]
        for state in self._fields:
            if state.size is not None:
                state.labels = state.spec.labels(state.size)

    def _kind_of(self, specs: Sequence[FieldSpec]) -> _Kind:
        """The parser of ``specs`` (fields of one type): fast parsers, field paths, or both."""
        msgtype = specs[0].type
        generic = [f.field for f in specs if f.generic]
        fast = len(generic) < len(specs)
        parse: Callable[[bytes | memoryview], Parsed] | None = None
        if fast:
            parse = m.JointStateParser().parse if msgtype == JOINT_STATE else PARSERS[msgtype]
        paths: frozenset[str] = frozenset()
        if generic:  # field paths: one walk per message over the type's definition
            reader = path_reader(msgtype, generic)
            paths = frozenset(reader.paths)
            by_path = _paths_parser(reader)
            parse = by_path if parse is None else _both(parse, by_path)
        assert parse is not None
        return _Kind(msgtype, parse, paths)

    def for_type(self, msgtype: str) -> None:
        """Read messages of ``msgtype`` too (a topic under several types); raises
        :class:`ObservationSpecError` naming the field ``msgtype`` cannot give."""
        if msgtype not in self._kinds:
            full = canonical_type(msgtype) or msgtype
            same = self._kinds.get(full)
            self._kinds[msgtype] = same or self._kind_of([replace(f, type=full) for f in self._specs])

    @property
    def sizes(self) -> list[int | None]:
        """Element count of each field (``None`` until a first message decides it)."""
        return [s.size for s in self._fields]

    @property
    def labels(self) -> list[tuple[str, ...] | None]:
        """Element labels of each field (``None`` until a first message decides them)."""
        return [s.labels for s in self._fields]

    def extract(self, raw: bytes | memoryview,
                msgtype: str | None = None) -> tuple[int | None, list[np.ndarray]]:
        """``(header stamp ns or None, one float vector per field)``; raises :class:`ExtractError`.

        ``msgtype``: the message's own type when it may differ from the spec's (:meth:`for_type`
        first; ``None``: the spec's).  The header stamp is ``None`` for header-less types and for a
        zero stamp (unset by the driver).
        """
        kind = self._main if msgtype is None or msgtype == self.type else self._kinds.get(msgtype)
        if kind is None:
            raise ValueError(f"topic '{self.topic}': type {msgtype} not declared (call for_type first)")
        try:
            stamp, values, names = kind.parse(raw)
        except Exception as err:  # struct, rosbags and numpy raise several types on bad bytes
            detail = f"cannot decode {kind.type}: {type(err).__name__}: {err}"
            raise ExtractError("malformed", detail) from err
        out = [self._field(state, values, names, kind) for state in self._fields]
        return (stamp or None), out

    def _field(
        self, state: _FieldState, values: dict[str, np.ndarray], names: tuple[str, ...] | None, kind: _Kind
    ) -> np.ndarray:
        spec = state.spec
        if spec.field in kind.paths:
            vec = values[spec.field]
        elif kind.type == JOINT_STATE:
            vec = self._joint_field(state, values[spec.field], names or ())
        elif (kind.type, spec.field) in _SLICES:
            vec = values["all"][_SLICES[(kind.type, spec.field)]]
        else:
            vec = values["data"]
        if state.size is None:  # first good message pins the size
            if vec.size == 0:
                raise ExtractError("wrong_size", f"field '{spec.field}' is empty")
            state.size = int(vec.size)
            state.labels = spec.labels(state.size)
        elif vec.size != state.size:
            raise ExtractError("wrong_size", f"field '{spec.field}' has {vec.size} elements, expected "
                               f"{state.size}")
        return vec

    def _joint_field(self, state: _FieldState, arr: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
        name = state.spec.field
        if names and arr.size != len(names):
            raise ExtractError("wrong_size", f"{name} has {arr.size} values for {len(names)} joints")
        if state.joints is None:  # no names in the spec: pin the first message's joints
            if arr.size == 0:
                raise ExtractError("wrong_size", f"field '{name}' is empty")
            state.joints = tuple(names)
            state.size = int(arr.size)
            state.labels = tuple(names) if names else tuple(str(i) for i in range(arr.size))
        if not state.joints:  # joints without names: positional
            return arr
        if names is state.last_names:  # the parser returns the same tuple for an unchanged layout
            return arr[state.last_index]
        key = tuple(names)
        index = state.index_cache.get(key)
        if index is None:
            position = {n: i for i, n in enumerate(key)}
            missing = [n for n in state.joints if n not in position]
            if missing:
                raise ExtractError("malformed", f"joint{'s' if len(missing) > 1 else ''} {missing} not in "
                                   f"the message (joints {list(key)})")
            index = np.asarray([position[n] for n in state.joints], dtype=np.intp)
            if len(state.index_cache) < 64:
                state.index_cache[key] = index
        state.last_names, state.last_index = names, index
        return arr[index]


def path_reader(typename: str, paths: list[str]) -> FieldReader:
    """A :class:`FieldReader` of ``paths`` (and ``header.stamp`` last when the type has a header);
    :class:`ObservationSpecError` names the type or the path at fault."""
    try:
        if not known(typename):
            raise ObservationSpecError(
                f"type {typename} is not in the bag's definitions nor the typestore: name its .msg folder "
                f"with `types: DIR`, or install its package ({typename.split('/', 1)[0]})")
        header = dict(fields_of(typename)).get("header") == (NAME, "std_msgs/msg/Header")
        return FieldReader(typename, [*paths, *(["header.stamp"] if header else [])])
    except FieldPathError as err:
        raise ObservationSpecError(str(err)) from err


def _paths_parser(reader: FieldReader) -> Callable[[bytes | memoryview], Parsed]:
    """The parser of the field paths of ``reader`` (``header.stamp`` last when the type has one)."""
    def parse(raw: bytes | memoryview) -> Parsed:
        values = reader.values(raw)  # CdrError on bytes that do not fit: 'malformed' in extract()
        stamp = None
        if reader.paths[-1] == "header.stamp":
            sec, nanosec = values.pop()
            stamp = int(sec) * 1_000_000_000 + int(nanosec)
        return stamp, dict(zip(reader.paths, values)), None

    return parse


def _both(fast: Callable[[bytes | memoryview], Parsed],
          paths: Callable[[bytes | memoryview], Parsed]) -> Callable[[bytes | memoryview], Parsed]:
    """A topic with fast fields and field paths: both parsers, their values merged."""
    def parse(raw: bytes | memoryview) -> Parsed:
        stamp, values, names = fast(raw)
        return stamp, {**values, **paths(raw)[1]}, names

    return parse


def extractors(spec: ObservationSpec) -> dict[str, TopicExtractor]:
    """One :class:`TopicExtractor` per topic of ``spec`` (the step topic first)."""
    return {t: TopicExtractor(t, [f for f in spec.fields if f.topic == t]) for t in spec.topics}


def observation_layout(
    spec: ObservationSpec, first_messages: Mapping[str, bytes | memoryview] | None = None
) -> tuple[int, tuple[str, ...]]:
    """``(dim, names)`` of the observation: from the declared sizes, else from one message per topic.

    Names are ``<topic without leading '/'>/<field>/<label>``, e.g. ``arm1/joint_states/position/j1``.
    Raises :class:`~ompn_ros.data.errors.ObservationSpecError` naming the topic whose message is needed
    and missing or unusable.
    """
    given = dict(first_messages or {})
    by_topic = extractors(spec)
    for topic, ex in by_topic.items():
        if all(s is not None for s in ex.sizes) and all(lab is not None for lab in ex.labels):
            continue
        if topic not in given:
            raise ObservationSpecError(
                f"the size of topic '{topic}' is not declared: a first message of it is needed")
        try:
            ex.extract(given[topic])
        except ExtractError as err:
            raise ObservationSpecError(f"topic '{topic}': first message unusable: {err}") from err
    return layout_of(spec, by_topic)


def layout_of(spec: ObservationSpec, by_topic: Mapping[str, TopicExtractor]) -> tuple[int, tuple[str, ...]]:
    """``(dim, names)`` from extractors whose sizes are known (``ObservationSpecError`` names the first
    unknown)."""
    names: list[str] = []
    position = {topic: 0 for topic in by_topic}
    for f in spec.fields:
        k = position[f.topic]
        position[f.topic] += 1
        labels = by_topic[f.topic].labels[k]
        if labels is None:
            raise ObservationSpecError(f"the size of field '{f.field}' of topic '{f.topic}' is not known yet")
        names.extend(f"{f.topic.lstrip('/')}/{f.field}/{label}" for label in labels)
    return len(names), tuple(names)
