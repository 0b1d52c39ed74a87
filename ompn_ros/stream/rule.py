"""The stream rule: how a stream of stamped observations and episode markers becomes episodes and steps.

:class:`StreamRule` is what ``ompn_node`` and the offline replay (:mod:`ompn_ros.stream.replay`) both
run, so a recorded stream replayed with its stamps gives the node's output, episode cuts included.  It
takes plain inputs (stamps in ns, the receiver's clock in ns, observations, marker text), drives one
:class:`~ompn_ros.segmenter.StreamingSegmenter` (Lu et al., ICLR 2021: one memory step per observation,
boundaries by the causal detector) and hands what happened to a :class:`StreamSink`: the accepted
steps, the boundary events, the rejected inputs and the lines worth a warning.

The rules, in the order a stamped observation meets them (``docs/parameters.md``):

* a stamp more than ``max_stamp_lead`` ahead of the receiver's clock is rejected (``future_stamp``);
* one more than ``clock_jump_back`` behind the last step is a clock restart (a restarted simulation, a
  bag played in a loop): the open episode is closed and a new one starts (``clock_jumps``);
* with ``episode_gap``, a step stamped more than that after the previous one ends the episode and
  starts the next (the bag reader's ``split: gaps``, :mod:`ompn_ros.data.cuts.gap`), as does a silence of
  that long on the receiver's clock (:meth:`StreamRule.check_silence`);
* unless the stamps are header stamps (:attr:`StreamLimits.header_topic`) and the receiver's clock did
  not move with them: then the robot's clock stepped (an NTP correction), which reshapes no episode:
  it goes on in arrival order, the step counted (``clock_steps``) and warned once
  (:mod:`ompn_ros.data.clock_steps`, the bag reader's rule; docs/specs.md, "Clocks");
* likewise for stamps the node took at reception from its wall clock, given with the node's steady
  clock beside them (``against_ns``): a step of the PC's clock moves them and not the steady clock;
* with ``idle_s``, idle observations are held until the reader's ``split: idle`` rule decides them;
* with a model whose ``still_tolerance`` is above 0, an observation that moved nothing since the last
  stepped one is not stepped (:mod:`ompn_ros.data.cuts.still`); steps and boundaries keep the stream's rows;
* a smaller step back, like any invalid observation, is rejected by the segmenter without a step.

Episode markers ('start' with an optional sketch, 'end' with the step count), sketch messages and
resets end the held input first (as the end of a bag does) and start the next episode.  Every call is
O(1) per observation, amortised.

The rule keeps the episode and applies what its parts decide: the clocks (:mod:`ompn_ros.stream.clock`),
the pause and idle gate (:mod:`ompn_ros.stream.pause`), the rows of the still rule
(:mod:`ompn_ros.stream.rows`) and the markers (:class:`EpisodeMarkers`).
"""

from __future__ import annotations

import array
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from ompn_ros import layout
from ompn_ros.data.cuts import ALL_ELEMENTS, Repeats, SpeedElements
from ompn_ros.data.messages import parse_sketch_value
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.segmenter import SegmenterOutput, StreamingSegmenter
from ompn_ros.stream.clock import StreamClocks, restart_line, step_line
from ompn_ros.stream.pause import IdleDecisions, PauseGate
from ompn_ros.stream.rows import EpisodeRows
from ompn_ros.validate import BadSketch, FutureStamp, InvalidInput, SketchError, validate_sketch

__all__ = ["EpisodeMarkers", "StreamLimits", "StreamRule", "StreamSink"]


class StreamLimits:
    """The stream parameters in seconds (as given: they appear in the warnings) and in ns (per step).

    ``header_topic``: the topic whose ``header.stamp`` stamps the observations ('' when they are
    stamped otherwise: at reception, by the middleware, by a sim's clock); its clock's steps are told
    from clock restarts and pauses against the receiver's clock."""

    def __init__(self, *, clock_jump_back: float = 1.0, max_stamp_lead: float = 0.0,
                 episode_gap: float = 0.0, idle_s: float = 0.0, idle_speed: float = 0.01,
                 idle_elements: SpeedElements = ALL_ELEMENTS, header_topic: str = "") -> None:
        self.clock_jump_back, self.max_stamp_lead = clock_jump_back, max_stamp_lead
        self.episode_gap, self.idle_s, self.idle_speed = episode_gap, idle_s, float(idle_speed)
        self.idle_elements = idle_elements  # the joint speed of a JointState observation, else every element
        self.jump_back_ns = int(float(clock_jump_back) * 1e9)
        self.max_lead_ns = int(float(max_stamp_lead) * 1e9)
        self.gap_ns = round(float(episode_gap) * 1e9)
        self.idle_ns = round(float(idle_s) * 1e9)
        self.header_topic = header_topic

    @classmethod
    def of(cls, values: Mapping[str, Any]) -> StreamLimits:
        """The limits of ``ompn_node``'s parameter values."""
        names = ("clock_jump_back", "max_stamp_lead", "episode_gap", "idle_s", "idle_speed")
        joint = values.get("obs_source") == "joint_state" and not values.get("observation_spec")
        elements = SpeedElements(tuple(values["joint_fields"])) if joint else ALL_ELEMENTS
        return cls(**{name: values[name] for name in names}, idle_elements=elements,
                   header_topic=layout.JOINT_STATES if joint else "")


class StreamSink(Protocol):
    """Where :class:`StreamRule` puts what happened (the node publishes it, the replay collects it)."""

    def step_out(self, out: SegmenterOutput, stamp_ns: int, episode: int) -> None:
        """An accepted step (its boundary, if any, was given to :meth:`boundary_out` just before)."""

    def boundary_out(self, event: BoundaryEvent, decided_ns: int, episode: int, log: bool) -> None:
        """A boundary event: at a step (``log`` False: the step logs it), or closing an episode."""

    def skipped(self, error: InvalidInput, by_segmenter: bool) -> None:
        """An input skipped without a step, counted already; ``by_segmenter``: the observation itself."""

    def warn_throttled(self, text: str, with_total: bool = True) -> None:
        """A line about bad input, at most one per throttle period."""

    def warning(self, text: str) -> None:
        """A line about the stream (an episode start refused, a clock restart), every time."""


class StreamRule:
    """The stamp and episode rules over one segmenter, with the counters they keep (:attr:`events`).

    The rule owns the episode: whether one is open (:attr:`episode_open`), the last stamp stepped and
    its rows (:attr:`rows`: the still runs); the segmenter validates, steps, detects and counts the steps
    (:meth:`StreamingSegmenter.step`; :attr:`step_index` reads its count).  Its parts decide and the rule
    applies: :attr:`clocks` (stamps from the future, clock restarts and steps) and :attr:`pauses`
    (``episode_gap``, ``idle_s``); :attr:`markers` takes the episode markers, sketch messages and resets.
    ``clock`` gives the receiver's clock in ns (0: unknown, the future check is off).  The segmenter is set
    once the model is loaded (:attr:`segmenter`); every entry point but :meth:`receive_stamp` and
    :meth:`start_episode` expects it.
    """

    def __init__(self, sink: StreamSink, clock: Callable[[], int],
                 limits: StreamLimits | None = None) -> None:
        self.sink, self.clock = sink, clock
        self.limits = limits or StreamLimits()
        self._segmenter: StreamingSegmenter | None = None
        self.events: Counter[str] = Counter()
        self.repeats = Repeats()  # messages a driver sent twice: one step (the reader's rule)
        self.default_sketch: np.ndarray | None = None
        self.episode_sketch: np.ndarray | None = None
        self.last_stamp: int | None = None  # of the last stamped step of this episode (None: none yet)
        self.closed = False  # the episode was closed (close_episode); the next starts it again
        self.rows = EpisodeRows()  # the still runs (the model's still_tolerance): steps as rows
        self.clocks = StreamClocks()  # receive stamps, clock restarts and steps
        self.pauses = PauseGate()  # episode_gap and idle_s, armed by arm()
        self.markers = EpisodeMarkers(self)  # episode markers, sketch messages, resets

    @property
    def segmenter(self) -> StreamingSegmenter | None:
        """The model's segmenter (``None`` until one is loaded); a new one starts with no step."""
        return self._segmenter

    @segmenter.setter
    def segmenter(self, segmenter: StreamingSegmenter | None) -> None:
        self._segmenter = segmenter
        self.last_stamp, self.closed = None, False
        self.rows.forget()

    def arm(self) -> None:
        """Start the clock steps and the pause and idle rules the limits ask for (the node: on activation)."""
        self.pauses.arm(self.limits)
        self.clocks.arm()

    def disarm(self) -> None:
        self.pauses.disarm()
        self.clocks.disarm()

    def receive_stamp(self, now_ns: int) -> int:
        """A stamp from the receiver's clock (:meth:`StreamClocks.receive_stamp`, ``clock_jump_back``)."""
        return self.clocks.receive_stamp(now_ns, self.limits.jump_back_ns)

    # --- observations ----------------------------------------------------------------------------
    def observe(self, data: Any, stamp_ns: int | None, now_ns: int | None = None,
                against_ns: int | None = None) -> None:
        """One observation: judged by its stamp (``now_ns``: the receiver's clock when the caller read
        it already), held by the idle rule or stepped, its outputs given to the sink.  ``against_ns``: the
        clock the stamps' clock is judged against for steps (:meth:`StreamClocks.step`)."""
        seg = self.segmenter
        assert seg is not None
        if stamp_ns is not None and not self._stamp_usable(stamp_ns, now_ns, against_ns):
            return
        decided = None if stamp_ns is None else self.pauses.hold(data, stamp_ns)
        if decided is not None:
            self._idle_decided(decided)
            return
        self._step(seg, data, stamp_ns)

    def reject(self, error: InvalidInput) -> None:
        """Count an input the caller could not use (undecodable, a bad stamp) and tell the sink."""
        assert self.segmenter is not None
        self.segmenter.count_rejection(error)
        self.sink.skipped(error, False)

    @property
    def step_index(self) -> int:
        """The episode's last step (-1: none yet): the segmenter's count (its step, reset, stop move it)."""
        return -1 if self._segmenter is None else self._segmenter.step_index

    @property
    def episode_open(self) -> bool:
        """An episode has a step and was not closed yet (a pause, a marker or a restart closes it)."""
        return self.step_index >= 0 and not self.closed

    def _stamp_usable(self, stamp_ns: int, now_ns: int | None, against_ns: int | None) -> bool:
        """Apply what :attr:`clocks` and :attr:`pauses` decide of a stamp: a far-future stamp is rejected,
        a clock restart or a pause starts a new episode (counted, warned), a step of the stamps' clock
        changes nothing but the stamp the next ones follow (counted, warned)."""
        limits = self.limits
        if now_ns is None:
            now_ns = self.clock() if limits.max_lead_ns > 0 or limits.header_topic else 0
        verdict, stepped = self.clocks.judge(stamp_ns, self.last_stamp, now_ns, against_ns, limits)
        if verdict == "future":
            self.reject(FutureStamp(f"stamp {stamp_ns} ns is more than max_stamp_lead="
                                    f"{limits.max_stamp_lead} s ahead of the node's clock"))
            return False
        gap = self.pauses.gap(stamp_ns, self.last_stamp, limits.gap_ns)
        if stepped and (verdict == "jump_back" or gap):
            # no cut, no reorder: the next stamps follow this one (one line per step)
            self.events["clock_steps"] += 1
            self.sink.warning(step_line(stepped, limits.header_topic))
            self.last_stamp = None
            return True
        if verdict == "jump_back":
            self.events["clock_jumps"] += 1
            self.sink.warning(restart_line(self.last_stamp, stamp_ns, limits.clock_jump_back))
            return self.restart_episode()
        if gap:
            return self.end_at_pause()
        return True

    def _step(self, seg: StreamingSegmenter, data: Any, stamp_ns: int | None) -> None:
        packed = isinstance(data, array.array) and data.typecode == "f"
        obs = np.frombuffer(data, dtype=np.float32) if packed else data
        hold = self.rows.hold(seg.still_tolerance)  # a still observation joins the open run, no step
        try:
            out = seg.step(obs, stamp_ns, after_ns=self.last_stamp, hold=hold)
        except InvalidInput as exc:
            self.sink.skipped(exc, True)
            return
        if out is None:
            self.events["still_observations"] += 1
            return
        if stamp_ns is not None:
            self.last_stamp = int(stamp_ns)
        if out.step_index == 0:
            self.events["episodes"] += 1
        out = self.rows.output(out)  # the rows and stamps of the recorded stream
        # The boundary event goes out first: it is the latency-critical product of the node.
        if out.boundary is not None:
            self.emit_boundary(out.boundary, log=False)
        self.sink.step_out(out, 0 if stamp_ns is None else int(stamp_ns), self.events["episodes"])

    def _idle_decided(self, decided: IdleDecisions) -> None:
        """Step and close what the idle rule decided, in order (:meth:`PauseGate.hold` / ``flush``); an
        episode the rule ended is decided where the rule decided it (:attr:`PauseGate.decided`)."""
        for kind, x, stamp in decided:
            seg = self.segmenter
            if seg is None:
                return
            if kind == "start":
                self.start_episode(self.episode_sketch, count_bad=False)
            if x is not None:
                self._step(seg, x, stamp)
            if kind == "end" and self.episode_open:
                # the final observation (row T) is the last one given to the segmenter
                final = self.rows.last(self.step_index)
                held = self.pauses.decided
                self.close_episode(final, None if held is None else (final + held[0], held[1]))

    def emit_boundary(self, event: BoundaryEvent, decided_ns: int | None = None, log: bool = True) -> None:
        """Give ``event`` to the sink, decided at ``decided_ns`` (default: the last step's stamp)."""
        decided = (self.last_stamp or 0) if decided_ns is None else decided_ns
        self.sink.boundary_out(event, decided, self.events["episodes"], log)
        self.events["boundaries"] += 1

    # --- episodes --------------------------------------------------------------------------------
    def start_episode(self, sketch: np.ndarray | None, count_bad: bool = True) -> bool:
        """Reset the memory and every per-episode state (stamps included) for a new episode; an unusable
        sketch stops the segmenter until the next start (counted with ``count_bad``, warned)."""
        seg = self.segmenter
        if seg is None:
            return False
        try:
            self.begin_episode(sketch)
        except SketchError as exc:
            self.stop()
            if count_bad:
                seg.count_rejection(BadSketch(str(exc)))
            self.sink.warning(f"episode start rejected: {exc}; waiting for the next valid start")
            return False
        return True

    def begin_episode(self, sketch: np.ndarray | None) -> None:
        """:meth:`start_episode` that raises :class:`SketchError` for a sketch the model cannot use
        (``None`` or empty: the latest sketch message, else the default sketch)."""
        seg = self.segmenter
        assert seg is not None
        if sketch is None or sketch.size == 0:
            latest = self.markers.latest_sketch
            sketch = latest if latest is not None else self.default_sketch
        seg.reset(sketch)
        self.rows.forget()
        self.clocks.last_receive_ns = 0
        self.last_stamp, self.closed = None, False
        self.episode_sketch = sketch

    def stop(self) -> None:
        """An episode start was refused: no steps until the next valid start."""
        assert self.segmenter is not None
        self.segmenter.stop()

    def close_episode(self, steps: int | None, decided: tuple[int, int] | None = None) -> None:
        """Close the episode at ``steps - 1`` (the marker's count; the last step seen if unknown): the
        boundaries the detector still decides, the last ``final`` (the last segment's boundary, or the
        episode end when the end of the last subtask was published before: docs/design.md#episode-end).
        ``decided``: ``(row, stamp)`` of the observation that decided the end, when later than the last
        one stepped (the idle rule's); the closing boundaries carry it as their decided step and stamp."""
        seg = self.segmenter
        assert seg is not None
        last = self.rows.last(self.step_index)
        if steps is not None and steps < last:  # fewer steps than observed: the marker is wrong
            self.events["bad_end_markers"] += 1
            self.sink.warning(
                f"end marker says steps={steps} after {last + 1} observations: closing at the last step seen"
            )
            steps = None
        last_row = None if steps is None or steps <= 0 else steps - 1
        steps = self.rows.steps_before(steps)  # the marker counts rows; the detector, steps
        closing = seg.end_episode(steps - 1 if steps is not None and steps > 0 else None)
        self.closed = True
        self.events["episodes_ended"] += 1
        for event in closing:
            mapped = self.rows.event(event, last_row)
            assert mapped is not None
            if decided is not None:
                mapped = replace(mapped, detected_at=max(mapped.detected_at, decided[0]))
            self.emit_boundary(mapped, decided_ns=None if decided is None else decided[1])

    def restart_episode(self) -> bool:
        """A clock restart: close the open episode, start the next (counted); False if it cannot start."""
        if self.episode_open:
            self.close_episode(None)
        started = self.start_episode(self.episode_sketch, count_bad=False)
        self.events["episode_starts"] += int(started)
        return started

    def end_at_pause(self) -> bool:
        """``episode_gap``: close the open episode as an end marker would and start the next one."""
        if self.episode_open:
            self.close_episode(None)
        self.events["episode_gaps"] += 1
        self.pauses.paused()
        return self.start_episode(self.episode_sketch, count_bad=False)

    def check_silence(self) -> None:
        """``episode_gap`` polled by a timer: end an open episode that had no step for that long."""
        seg = self.segmenter
        open_episode = seg is not None and seg.ready and self.episode_open
        if seg is not None and self.pauses.quiet(self.clock, self.step_index, open_episode):
            self.end_at_pause()

    # --- the held input ------------------------------------------------------------------------
    def input_ends(self) -> None:
        """Before an episode marker or a reset: with ``idle_s`` the held idle observations end the
        open episode as at the end of a bag (the first is its final observation, the others trimmed);
        the next message is never a repeat of one before."""
        self.repeats.forget()
        self._idle_decided(self.pauses.flush())


class EpisodeMarkers:
    """The episode markers, sketch messages and resets of a stream rule, the rule's part: each ends the
    held input (:meth:`StreamRule.input_ends`) and starts the next episode, with the sketch it names,
    else the latest one (:attr:`latest_sketch`), else the default."""

    def __init__(self, rule: StreamRule) -> None:
        self.rule = rule
        self.latest_sketch: np.ndarray | None = None  # of the last sketch message or start marker

    def marker(self, kind: str, values: Mapping[str, str]) -> None:
        """An episode marker (``layout.EPISODE_START`` / ``EPISODE_END``) with its key-value pairs."""
        rule, seg = self.rule, self.rule.segmenter
        assert seg is not None
        rule.events["markers"] += 1
        rule.input_ends()
        if kind == layout.EPISODE_START:
            self.start_marker(values.get(layout.KEY_SKETCH, ""))
        elif kind == layout.EPISODE_END and seg.ready:
            steps = _int_or_none(values.get(layout.KEY_STEPS, ""))
            if not rule.closed:
                rule.close_episode(steps)
            rule.start_episode(rule.episode_sketch, count_bad=False)  # steps before the next start

    def start_marker(self, text: str) -> None:
        """A 'start' marker whose sketch value is ``text`` ('' = none: the latest sketch or the default)."""
        rule, seg = self.rule, self.rule.segmenter
        assert seg is not None
        try:
            sketch = parse_sketch_value(text, seg.sketch_vocab if seg.needs_sketch else None)
        except SketchError as exc:
            seg.count_rejection(BadSketch(str(exc)))
            if seg.needs_sketch:
                rule.stop()
                rule.sink.warning(f"episode start rejected: marker {exc}; waiting for the next valid start")
                return
            sketch = None  # this model ignores sketches: the episode starts anyway
        self.latest_sketch = sketch if sketch is not None and sketch.size else None
        if rule.start_episode(sketch):
            rule.events["episode_starts"] += 1

    def sketch_message(self, values: Any) -> None:
        """A sketch message (subtask ids) for the coming episode; it restarts one that has no step yet."""
        rule, seg = self.rule, self.rule.segmenter
        assert seg is not None
        sketch = np.asarray(values, dtype=np.int64)
        if seg.needs_sketch:
            try:
                sketch = validate_sketch(sketch, seg.sketch_vocab)
            except SketchError as exc:
                seg.count_rejection(BadSketch(str(exc)))
                rule.sink.warn_throttled(f"sketch message rejected: {exc}")
                return
        self.latest_sketch = sketch
        if not seg.ready or rule.step_index < 0:  # no step yet: the episode starts with this sketch
            rule.start_episode(sketch)

    def reset(self) -> bool:
        """A reset request: the held input ends, a new episode starts with this episode's sketch."""
        rule = self.rule
        rule.input_ends()
        started = rule.start_episode(rule.episode_sketch)
        rule.events["episode_starts"] += int(started)
        return started


def _int_or_none(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None
