"""Observations assembled from several topics of one bag (``ReaderSpec.assemble``).

The bag's messages of the spec's topics are fed, in record order with their log stamps, to
:func:`ompn_ros.data.obs.assemble_stream`: the same :class:`~ompn_ros.data.obs.ObservationAssembler`
the live node runs, so a bag recorded from the live callbacks gives the live observations.  Every
step-topic message is a row of the step clock (its log stamp); rows the rule dropped keep zeros and
``kept = False`` and are removed after actions and labels are attached (``reader.assemble``).

Cost: O(M log M) to merge the M messages of the spec's topics into record order, then
O(M + S · D) in the assembler for S steps of size D.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ..obs import ObservationSpec, assemble_stream
from .context import BagContext


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


def record_order(ctx: BagContext, topics: tuple[str, ...]) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, log_stamp, raw)`` of the messages of ``topics`` in the bag's record order."""
    merged: list[tuple[int, str, int, bytes]] = []
    for topic in dict.fromkeys(topics):
        tdata = ctx.raw.topics.get(topic)
        if tdata is not None:
            merged.extend(zip(tdata.seqs, [topic] * len(tdata.seqs), tdata.stamps, tdata.raws))
    merged.sort(key=lambda item: item[0])
    for _, topic, stamp, raw in merged:
        yield topic, int(stamp), raw


def assembled_rows(ctx: BagContext, spec: ObservationSpec) -> AssembledRows:
    """The step rows of ``spec`` (topic names as in the bag) over the messages of ``ctx.raw``."""
    stream = assemble_stream(record_order(ctx, tuple(spec.topics)), spec)
    n_steps, dim = len(stream.step_log_stamps), stream.observations.shape[1]
    values = np.zeros((n_steps, dim), dtype=np.float32)
    values[stream.kept] = stream.observations
    stamps, kept = stream.step_log_stamps, stream.kept
    order = None
    if stamps.size > 1 and np.any(np.diff(stamps) < 0):
        order = np.argsort(stamps, kind="stable")
        values, stamps, kept = values[order], stamps[order], kept[order]
    rejected = {f"{topic}: {reason}": n for (topic, reason), n in stream.stats.rejected.items()}
    return AssembledRows(values, stamps, kept, order, stream.names, dict(stream.stats.dropped), rejected)
