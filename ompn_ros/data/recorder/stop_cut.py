"""Where a live recording ends when it is stopped: at a step boundary, the same one on every topic.

A recorder stopped by SIGINT/SIGTERM keeps taking what DDS delivers (the *drain*) and decides per
message, by its publisher source timestamp ``src``:

* ``src`` before the signal: written (everything published before the stop is kept);
* ``src`` at or after the signal: the first message of the *step topic* (the observation, which
  opens a step in the step contract of ``ompn_ros.layout``) published after the signal fixes the
  **cut**; messages before the cut complete the step that was under way and are written, messages
  from the cut on are dropped.  Until the cut is known they are held back.

Every topic therefore ends at the same step: a reader never sees an observation without the
subtask/action published after it, nor a partner without its observation.  Without a step topic
(``step_topic=None``) the cut is the signal itself.  If the drain ends before any step-topic message
after the signal arrives (the publisher stopped), :meth:`StopCut.finish` releases the held messages:
they are the rest of the last step.

Costs O(1) per message, O(held) once when the cut is found.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass
class StopCut(Generic[T]):
    """Per-message write/hold/drop decisions after a stop request (module docstring).

    ``T`` is whatever the caller needs to write the message later (e.g. ``(topic, stamp, raw)``).
    """

    step_topic: str | None
    signal_ns: int | None = None
    cut_ns: int | None = None
    dropped: int = 0  # messages from the cut on (not recorded)
    passed: set[str] = field(default_factory=set)  # topics that delivered a message at/after the cut
    _held: list[tuple[int, str, T]] = field(default_factory=list)

    @property
    def stopping(self) -> bool:
        return self.signal_ns is not None

    @property
    def held(self) -> int:
        return len(self._held)

    def request(self, signal_ns: int) -> None:
        """Stop requested at ``signal_ns`` (same clock as the source timestamps); first call wins."""
        if self.signal_ns is None:
            self.signal_ns = int(signal_ns)
            if self.step_topic is None:
                self.cut_ns = self.signal_ns

    def offer(self, topic: str, src_ns: int, item: T) -> list[T]:
        """The items to write now (possibly none, possibly earlier held ones) after this message."""
        if self.signal_ns is None or src_ns < self.signal_ns:
            return [item]
        if self.cut_ns is None:
            if topic != self.step_topic:
                self._held.append((src_ns, topic, item))
                return []
            self.cut_ns = src_ns
            release = [it for stamp, _, it in self._held if stamp < src_ns]
            self.passed.update(name for stamp, name, _ in self._held if stamp >= src_ns)
            self.dropped += len(self._held) - len(release)
            self._held.clear()
            self.passed.add(topic)
            self.dropped += 1
            return release
        if src_ns < self.cut_ns:
            return [item]
        self.passed.add(topic)
        self.dropped += 1
        return []

    def finish(self) -> list[T]:
        """Drain over: the held messages (no step opened after the signal, so they end the last one)."""
        release = [it for _, _, it in self._held]
        self._held.clear()
        return release


__all__ = ["StopCut"]
