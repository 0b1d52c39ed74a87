"""ObservationAssembler: the one rule that turns several topics into one observation per step.

The rule (``ompn_node`` applies it live, the bag reader offline through
:func:`ompn_ros.data.obs.stream.assemble_stream`, with this same class):

* Every message of ``spec.step_topic`` is a **step**: it gives one observation or one counted
  :class:`Drop`.  The observation is ``spec.fields`` concatenated in order (float32).
* Fields of the step topic come from the step message itself.  Fields of every other (*partner*)
  topic come from **the latest message of that topic stamped at or before the step**, among the
  messages offered before the step.  It must be at most ``spec.tolerance_s`` older than the step.
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
* Nothing waits: a partner message fed after its step is not used for that step (it serves later
  steps).  So the result depends only on the feeding order and the stamps, and a bag recorded from
  the same callbacks, with the receive time as log time, gives back exactly the live observations.

Complexity: a step costs O(D + Σ log h) (``h`` = kept history per partner topic, at most
``2 * history``); an offered partner message O(its size + log h) amortised.
"""

from __future__ import annotations

from bisect import bisect_right, insort
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .extract import ExtractError, TopicExtractor, extractors, layout_of
from .spec import ObservationSpec, canonical_type

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


@dataclass
class AssemblerStats:
    """Counters of an assembler (cumulative until ``reset(clear_stats=True)``).

    Attributes:
        steps: step messages fed; ``kept + sum(dropped.values()) == steps``.
        kept: steps that gave an observation.
        dropped: dropped steps by reason.
        rejected: rejected partner messages (and wrong-type reports) by ``(topic, reason)``.
        ignored: messages offered on topics the spec does not use.
    """

    steps: int = 0
    kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    rejected: dict[tuple[str, str], int] = field(default_factory=dict)
    ignored: int = 0

    def as_dict(self) -> dict[str, int]:
        """Flat counters for diagnostics: ``steps``, ``kept``, ``dropped.<reason>``,
        ``rejected.<topic>.<reason>``, ``ignored``."""
        out = {"steps": self.steps, "kept": self.kept, "ignored": self.ignored}
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


class ObservationAssembler:
    """Incremental observation assembly under the rule of this module (not thread-safe).

    Example::

        asm = ObservationAssembler(spec)
        asm.offer('/arm1/gripper', receive_ns, raw)         # partner topics
        obs = asm.step(receive_ns, raw)                      # step topic: np.ndarray or Drop

    Args:
        spec: the observation spec (topic names as they will be fed: resolve namespaces first).
        history: partner messages kept per topic (at least this many, at most twice).
    """

    def __init__(self, spec: ObservationSpec, history: int = 256) -> None:
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        self.spec = spec
        self._ex: dict[str, TopicExtractor] = extractors(spec)
        self._step_ex = self._ex[spec.step_topic]
        self._hist = {t: _History(history) for t in spec.partner_topics}
        self._tol_ns = round(spec.tolerance_s * 1e9)
        self._header = spec.stamp == "header"
        self._wrong_type: dict[str, str] = {}
        self._slots: list[tuple[str, int, slice]] | None = None
        self._dim: int | None = None
        self._names: tuple[str, ...] = ()
        self.stats = AssemblerStats()
        self.last_stamp_ns: int | None = None  # stamp (under the stamp rule) of the last step fed

    # --- layout -----------------------------------------------------------------------------------
    @property
    def dim(self) -> int | None:
        """Observation size, ``None`` until known (declared, or after the first kept step)."""
        if self._dim is None and all(s is not None for ex in self._ex.values() for s in ex.sizes):
            self._resolve()
        return self._dim

    def obs_names(self) -> tuple[str, ...]:
        """Element names (``<topic>/<field>/<label>``); raises ``ValueError`` while the size is unknown."""
        if self.dim is None:
            raise ValueError("the observation layout is not known until the first kept step")
        return self._names

    def _resolve(self) -> None:
        self._dim, self._names = layout_of(self.spec, self._ex)
        slots, start, k = [], 0, dict.fromkeys(self._ex, 0)
        for f in self.spec.fields:
            size = self._ex[f.topic].sizes[k[f.topic]]
            assert size is not None
            slots.append((f.topic, k[f.topic], slice(start, start + size)))
            k[f.topic] += 1
            start += size
        self._slots = slots

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

    def offer(self, topic: str, stamp_ns: int, raw: bytes | memoryview) -> Drop | None:
        """Feed a message of a partner topic; returns its rejection (counted) or ``None``.

        ``stamp_ns`` is the receive time (live) or the log time (offline).  Messages of topics the
        spec does not use are ignored (counted); a step-topic message must go to :meth:`step`.
        """
        hist = self._hist.get(topic)
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
            header, vectors = self._ex[topic].extract(raw)
        except ExtractError as err:
            rejection = Drop(err.reason, topic, int(stamp_ns), err.detail)
            hist.add(int(stamp_ns), rejection)
            self._count_rejected(topic, err.reason)
            return rejection
        hist.add(header if header is not None and self._header else int(stamp_ns), vectors)
        return None

    def step(self, stamp_ns: int, raw: bytes | memoryview) -> np.ndarray | Drop:
        """Feed a message of the step topic: its observation (float32 ``[dim]``, a new array) or the
        counted :class:`Drop`.  ``stamp_ns`` as in :meth:`offer`."""
        self.stats.steps += 1
        topic = self.spec.step_topic
        self.last_stamp_ns = stamp = int(stamp_ns)
        if topic in self._wrong_type:
            return self._drop("wrong_type", topic, stamp, self._wrong_type[topic])
        try:
            header, vectors = self._step_ex.extract(raw)
        except ExtractError as err:
            return self._drop(err.reason, topic, stamp, err.detail)
        if header is not None and self._header:
            self.last_stamp_ns = stamp = header
        values = {topic: vectors}
        for partner, hist in self._hist.items():
            found = self._partner(partner, hist, stamp)
            if isinstance(found, Drop):
                return self._drop(found.reason, found.topic, stamp, found.detail)
            values[partner] = found
        if self._slots is None:
            self._resolve()
        assert self._slots is not None and self._dim is not None
        out = np.empty(self._dim, dtype=np.float32)
        for name, k, where in self._slots:
            out[where] = values[name][k]
        self.stats.kept += 1
        return out

    def _partner(self, topic: str, hist: _History, stamp: int) -> list[np.ndarray] | Drop:
        if topic in self._wrong_type:
            return Drop("wrong_type", topic, stamp, self._wrong_type[topic])
        i = bisect_right(hist.stamps, stamp) - 1
        if i < 0:
            detail = ("no message yet" if not hist.stamps else "no message at or before the step "
                      f"(the oldest kept is {hist.stamps[0] - stamp} ns later)")
            return Drop("missing", topic, stamp, detail)
        entry = hist.entries[i]
        if isinstance(entry, Drop):
            return Drop(entry.reason, topic, stamp, f"its latest message was rejected: {entry.detail}")
        age = stamp - hist.stamps[i]
        if age > self._tol_ns:
            return Drop("stale", topic, stamp, f"its latest message is {age / 1e6:.3f} ms older than the "
                        f"step (tolerance {self.spec.tolerance_s * 1e3:g} ms)")
        return entry

    def _drop(self, reason: DropReason, topic: str, stamp: int, detail: str) -> Drop:
        self.stats.dropped[reason] = self.stats.dropped.get(reason, 0) + 1
        return Drop(reason, topic, stamp, detail)

    def _count_rejected(self, topic: str, reason: str) -> None:
        key = (topic, reason)
        self.stats.rejected[key] = self.stats.rejected.get(key, 0) + 1

    def reset(self, clear_stats: bool = False) -> None:
        """Forget the partner messages (and with ``clear_stats`` the counters).  The layout pinned by
        first messages and the wrong-type reports are kept."""
        for hist in self._hist.values():
            hist.clear()
        self.last_stamp_ns = None
        if clear_stats:
            self.stats = AssemblerStats()
