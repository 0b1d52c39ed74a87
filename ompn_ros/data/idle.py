"""Episodes split where the robot is still: the reader's ``split: idle`` and ``ompn_node``'s ``idle_s``.

Real drivers publish joint states continuously, also while the robot waits between demonstrations, so
a time gap never appears.  The rule here cuts such a stream instead, one step at a time, so the bag
reader and the live node cut in the same places (``ReaderSpec.split``):

* a step is **still** when the caller says so: its observation changed by less than ``idle_speed``
  per second since the previous step (:func:`still_by_speed`, the largest element change divided by
  the time between the two stamps; the first step of a stream counts as still), or, in the reader,
  when it has no command attached;
* still steps inside an episode are held; when the robot moves again before ``idle_s`` passed they
  are steps of the episode (a short pause, e.g. while the gripper closes);
* once the held still steps span ``idle_s`` (or two steps lie more than ``idle_s`` apart) the episode
  ends: its final observation (row ``T``) is the first still step, the state after the last motion;
  the other still steps are trimmed, never steps;
* outside an episode still steps are trimmed; the next moving step starts an episode.

At the end of a stream the open episode ends the same way (at its first held still step, else at its
last step).  :class:`IdleSplitter` is the rule for one step; :func:`idle_windows` runs it over a whole
array of stamps.  Both are O(1) per step (amortised) and ROS-free.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Kind = Literal["start", "step", "end"]


@dataclass(frozen=True)
class Cut:
    """What happens to step ``row`` (the 0-based count of pushed steps): it ``start``\\ s an episode (and
    is its first step), is a ``step`` of the open one, or is the final observation that ``end``\\ s it."""

    kind: Kind
    row: int


@dataclass
class IdleSplitter:
    """The idle rule for a stream of steps (see the module docstring).

    Args:
        idle_ns: how long the robot must be still (ns, > 0) before the episode ends.
    """

    idle_ns: int
    open: bool = False
    trimmed: int = 0  # still steps that belong to no episode
    _row: int = -1
    _last_stamp: int | None = None
    _last_step: int = -1
    _held: list[tuple[int, int]] = field(default_factory=list)  # (row, stamp) of still steps

    def __post_init__(self) -> None:
        if self.idle_ns <= 0:
            raise ValueError(f"the idle rule needs idle_s > 0, got {self.idle_ns} ns")

    def push(self, stamp_ns: int, still: bool) -> list[Cut]:
        """The decisions this step makes possible, in order (an empty list: held or trimmed)."""
        self._row += 1
        row, out = self._row, []
        if self.open and self._last_stamp is not None and stamp_ns - self._last_stamp > self.idle_ns:
            out.extend(self.finish())  # silence longer than idle_s: the episode ended before this step
        self._last_stamp = stamp_ns
        if not self.open:
            if still:
                self.trimmed += 1
                return out
            self.open, self._last_step = True, row
            out.append(Cut("start", row))
            return out
        if still:
            self._held.append((row, stamp_ns))
            if stamp_ns - self._held[0][1] >= self.idle_ns:
                out.extend(self.finish())
            return out
        out.extend(Cut("step", r) for r, _ in self._held)
        self._held.clear()
        self._last_step = row
        out.append(Cut("step", row))
        return out

    @property
    def rows(self) -> int:
        """Steps pushed so far."""
        return self._row + 1

    @property
    def held(self) -> int:
        """How many still steps are held, not yet decided (O(1))."""
        return len(self._held)

    @property
    def held_rows(self) -> set[int]:
        """Rows of the still steps held, not yet decided (O(held): for inspection, not per step)."""
        return {r for r, _ in self._held}

    def finish(self) -> list[Cut]:
        """End the open episode now (end of stream, or silence): at its first held still step, else at
        its last step.  Nothing when no episode is open."""
        if not self.open:
            return []
        final = self._held[0][0] if self._held else self._last_step
        self.trimmed += max(0, len(self._held) - 1)
        self._held.clear()
        self.open = False
        return [Cut("end", final)]


def still_by_speed(stamps_ns: np.ndarray, values: np.ndarray, idle_speed: float) -> np.ndarray:
    """Per step, whether the observation changed by less than ``idle_speed`` per second since the
    previous one (largest element change / time between the stamps; the first step is still)."""
    n = len(stamps_ns)
    still = np.ones(n, dtype=bool)
    if n < 2:
        return still
    dt = np.maximum(np.diff(stamps_ns).astype(np.float64), 1.0) / 1e9
    change = np.abs(np.diff(np.asarray(values, dtype=np.float64), axis=0))
    still[1:] = change.max(axis=1, initial=0.0) < idle_speed * dt
    return still


def step_still(prev: np.ndarray | None, prev_ns: int | None, obs: np.ndarray, stamp_ns: int,
               idle_speed: float) -> bool:
    """:func:`still_by_speed` for one step (``prev`` = the previous observation, ``None`` at the start)."""
    if prev is None or prev_ns is None or prev.shape != obs.shape:
        return True
    dt = max(stamp_ns - prev_ns, 1) / 1e9
    change = np.abs(np.asarray(obs, dtype=np.float64) - np.asarray(prev, dtype=np.float64))
    return bool(change.max(initial=0.0) < idle_speed * dt)


def idle_windows(stamps_ns: np.ndarray, still: np.ndarray,
                 idle_s: float) -> tuple[list[tuple[int, int]], int]:
    """The episodes of a whole stream as ``(first_row, stop_row)`` (stop exclusive; ``stop_row - 1`` is
    the final observation) and the number of trimmed still steps: :class:`IdleSplitter` over every
    step, then :meth:`IdleSplitter.finish`."""
    splitter = IdleSplitter(round(idle_s * 1e9))
    windows: list[tuple[int, int]] = []
    first = -1
    for i in range(len(stamps_ns)):
        for cut in splitter.push(int(stamps_ns[i]), bool(still[i])):
            first = _apply(cut, first, windows)
    for cut in splitter.finish():
        first = _apply(cut, first, windows)
    return windows, splitter.trimmed


def _apply(cut: Cut, first: int, windows: list[tuple[int, int]]) -> int:
    if cut.kind == "start":
        return cut.row
    if cut.kind == "end":
        windows.append((first, cut.row + 1))
        return -1
    return first


__all__ = ["Cut", "IdleSplitter", "idle_windows", "step_still", "still_by_speed"]
