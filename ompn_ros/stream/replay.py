"""Offline replay through the stream rule: recorded observations give what ``ompn_node`` publishes.

:func:`replay_episode` replays one episode (the evaluation's and ``ompn_segment``'s unit);
:func:`replay_stream` replays a recorded stream with its stamps, episode cuts by the node's rules
included (:mod:`ompn_ros.stream.rule`).  Both run :class:`~ompn_ros.stream.rule.StreamRule` over a
:class:`~ompn_ros.segmenter.StreamingSegmenter`, as the node does, so live and offline cannot drift
apart.  Cost: one model step per observation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ompn_ros.data.cuts import StillRuns
from ompn_ros.data.episode import Episode
from ompn_ros.detect.head import step_outputs
from ompn_ros.detect.online import BoundaryEvent, subtask_ends
from ompn_ros.segmenter import ReplayResult, SegmenterOutput, StreamingSegmenter
from ompn_ros.stream.rule import StreamLimits, StreamRule
from ompn_ros.validate import InvalidInput

__all__ = ["StreamRecord", "replay_episode", "replay_stream"]


@dataclass
class StreamRecord:
    """What the stream rule gave out, in order: the steps ``(episode, stamp ns, output)``, the boundaries
    ``(episode, decided stamp ns, event)``, the rejected inputs and the warning lines."""

    steps: list[tuple[int, int, SegmenterOutput]] = field(default_factory=list)
    boundaries: list[tuple[int, int, BoundaryEvent]] = field(default_factory=list)
    rejections: list[InvalidInput] = field(default_factory=list)
    events: dict[str, int] = field(default_factory=dict)  # the rule's counters at the end (replay_stream)
    warnings: list[str] = field(default_factory=list)
    strict: bool = False  # raise at the first rejected input or warning (one recorded episode)

    def step_out(self, out: SegmenterOutput, stamp_ns: int, episode: int) -> None:
        self.steps.append((episode, stamp_ns, out))

    def boundary_out(self, event: BoundaryEvent, decided_ns: int, episode: int, log: bool) -> None:
        self.boundaries.append((episode, decided_ns, event))

    def skipped(self, error: InvalidInput, by_segmenter: bool) -> None:
        if self.strict:
            raise error
        self.rejections.append(error)

    def warn_throttled(self, text: str, with_total: bool = True) -> None:
        self.warning(text)

    def warning(self, text: str) -> None:
        if self.strict:
            raise ValueError(text)
        self.warnings.append(text)


def replay_stream(
    segmenter: StreamingSegmenter,
    observations: Sequence[Any],
    stamps_ns: Sequence[int],
    limits: StreamLimits,
    sketch: np.ndarray | None = None,
    receive_ns: Sequence[int] | None = None,
    steady_ns: Sequence[int] | None = None,
) -> StreamRecord:
    """Replay a recorded stream without markers, stamps as recorded: the steps and boundaries the node
    publishes for it.  ``receive_ns``: the receiver's clock at each observation (a bag's log stamps
    beside header stamps), as the node reads it: it tells a step of the header clock from a pause or
    a restart (``limits.header_topic``) and is what ``max_stamp_lead`` is checked against; without
    it the clock is unknown (no stamp counts as from the future, no clock step is seen).  ``steady_ns``:
    the node's steady clock at each observation, beside stamps the node took at reception from its wall
    clock: it tells a step of that clock from a pause or a restart.  The last
    episode stays open, as in the node until a marker, a pause or a reset ends it."""
    record = StreamRecord()
    rule = StreamRule(record, lambda: 0, limits)
    rule.segmenter, rule.default_sketch = segmenter, sketch
    rule.arm()
    rule.start_episode(sketch)
    receive = [0] * len(stamps_ns) if receive_ns is None else receive_ns
    steady: Sequence[int | None] = [None] * len(stamps_ns) if steady_ns is None else steady_ns
    for obs, stamp, now, against in zip(observations, stamps_ns, receive, steady, strict=True):
        rule.observe(obs, int(stamp), int(now), None if against is None else int(against))
    record.events = dict(rule.events)
    return record


def replay_episode(
    segmenter: StreamingSegmenter,
    episode: Episode,
    *,
    include_done_step: bool = False,
    stamps_ns: np.ndarray | None = None,
) -> ReplayResult:
    """Feed ``episode``'s observations through ``segmenter`` exactly as the node would between a
    'start' and an 'end' marker; an observation the node would skip raises its :class:`InvalidInput`.

    With ``include_done_step`` the final observation (row T) is stepped too, as in a live stream;
    the last segment is closed at ``T - 1`` either way, and the returned arrays cover the
    ``T`` real steps only (the offline evaluation drops the done step, ``docs/craft.md`` §5.2).
    """
    record = StreamRecord(strict=True)
    rule = StreamRule(record, lambda: 0)
    rule.segmenter = segmenter
    rule.begin_episode(episode.sketch if segmenter.needs_sketch else None)  # SketchError: not usable
    T = episode.length
    n_obs = T + 1 if include_done_step else T
    for t in range(n_obs):
        rule.observe(episode.observations[t], None if stamps_ns is None else int(stamps_ns[t]), 0)
    rule.close_episode(T)
    return _episode_result(record, T, rule.rows.runs)


def _episode_result(record: StreamRecord, T: int, runs: StillRuns | None = None) -> ReplayResult:
    """The ``T`` real steps of ``record`` (one episode) as arrays, with its boundaries up to step T - 1;
    with ``runs`` (a model's ``still_tolerance``) a row per observation of the stream
    (:func:`_outputs_on_rows`)."""
    run_ends = None
    if runs is not None and runs.steps:
        record.steps, run_ends = _outputs_on_rows(record.steps, runs, T)
    published = [event for _, _, event in record.boundaries]
    outs = [out for _, _, out in record.steps[:T]]
    sos = [out.step_output for out in outs]
    return ReplayResult(
        p_hat=np.array([np.asarray(so.p_hat, dtype=np.float64) for so in sos]),
        pi=np.array([np.asarray(so.pi, dtype=np.float64) for so in sos]),
        pi_end=np.array([float(so.pi_end) for so in sos]),
        expected_position=np.array([float(so.expected_position) for so in sos]),
        scores=np.array([out.score for out in outs]),
        boundaries=_subtasks(published, outs, record.steps, T),
        actions=[so.action for so in sos],
        published=published,
        outputs=np.array([step_outputs(so) for so in sos]),
        run_ends=run_ends,
    )


def _subtasks(published: list[BoundaryEvent], outs: list[SegmenterOutput],
              steps: list[tuple[int, int, SegmenterOutput]], T: int) -> list[BoundaryEvent]:
    """One event per subtask of the episode (the episode end left out), in the ``T`` real steps: a
    boundary the detector decided on the final observation (row ``T``) ends the last real step, with
    that step's score, level and stamp."""
    out = []
    for event in subtask_ends(published):
        if event.step > T - 1 and T > 0:
            last = outs[T - 1] if len(outs) >= T else None
            stamp = steps[T - 1][1] if len(steps) >= T and event.stamp_ns else event.stamp_ns
            event = dataclasses.replace(event, step=T - 1, stamp_ns=stamp, score=last.score if last else 0.0,
                                        level=last.level if last else 0)
        out.append(event)
    return out


def _outputs_on_rows(steps: list[tuple[int, int, SegmenterOutput]], runs: StillRuns, T: int
                     ) -> tuple[list[tuple[int, int, SegmenterOutput]], np.ndarray]:
    """The stepped outputs spread over the ``T`` rows of the stream they came from, and the row of each
    step's output: the last row of its run (where its boundary lies, :meth:`StillRuns.run_of`); the
    run's earlier rows hold its memory read-out with no expansion (``p_hat`` all on the bottom slot,
    score 0)."""
    rows: list[tuple[int, int, SegmenterOutput]] = []
    ends: list[int] = []
    for j, (episode, stamp, out) in enumerate(steps):
        if runs.firsts[j] > T - 1:
            break
        first, last = runs.run_of(j, T - 1)
        if last > first:
            so = out.step_output
            still_p_hat = np.zeros_like(np.asarray(so.p_hat))
            still_p_hat[-1] = 1.0
            held_output = dataclasses.replace(so, p_hat=still_p_hat)
            held = dataclasses.replace(out, step_output=held_output, boundary=None, score=0.0, level=1)
            rows.extend((episode, stamp, dataclasses.replace(held, step_index=row))
                        for row in range(first, last))
        rows.append((episode, stamp, dataclasses.replace(out, step_index=last)))
        ends.append(last)
    return rows, np.array(ends, dtype=np.int64)
