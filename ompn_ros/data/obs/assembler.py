"""ObservationAssembler: the one rule that turns several topics into one observation per step.

The rule (``ompn_node`` applies it live, the bag reader offline through
:func:`ompn_ros.data.obs.stream.assemble_stream`, with this same class):

* Every message of ``spec.step_topic`` is a **step**: it gives one observation or one counted
  :class:`Drop`.  The observation is ``spec.fields`` concatenated in order (float32).
* Fields of the step topic come from the step message itself.  Fields of every other (*partner*)
  topic come from **the latest message of that topic stamped at or before the step**, on the
  partner's clock: a partner stamped by its headers is compared with the step's stamp, a partner
  stamped at reception with the step's reception (so a backlog of the caller, which delays every
  reception alike, does not age it).  It must be at most ``spec.tolerance_s`` older than the step;
  for a partner stamped at reception, a header-stamped step's age is measured from its *on-time
  reception* (its header stamp plus the smallest reception − header offset of the last
  :data:`ON_TIME_WINDOW` header-stamped steps) when that is earlier than its reception.  So a step
  that the caller served late (a stalled process, a queue served out of order) is not dropped
  because its partner messages queued behind it: the partner it is given is the same, only its age
  is not inflated by the stall.
* Otherwise the step is dropped, and counted by reason: ``missing`` (no partner message at or
  before the step), ``stale`` (older than the tolerance), ``malformed`` (undecodable bytes, or a
  JointState lacking a joint of the spec), ``wrong_size`` (a field with another element count than
  declared or than its first message), ``wrong_type`` (the topic has another type than the spec;
  see :meth:`ObservationAssembler.check_type`).  A partner message that is malformed or of the
  wrong size is rejected when offered (counted) and still *occupies its stamp*: a step whose latest
  partner at or before it is that message is dropped with the message's reason rather than silently
  using an older one.
* **Stamps**: with ``spec.stamp == 'header'`` a message's stamp is its ``header.stamp`` when its type
  has a header (JointState, WrenchStamped, PoseStamped) and the stamp is not zero; otherwise, and
  always with ``'receive'``, it is the ``stamp_ns`` given by the caller: the receive time live (the
  subscription callback's clock), the log (record) time offline.
* **Waiting** (``spec.wait_s``): a step is decided once every partner topic whose stamps come from
  its headers (``stamp: header`` and a type with a header) has offered a message stamped at or after
  the step, so a partner message that arrives after its step, but is stamped before it, is still
  used.  Until then the step is *held* (:meth:`ObservationAssembler.hold`) and held steps are
  released in step order (:meth:`ObservationAssembler.release`).  The decision is then the stamp
  rule above, whatever the arrival order, which is what the bag reader computes from the same
  messages.  Partners stamped at reception are never waited for (a later message is stamped later)
  and a single-topic spec never holds.  A step still waiting ``wait_s`` after it arrived (on the
  caller's clock: the receive time live, the log time offline), or pushed out of the bounded queue,
  or flushed (episode marker, reset, end of the recording) is decided with what has arrived and
  counted ``late`` (``stats.late``; it may still be kept).  ``wait_s: 0`` decides every step on
  arrival; :meth:`ObservationAssembler.step` does the same for one step.

Complexity: a step costs O(D + Σ log h) (``h`` = kept history per partner topic, at most
``2 * history``); an offered partner message O(its size + log h) amortised; a release check O(P)
for P waited-for partner topics.
"""

from __future__ import annotations

from bisect import bisect_right, insort
from collections import deque
from collections.abc import Container
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .extract import ExtractError, TopicExtractor, extractors, layout_of
from .spec import ObservationSpec, canonical_type

ON_TIME_WINDOW = 256
"""Header-stamped steps over which the smallest reception − header offset is taken (module docstring)."""

DropReason = Literal["missing", "stale", "malformed", "wrong_size", "wrong_type"]
DROP_REASONS: tuple[DropReason, ...] = ("missing", "stale", "malformed", "wrong_size", "wrong_type")


@dataclass(frozen=True)
class Drop:
    """Why a step gave no observation (or, returned by ``offer``, why a partner message was rejected).

    Attributes:
        reason: one of :data:`DROP_REASONS`.
        topic: the topic at fault (the step topic or a partner topic).
        stamp_ns: the stamp of the step (or of the rejected message) under the stamp rule.
        detail: one human-readable line.
    """

    reason: DropReason
    topic: str
    stamp_ns: int
    detail: str = ""

    def __str__(self) -> str:
        return f"{self.reason} on '{self.topic}' at {self.stamp_ns} ns: {self.detail}"


@dataclass(frozen=True)
class Decided:
    """One step decided by the assembler, released in step order.

    Attributes:
        receive_ns: the caller's stamp of the step message (receive time live, log time offline).
        stamp_ns: the step's stamp under the stamp rule.
        result: the observation (float32 ``[dim]``) or the counted :class:`Drop`.
        late: decided before every waited-for partner had caught up (wait over, queue full or flush).
    """

    receive_ns: int
    stamp_ns: int
    result: np.ndarray | Drop
    late: bool = False


@dataclass
class AssemblerStats:
    """Counters of an assembler (cumulative until ``reset(clear_stats=True)``).

    Attributes:
        steps: step messages fed; ``kept + sum(dropped.values()) + held == steps``.
        kept: steps that gave an observation.
        late: steps decided before every waited-for partner had caught up (kept or dropped).
        dropped: dropped steps by reason.
        rejected: rejected partner messages (and wrong-type reports) by ``(topic, reason)``.
        ignored: messages offered on topics the spec does not use.
    """

    steps: int = 0
    kept: int = 0
    late: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    rejected: dict[tuple[str, str], int] = field(default_factory=dict)
    ignored: int = 0

    def as_dict(self) -> dict[str, int]:
        """Flat counters for diagnostics: ``steps``, ``kept``, ``late``, ``dropped.<reason>``,
        ``rejected.<topic>.<reason>``, ``ignored``."""
        out = {"steps": self.steps, "kept": self.kept, "late": self.late, "ignored": self.ignored}
        out.update({f"dropped.{r}": n for r, n in sorted(self.dropped.items())})
        out.update({f"rejected.{t}.{r}": n for (t, r), n in sorted(self.rejected.items())})
        return out


class _History:
    """Partner messages of one topic sorted by stamp: extracted vectors, or the rejection."""

    __slots__ = ("entries", "limit", "stamps")

    def __init__(self, limit: int) -> None:
        self.stamps: list[int] = []
        self.entries: list[list[np.ndarray] | Drop] = []
        self.limit = limit

    def add(self, stamp: int, entry: list[np.ndarray] | Drop) -> None:
        if not self.stamps or stamp >= self.stamps[-1]:
            self.stamps.append(stamp)
            self.entries.append(entry)
        else:  # out of order: keep the list sorted (equal stamps: the later message wins)
            i = bisect_right(self.stamps, stamp)
            insort(self.stamps, stamp)
            self.entries.insert(i, entry)
        if len(self.stamps) > 2 * self.limit:
            del self.stamps[: self.limit]
            del self.entries[: self.limit]

    def clear(self) -> None:
        self.stamps.clear()
        self.entries.clear()


class _OnTimeReception:
    """The smallest ``receive - stamp`` offset of the last ``window`` steps (a monotonic queue, O(1)
    amortised per step): ``stamp + offset`` is when a step would have been received without backlog."""

    __slots__ = ("_n", "_queue", "window")

    def __init__(self, window: int = ON_TIME_WINDOW) -> None:
        self.window = window
        self._n = 0
        self._queue: deque[tuple[int, int]] = deque()  # (step number, offset), offsets increasing

    def of(self, receive: int, stamp: int) -> int:
        """Add one header-stamped step and return its on-time reception (never after ``receive``)."""
        self._n += 1
        offset, queue = receive - stamp, self._queue
        while queue and queue[-1][1] >= offset:
            queue.pop()
        queue.append((self._n, offset))
        if queue[0][0] <= self._n - self.window:
            queue.popleft()
        return stamp + queue[0][1]

    def clear(self) -> None:
        self._queue.clear()


class _Partners:
    """The partner topics' messages, a sorted :class:`_History` each, and for the partners a held
    step waits for (``waited``) the latest stamp each has offered."""

    __slots__ = ("by_header", "history", "tol_ns", "tolerance_s", "waited")

    def __init__(self, spec: ObservationSpec, by_header: frozenset[str], history: int) -> None:
        self.history = {t: _History(history) for t in spec.partner_topics}
        self.by_header = by_header  # the partners stamped by their headers (compared with the step's stamp)
        waited = [t for t in spec.partner_topics if t in by_header]
        self.waited: dict[str, int | None] = dict.fromkeys(waited if spec.wait_s > 0 else ())
        self.tolerance_s = spec.tolerance_s
        self.tol_ns = round(spec.tolerance_s * 1e9)

    def add(self, topic: str, hist: _History, stamp: int, entry: list[np.ndarray] | Drop) -> None:
        hist.add(stamp, entry)
        if topic in self.waited:
            last = self.waited[topic]
            self.waited[topic] = stamp if last is None or stamp > last else last

    def settled(self, stamp: int, wrong_type: Container[str]) -> bool:
        """Every waited-for partner (but those of the wrong type) has offered a message stamped at or
        after ``stamp``."""
        for topic, last in self.waited.items():
            if (last is None or last < stamp) and topic not in wrong_type:
                return False
        return True

    def latest(self, topic: str, stamp: int, receive: int, on_time: int) -> list[np.ndarray] | Drop:
        """The latest message of ``topic`` stamped at or before the step, at most the tolerance older
        than it, or the Drop: on the step's stamp for a partner stamped by its headers, else on its
        reception (aged from its on-time reception)."""
        at, aged_from = (stamp, stamp) if topic in self.by_header else (receive, on_time)
        hist = self.history[topic]
        i = bisect_right(hist.stamps, at) - 1
        if i < 0:
            detail = ("no message yet" if not hist.stamps else "no message at or before the step "
                      f"(the oldest kept is {hist.stamps[0] - at} ns later)")
            return Drop("missing", topic, at, detail)
        entry = hist.entries[i]
        if isinstance(entry, Drop):
            return Drop(entry.reason, topic, at, f"its latest message was rejected: {entry.detail}")
        age = aged_from - hist.stamps[i]
        if age > self.tol_ns:
            return Drop("stale", topic, at, f"its latest message is {age / 1e6:.3f} ms older than the "
                        f"step (tolerance {self.tolerance_s * 1e3:g} ms)")
        return entry

    def clear(self) -> None:
        for hist in self.history.values():
            hist.clear()
        self.waited = dict.fromkeys(self.waited)


class _Layout:
    """Where each field's vector goes in the observation: its size and element names, pinned once
    every field's size is known (declared, or by the first messages)."""

    __slots__ = ("dim", "extractors", "names", "slots", "spec")

    def __init__(self, spec: ObservationSpec, extractors: dict[str, TopicExtractor]) -> None:
        self.spec = spec
        self.extractors = extractors
        self.dim: int | None = None
        self.names: tuple[str, ...] = ()
        self.slots: list[tuple[str, int, slice]] | None = None

    def known(self) -> int | None:
        """The observation size, ``None`` while a field's size is unknown."""
        if self.dim is None and all(s is not None for ex in self.extractors.values() for s in ex.sizes):
            self.resolve()
        return self.dim

    def resolve(self) -> None:
        self.dim, self.names = layout_of(self.spec, self.extractors)
        slots, start, k = [], 0, dict.fromkeys(self.extractors, 0)
        for f in self.spec.fields:
            size = self.extractors[f.topic].sizes[k[f.topic]]
            assert size is not None
            slots.append((f.topic, k[f.topic], slice(start, start + size)))
            k[f.topic] += 1
            start += size
        self.slots = slots

    def fill(self, values: dict[str, list[np.ndarray]]) -> np.ndarray:
        """The observation (float32, a new array) of one step's vectors by topic."""
        if self.slots is None:
            self.resolve()
        assert self.slots is not None and self.dim is not None
        out = np.empty(self.dim, dtype=np.float32)
        for name, k, where in self.slots:
            out[where] = values[name][k]
        return out


class ObservationAssembler:
    """Incremental observation assembly under the rule of this module (not thread-safe).

    Example::

        asm = ObservationAssembler(spec)
        asm.offer('/arm1/gripper', receive_ns, raw)         # partner topics
        asm.hold(receive_ns, raw)                            # step topic
        for d in asm.release(now_ns):                        # call on every message and now and then
            use(d.stamp_ns, d.result)                        # np.ndarray or Drop, in step order

    Args:
        spec: the observation spec (topic names as they will be fed: resolve namespaces first).
        history: partner messages kept per topic (at least this many, at most twice).
        max_held: steps held at most (default ``history``); one more releases the oldest as ``late``.
    """

    def __init__(self, spec: ObservationSpec, history: int = 256, max_held: int | None = None) -> None:
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        if max_held is not None and max_held < 1:
            raise ValueError(f"max_held must be >= 1, got {max_held}")
        self.spec = spec
        self._ex: dict[str, TopicExtractor] = extractors(spec)
        self._step_ex = self._ex[spec.step_topic]
        self._header = spec.stamp == "header"
        self._wrong_type: dict[str, str] = {}
        self._layout = _Layout(spec, self._ex)
        self.stats = AssemblerStats()
        self.last_stamp_ns: int | None = None  # stamp (under the stamp rule) of the last step fed
        by_header = frozenset(t for t in spec.partner_topics if self._header and self._ex[t].has_header)
        self._partners = _Partners(spec, by_header, history)
        self._wait_ns = round(spec.wait_s * 1e9)
        self._max_held = history if max_held is None else max_held
        self._held: deque[tuple[int, int, int, list[np.ndarray] | Drop]] = deque()
        self._on_time = _OnTimeReception()

    @property
    def step_header_stamped(self) -> bool:
        """Steps are stamped by the step topic's ``header.stamp`` (``stamp: header``, a type with one)."""
        return self._header and self._step_ex.has_header

    # --- layout -----------------------------------------------------------------------------------
    @property
    def dim(self) -> int | None:
        """Observation size, ``None`` until known (declared, or after the first kept step)."""
        return self._layout.known()

    def obs_names(self) -> tuple[str, ...]:
        """Element names (``<topic>/<field>/<label>``); raises ``ValueError`` while the size is unknown."""
        if self.dim is None:
            raise ValueError("the observation layout is not known until the first kept step")
        return self._layout.names

    # --- feeding ----------------------------------------------------------------------------------
    def check_type(self, topic: str, typename: str) -> str | None:
        """Declare the type ``topic`` has (from the ROS graph or the bag); returns the one-line problem
        when it differs from the spec (then every message of it is rejected and every step dropped as
        ``wrong_type``, until a call with the right type), ``None`` when it is fine or not used.
        The report itself is counted once per change (``rejected[(topic, 'wrong_type')]``), so the
        graph may be polled."""
        if topic not in self._ex:
            return None
        want = self._ex[topic].type
        if canonical_type(typename) == want:
            self._wrong_type.pop(topic, None)
            return None
        problem = f"topic '{topic}' has type {typename}, the observation spec expects {want}"
        if self._wrong_type.get(topic) != problem:  # counted once per change, not per poll of the graph
            self._wrong_type[topic] = problem
            self._count_rejected(topic, "wrong_type")
        return problem

    def for_type(self, topic: str, msgtype: str) -> None:
        """Accept messages of ``msgtype`` on ``topic`` besides the spec's type (a bag topic recorded
        under several types), each read by its own type (``msgtype`` of :meth:`offer`, :meth:`step`);
        raises :class:`~ompn_ros.data.errors.ObservationSpecError` when the type lacks a field."""
        self._ex[topic].for_type(msgtype)

    def offer(self, topic: str, stamp_ns: int, raw: bytes | memoryview,
              msgtype: str | None = None) -> Drop | None:
        """Feed a message of a partner topic; returns its rejection (counted) or ``None``.

        ``stamp_ns`` is the receive time (live) or the log time (offline).  Messages of topics the
        spec does not use are ignored (counted); a step-topic message must go to :meth:`step`.
        ``msgtype``: the message's type when :meth:`for_type` declared it (``None``: the spec's).
        """
        hist = self._partners.history.get(topic)
        if hist is None:
            if topic == self.spec.step_topic:
                raise ValueError(f"'{topic}' is the step topic: feed it to step(), not offer()")
            self.stats.ignored += 1
            return None
        if topic in self._wrong_type:
            self._count_rejected(topic, "wrong_type")
            return Drop("wrong_type", topic, int(stamp_ns), self._wrong_type[topic])
        if not isinstance(raw, bytes):  # the kept vectors may view the bytes: never a reusable buffer
            raw = bytes(raw)
        try:
            header, vectors = self._ex[topic].extract(raw, msgtype)
        except ExtractError as err:
            rejection = Drop(err.reason, topic, int(stamp_ns), err.detail)
            self._partners.add(topic, hist, int(stamp_ns), rejection)
            self._count_rejected(topic, err.reason)
            return rejection
        self._partners.add(topic, hist, header if header is not None and self._header else int(stamp_ns),
                           vectors)
        return None

    def step(self, stamp_ns: int, raw: bytes | memoryview, msgtype: str | None = None) -> np.ndarray | Drop:
        """Feed a message of the step topic and decide it at once, without waiting: its observation
        (float32 ``[dim]``, a new array) or the counted :class:`Drop`.  ``stamp_ns`` as in
        :meth:`offer` (``msgtype`` too).  Not to be mixed with :meth:`hold` while steps are held."""
        if self._held:
            raise ValueError("step() while steps are held: release(flush=True) first, or use hold()")
        self.stats.steps += 1
        stamp, on_time, parsed = self._parse_step(int(stamp_ns), raw, msgtype)
        return self._decide(int(stamp_ns), stamp, on_time, parsed)

    def hold(self, stamp_ns: int, raw: bytes | memoryview) -> None:
        """Feed a message of the step topic; it is decided by :meth:`release` (module docstring).
        ``stamp_ns`` as in :meth:`offer`, and the start of the step's wait."""
        self.stats.steps += 1
        if not isinstance(raw, bytes):  # the held vectors may view the bytes: never a reusable buffer
            raw = bytes(raw)
        self._held.append((int(stamp_ns), *self._parse_step(int(stamp_ns), raw)))

    @property
    def waited_topics(self) -> tuple[str, ...]:
        """The partner topics a held step waits for (stamped by their headers; none if ``wait_s`` is 0)."""
        return tuple(self._partners.waited)

    @property
    def held(self) -> int:
        """Steps fed to :meth:`hold` and not yet released."""
        return len(self._held)

    def release(self, now_ns: int | None = None, flush: bool = False) -> list[Decided]:
        """Decide the held steps that can be decided, oldest first, and return them in step order.

        A step is decided when every waited-for partner has offered a message stamped at or after it;
        else when ``now_ns`` (the caller's clock, as the stamps given to :meth:`hold`) is ``wait_s``
        past its arrival, when more than ``max_held`` steps are held, or with ``flush``: then it is
        decided with what has arrived and counted ``late``.  A later step never overtakes an earlier one.
        """
        out: list[Decided] = []
        while self._held:
            receive, stamp, on_time, parsed = self._held[0]
            late = False
            if not isinstance(parsed, Drop) and not self._partners.settled(stamp, self._wrong_type):
                due = now_ns is not None and now_ns - receive >= self._wait_ns
                if not (flush or due or len(self._held) > self._max_held):
                    break
                late = True
                self.stats.late += 1
            self._held.popleft()
            out.append(Decided(receive, stamp, self._decide(receive, stamp, on_time, parsed), late))
        return out

    def _parse_step(self, receive: int, raw: bytes | memoryview,
                    msgtype: str | None = None) -> tuple[int, int, list[np.ndarray] | Drop]:
        """``(stamp under the stamp rule, on-time reception, the step's vectors or its Drop)``; sets
        ``last_stamp_ns``.  The on-time reception is ``receive`` unless the stamp is the header's."""
        topic = self.spec.step_topic
        self.last_stamp_ns = receive
        if topic in self._wrong_type:
            return receive, receive, Drop("wrong_type", topic, receive, self._wrong_type[topic])
        try:
            header, vectors = self._step_ex.extract(raw, msgtype)
        except ExtractError as err:
            return receive, receive, Drop(err.reason, topic, receive, err.detail)
        if header is not None and self._header:
            self.last_stamp_ns = header
            return header, self._on_time.of(receive, header), vectors
        return receive, receive, vectors

    def _decide(
        self, receive: int, stamp: int, on_time: int, parsed: list[np.ndarray] | Drop
    ) -> np.ndarray | Drop:
        """The rule for one parsed step (``receive``: the caller's stamp, ``stamp``: under the stamp
        rule, ``on_time``: its on-time reception): the observation, or the counted drop."""
        if isinstance(parsed, Drop):
            return self._drop(parsed.reason, parsed.topic, stamp, parsed.detail)
        values = {self.spec.step_topic: parsed}
        for partner in self._partners.history:
            if partner in self._wrong_type:
                return self._drop("wrong_type", partner, stamp, self._wrong_type[partner])
            found = self._partners.latest(partner, stamp, receive, on_time)
            if isinstance(found, Drop):
                return self._drop(found.reason, found.topic, stamp, found.detail)
            values[partner] = found
        out = self._layout.fill(values)
        self.stats.kept += 1
        return out

    def _drop(self, reason: DropReason, topic: str, stamp: int, detail: str) -> Drop:
        self.stats.dropped[reason] = self.stats.dropped.get(reason, 0) + 1
        return Drop(reason, topic, stamp, detail)

    def _count_rejected(self, topic: str, reason: str) -> None:
        key = (topic, reason)
        self.stats.rejected[key] = self.stats.rejected.get(key, 0) + 1

    def reset(self, clear_stats: bool = False) -> list[Decided]:
        """Decide the held steps (``release(flush=True)``, returned), then forget the partner messages
        (and with ``clear_stats`` the counters).  The layout pinned by first messages and the
        wrong-type reports are kept."""
        flushed = self.release(flush=True)
        self._partners.clear()
        self._on_time.clear()
        self.last_stamp_ns = None
        if clear_stats:
            self.stats = AssemblerStats()
        return flushed
