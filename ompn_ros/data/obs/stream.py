"""The offline path: drive one :class:`ObservationAssembler` over recorded messages in record order.

Because this is the live assembler fed in the order the messages were recorded (with the log time
as the caller's stamp), a bag recorded from the live callbacks gives the live observations exactly.
Complexity: O(messages + steps * D).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from .assembler import AssemblerStats, Drop, ObservationAssembler
from .spec import ObservationSpec


@dataclass(frozen=True)
class AssembledStream:
    """Observations of a recorded stream.

    Attributes:
        observations: float32 ``[N, D]``, the kept steps in record order.
        stamps: int64 ``[N]`` stamps of the kept steps under the spec's stamp rule.
        log_stamps: int64 ``[N]`` record (log) stamps of the kept steps.
        kept: bool ``[S]``, one per step-topic message in record order (``N = kept.sum()``).
        step_log_stamps: int64 ``[S]`` record stamps of every step-topic message, kept or dropped (the
            bag's step clock: align other per-step topics on it, then remove the dropped steps).
        drops: one :class:`Drop` per dropped step, in record order.
        stats: the assembler's counters (steps, kept, dropped by reason, rejected partner messages).
        names: element names of the observation (empty when no step was kept and the size is not
            declared).
        type_problems: one line per topic of the spec whose recorded type differs from the spec.
    """

    observations: np.ndarray
    stamps: np.ndarray
    log_stamps: np.ndarray
    kept: np.ndarray
    step_log_stamps: np.ndarray
    drops: tuple[Drop, ...]
    stats: AssemblerStats
    names: tuple[str, ...]
    type_problems: tuple[str, ...] = ()


def assemble_stream(
    messages: Iterable[tuple[str, int, bytes | memoryview]],
    spec: ObservationSpec,
    *,
    types: Mapping[str, str] | None = None,
    assembler: ObservationAssembler | None = None,
) -> AssembledStream:
    """Assemble ``(topic, log_stamp_ns, raw)`` messages (in record order) into observations.

    Args:
        messages: every message of the recording in record order; topics the spec does not use
            are ignored (counted).
        spec: the observation spec (topic names as recorded: resolve namespaces first).
        types: ``topic -> type name`` of the recording (the bag's connections); topics whose type
            differs from the spec are reported in ``type_problems`` and their messages rejected.
        assembler: continue with this assembler (its partner history and counters) instead of a
            fresh one, e.g. across the files of one recording.
    """
    if assembler is not None and assembler.spec != spec:
        raise ValueError("assemble_stream: the given assembler was built for another observation spec")
    asm = assembler if assembler is not None else ObservationAssembler(spec)
    problems = [p for t, name in (types or {}).items() if (p := asm.check_type(t, name)) is not None]
    step_topic = spec.step_topic
    rows: list[np.ndarray] = []
    stamps: list[int] = []
    log_stamps: list[int] = []
    kept: list[bool] = []
    step_log_stamps: list[int] = []
    drops: list[Drop] = []
    for topic, stamp, raw in messages:
        if topic != step_topic:
            asm.offer(topic, stamp, raw)
            continue
        result = asm.step(stamp, raw)
        step_log_stamps.append(int(stamp))
        kept.append(not isinstance(result, Drop))
        if isinstance(result, Drop):
            drops.append(result)
            continue
        rows.append(result)
        stamps.append(asm.last_stamp_ns if asm.last_stamp_ns is not None else int(stamp))
        log_stamps.append(int(stamp))
    dim = asm.dim
    obs = np.stack(rows) if rows else np.zeros((0, dim or 0), dtype=np.float32)
    return AssembledStream(
        observations=obs,
        stamps=np.asarray(stamps, dtype=np.int64),
        log_stamps=np.asarray(log_stamps, dtype=np.int64),
        kept=np.asarray(kept, dtype=bool),
        step_log_stamps=np.asarray(step_log_stamps, dtype=np.int64),
        drops=tuple(drops),
        stats=asm.stats,
        names=asm.obs_names() if dim is not None else (),
        type_problems=tuple(problems),
    )
