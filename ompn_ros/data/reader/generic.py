"""Vectors of any message type through a field path, and topics whose connections differ in type.

A :class:`~ompn_ros.reader.spec.VectorSource` with ``field`` reads the numbers that path leads to
(:class:`~ompn_ros.data.messages.fieldpath.FieldReader`, bulk by layout).  A topic recorded under
several types (a split bag where a command changed type) is decoded per connection: each message by
its own type, the fast parser of that type or the field path, never the bytes of one type read as
another (:meth:`TypeChecks.check_source` refuses a spec that fits only some of them).

Cost: O(total bytes) per topic for messages sharing a layout (see ``fieldpath``).
"""

from __future__ import annotations

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..errors import CorruptBagError, LabelError, TopicTypeError, UnknownTypeError, VectorLengthError
from ..messages.cdr import CdrError
from ..messages.fieldpath import FieldPathError, FieldReader, RowError
from ..messages.types import TypeDefinitionError, ensure
from .context import BagContext
from .spec import VectorSource
from .vectors import stack_float64_arrays

MULTIARRAYS = (layout.FLOAT32_ARRAY, layout.FLOAT64_ARRAY)


def field_reader(ctx: BagContext, topic: str, msgtype: str, paths: list[str]) -> FieldReader:
    """A reader of ``paths`` of ``msgtype`` (registered from ``ReaderSpec.types`` when the bag lacks its
    definition); :class:`UnknownTypeError` / :class:`TopicTypeError` name the way out."""
    try:
        ensure(msgtype, ctx.spec.types)
    except TypeDefinitionError as err:
        raise UnknownTypeError(str(err), path=ctx.path, topic=topic, index=0) from err
    try:
        return FieldReader(msgtype, paths)
    except FieldPathError as err:
        raise TopicTypeError(str(err), path=ctx.path, topic=topic, index=0) from err


def vectors(
    ctx: BagContext, topic: str, src: VectorSource, stamps: np.ndarray, raws: list[bytes], types: list[str]
) -> np.ndarray:
    """``[N, D]`` float32 of the messages ``raws`` (``types``: each message's type), per connection."""
    distinct = list(dict.fromkeys(types))
    if len(distinct) == 1:
        return _one_type(ctx, topic, src, stamps, raws, distinct[0], np.arange(len(raws)))
    kind = np.asarray([distinct.index(t) for t in types])
    out: np.ndarray | None = None
    for k, msgtype in enumerate(distinct):
        rows = np.flatnonzero(kind == k)
        part = _one_type(ctx, topic, src, stamps[rows], [raws[i] for i in rows.tolist()], msgtype, rows)
        if out is None:
            out = np.zeros((len(raws), part.shape[1]), dtype=np.float32)
        if part.shape[1] != out.shape[1]:
            raise VectorLengthError(
                f"{msgtype} gives {part.shape[1]} values, {distinct[0]} {out.shape[1]} "
                "(the topic changes type)",
                path=ctx.path,
                topic=topic,
                index=int(rows[0]),
                stamp=int(stamps[rows[0]]),
            )
        out[rows] = part
    assert out is not None
    return out


def _one_type(
    ctx: BagContext,
    topic: str,
    src: VectorSource,
    stamps: np.ndarray,
    raws: list[bytes],
    msgtype: str,
    rows: np.ndarray,
) -> np.ndarray:
    """Messages of one type; errors name the message's index in the whole topic (``rows``)."""
    if src.field is None and msgtype == layout.FLOAT32_ARRAY:
        try:
            return m.stack_float32_arrays(
                raws, expected_dim=src.dim, path=ctx.path, topic=topic, stamps=stamps
            )
        except (CorruptBagError, VectorLengthError) as err:
            raise type(err)(
                err.reason, path=ctx.path, topic=topic, index=int(rows[err.index or 0]), stamp=err.stamp
            ) from err
    if src.field is None and msgtype == layout.FLOAT64_ARRAY:
        try:
            return stack_float64_arrays(raws, src.dim, ctx.path, topic, stamps)
        except (CorruptBagError, VectorLengthError) as err:
            raise type(err)(
                err.reason, path=ctx.path, topic=topic, index=int(rows[err.index or 0]), stamp=err.stamp
            ) from err
    path = src.field or "data"
    reader = field_reader(ctx, topic, msgtype, [path])
    try:
        values = reader.vectors(raws)[0]
    except RowError as err:
        kind = VectorLengthError if err.reason == "wrong_size" else CorruptBagError
        raise kind(
            f"cannot read field '{path}' of {msgtype}: {err.detail}",
            path=ctx.path,
            topic=topic,
            index=int(rows[err.row]),
            stamp=int(stamps[err.row]),
        ) from err
    if src.dim is not None and values.shape[1] != src.dim and len(raws):
        raise VectorLengthError(
            f"field '{path}' has {values.shape[1]} values, expected {src.dim}",
            path=ctx.path,
            topic=topic,
            index=int(rows[0]),
            stamp=int(stamps[0]),
        )
    return values.astype(np.float32)


def header_stamps(ctx: BagContext, topic: str, raws: list[bytes], types: list[str]) -> np.ndarray:
    """``header.stamp`` (ns) of every message of a generic-typed topic (the ``header`` time base);
    ``types``: each message's type (a topic under several types is read per connection)."""
    out = np.zeros(len(raws), dtype=np.int64)
    for msgtype in dict.fromkeys(types):
        rows = [i for i, t in enumerate(types) if t == msgtype]
        reader = field_reader(ctx, topic, msgtype, ["header.stamp"])
        try:
            out[rows] = reader.stamps([raws[i] for i in rows])
        except RowError as err:
            raise CorruptBagError(
                f"cannot read header.stamp of {msgtype}: {err.detail}", path=ctx.path, topic=topic,
                index=rows[err.row]) from err
    return out


def labels(ctx: BagContext, topic: str, stamps: np.ndarray, raws: list[bytes], kind: str) -> np.ndarray:
    """The label of every message (``ReaderSpec.subtask_field``) as int64: numbers as they are, strings
    (names) as ids in order of first appearance (``labels: id`` only; the names go to the report)."""
    types = ctx.message_types(topic)  # each message by its own type (a topic under several types)
    readers = {t: field_reader(ctx, topic, t, [ctx.spec.subtask_field or ""]) for t in set(types)}
    names: dict[str, int] = {}
    out = np.zeros(len(raws), dtype=np.int64)
    for i, raw in enumerate(raws):
        msgtype, reader = types[i], readers[types[i]]
        try:
            value = reader.scalars(raw)[0]
        except CdrError as err:
            raise CorruptBagError(
                f"cannot read label field '{reader.paths[0]}' of {msgtype}: {err}",
                path=ctx.path,
                topic=topic,
                index=i,
                stamp=int(stamps[i]),
            ) from err
        if isinstance(value, str):
            if kind != layout.LABELS_ID:
                raise LabelError(
                    f"label field '{reader.paths[0]}' holds names ('{value}'): set labels: id",
                    path=ctx.path,
                    topic=topic,
                    index=i,
                )
            value = names.setdefault(value, len(names))
        elif float(value) != int(value):
            raise LabelError(
                f"label field '{reader.paths[0]}' holds {value}, not a whole number",
                path=ctx.path,
                topic=topic,
                index=i,
            )
        out[i] = int(value)
    if names:
        ctx.report.notes.append(f"topic '{topic}': subtask names as ids {names}")
    return out
