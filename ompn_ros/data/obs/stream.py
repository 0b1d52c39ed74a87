"""The offline path: drive one :class:`ObservationAssembler` over recorded messages in record order.

Because this is the live assembler fed in the order the messages were recorded (with the log time
as the caller's stamp and as the clock of the wait), a bag recorded from the live callbacks gives
the live observations exactly; and steps whose partners came late are decided by the stamp rule
(``wait_s``, :mod:`.assembler`), whatever the record order.
Complexity: O(messages + steps * D).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from .assembler import AssemblerStats, Decided, Drop, ObservationAssembler
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
    flush: bool = True,
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
        flush: decide the steps still held at the end (counted ``late`` when a partner had not caught
            up); ``False`` leaves them held in ``assembler`` for the next call (the next file).
    """
    if assembler is not None and assembler.spec != spec:
        raise ValueError("assemble_stream: the given assembler was built for another observation spec")
    asm = assembler if assembler is not None else ObservationAssembler(spec)
    problems = [p for t, name in (types or {}).items() if (p := asm.check_type(t, name)) is not None]
    step_topic = spec.step_topic
    out = _Collected()
    for topic, stamp, raw in messages:
        if topic != step_topic:
            asm.offer(topic, stamp, raw)
        else:
            asm.hold(stamp, raw)
        out.add(asm.release(int(stamp)))
    if flush:
        out.add(asm.release(flush=True))
    dim = asm.dim
    obs = np.stack(out.rows) if out.rows else np.zeros((0, dim or 0), dtype=np.float32)
    return AssembledStream(
        observations=obs,
        stamps=np.asarray(out.stamps, dtype=np.int64),
        log_stamps=np.asarray(out.log_stamps, dtype=np.int64),
        kept=np.asarray(out.kept, dtype=bool),
        step_log_stamps=np.asarray(out.step_log_stamps, dtype=np.int64),
        drops=tuple(out.drops),
        stats=asm.stats,
        names=asm.obs_names() if dim is not None else (),
        type_problems=tuple(problems),
    )


@dataclass
class _Collected:
    """The decided steps of a stream, in step order."""

    rows: list[np.ndarray] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    log_stamps: list[int] = field(default_factory=list)
    kept: list[bool] = field(default_factory=list)
    step_log_stamps: list[int] = field(default_factory=list)
    drops: list[Drop] = field(default_factory=list)

    def add(self, decided: list[Decided]) -> None:
        for d in decided:
            self.step_log_stamps.append(d.receive_ns)
            self.kept.append(not isinstance(d.result, Drop))
            if isinstance(d.result, Drop):
                self.drops.append(d.result)
                continue
            self.rows.append(d.result)
            self.stamps.append(d.stamp_ns)
            self.log_stamps.append(d.receive_ns)
