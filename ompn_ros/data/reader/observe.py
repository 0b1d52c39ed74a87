"""Observations assembled from several topics of one bag (``ReaderSpec.assemble``).

The bag's messages of the spec's topics are fed, in record order with their log stamps, to the
same :class:`~ompn_ros.data.obs.ObservationAssembler` the live node runs (as
:func:`ompn_ros.data.obs.assemble_stream` does), so a bag recorded from the live callbacks gives the
live observations.  Normally this happens while the bag is read
(:class:`~ompn_ros.data.reader.columns.AssemblySink`, the raw bytes are not kept); a bag cut at a
corrupt tail is assembled again from the storage.  Every
step-topic message is a row of the step clock (its log stamp); rows the rule dropped keep zeros and
``kept = False`` and are removed after actions and labels are attached (``reader.assemble``).

Cost: O(M + S · D) in the assembler for M messages and S steps of size D (O(M log M) more to merge
kept raw messages into record order); memory: the ``[S, D]`` float32 rows.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from rosbags.rosbag2 import Reader

from ..cuts import Repeats
from ..obs import ObservationSpec
from .columns import AssemblySink
from .context import BagContext
from .raw import bag_messages


@dataclass
class AssembledRows:
    """One row per step-topic message, sorted by log stamp.

    Attributes:
        values: float32 ``[S, D]`` (zeros on dropped rows).
        stamps: int64 ``[S]`` log stamps (the step clock).
        kept: bool ``[S]``; False = the rule dropped the step.
        order: the reorder applied to put the rows in stamp order (``None`` = record order was).
        names: element names of the observation (``<topic>/<field>/<label>``).
        dropped: dropped steps by reason (``missing``, ``stale``, ``malformed``, ...).
        rejected: rejected partner messages by ``'<topic>: <reason>'``.
    """

    values: np.ndarray
    stamps: np.ndarray
    kept: np.ndarray
    order: np.ndarray | None = None
    names: tuple[str, ...] = ()
    dropped: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)


Message = tuple[str, int, bytes, str]  # topic, log stamp, raw CDR, the message's own type


def record_order(ctx: BagContext, topics: tuple[str, ...]) -> Iterator[Message]:
    """``(topic, log_stamp, raw, type)`` of the messages of ``topics`` in the bag's record order."""
    merged: list[tuple[int, str, int, bytes, str]] = []
    for topic in dict.fromkeys(topics):
        tdata = ctx.raw.topics.get(topic)
        if tdata is not None:
            raws = ctx.data(topic)[1]  # first: it may reorder the topic's stamps and positions
            kinds = tdata.message_types()
            merged.extend(zip(tdata.seqs, [topic] * len(tdata.seqs), tdata.stamps, raws, kinds))
    merged.sort(key=lambda item: item[0])
    for _, topic, stamp, raw, msgtype in merged:
        yield topic, int(stamp), raw, msgtype


def reread(ctx: BagContext, topics: tuple[str, ...]) -> Iterator[Message]:
    """The messages of ``topics`` read again from the storage, in record order: the same messages
    as the first read (its first ``raw.count`` wanted messages), those stamped at or after
    ``raw.cut`` left out.  Used when their bytes were not kept (decoded while reading).  The messages
    come as in the first read (:func:`~.raw.bag_messages`: QoS-string mismatches, undeclared
    compression, repeats)."""
    wanted, cut = set(topics), ctx.raw.cut
    with Reader(ctx.raw.path) as reader:
        conns = [c for c in reader.connections if c.topic in ctx.raw.topics]
        for n, (conn, stamp, data) in enumerate(bag_messages(reader, conns, [], Repeats())):
            if n >= ctx.raw.count:
                break
            if conn.topic in wanted and (cut is None or stamp < cut):
                yield conn.topic, int(stamp), data, conn.msgtype


def assembled_rows(ctx: BagContext, spec: ObservationSpec) -> AssembledRows:
    """The step rows of ``spec`` (topic names as in the bag) over the messages of ``ctx.raw``."""
    sink = ctx.raw.assembly
    if sink is None or sink.spec != spec:
        kept_bytes = all(t not in ctx.raw.topics or ctx.raw.topics[t].has_raws for t in spec.topics)
        messages = record_order(ctx, tuple(spec.topics)) if kept_bytes else reread(ctx, tuple(spec.topics))
        sink = AssemblySink(spec, len(ctx.raw.topics[spec.step_topic].stamps)
                            if spec.step_topic in ctx.raw.topics else 0)
        for topic, stamp, raw, msgtype in messages:
            sink.add(topic, stamp, raw, msgtype)
    values, kept = sink.values, np.asarray(sink.kept, bool)
    stamps = np.asarray(sink.step_stamps, dtype=np.int64)
    order = None
    if stamps.size > 1 and np.any(np.diff(stamps) < 0):
        order = np.argsort(stamps, kind="stable")
        values, stamps, kept = values[order], stamps[order], kept[order]
    names = sink.asm.obs_names() if sink.asm.dim is not None else ()
    stats = sink.asm.stats
    rejected = {f"{topic}: {reason}": n for (topic, reason), n in stats.rejected.items()}
    return AssembledRows(values, stamps, kept, order, names, dict(stats.dropped), rejected)
