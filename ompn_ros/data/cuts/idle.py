"""Episodes split where the robot is idle: the reader's ``split: idle`` and ``ompn_node``'s ``idle_s``.

Real drivers publish joint states continuously, also while the robot waits between demonstrations, so
a time gap never appears.  The rule here cuts such a stream instead, one step at a time, so the bag
reader and the live node cut in the same places (``ReaderSpec.split``).  "Idle" is this rule's word
for a step that does not move (the package's words: :mod:`ompn_ros.data.cuts`):

* a step is **idle** when the caller says so: its speed is below ``idle_speed`` (:func:`idle_by_speed`;
  the first step of a stream counts as idle), or, in the reader, when it has no command attached;
* the **speed** of a step (:class:`SpeedElements`) is the joint speed in the observation's own units
  per second (rad/s for joint positions): for an observation made of JointState fields, the largest
  change of a joint *position* per second since the previous step and the largest measured joint
  *velocity* (read as a speed, never differentiated: a velocity's change per second is an
  acceleration), efforts ignored; for any other observation, the largest change of any element per
  second.  ``idle_speed: auto`` (the reader's default) derives the threshold from the stream's own
  noise floor (:func:`derive_idle_speed`, on the noise estimate the still rule's ``auto`` uses,
  :func:`.still.element_noise`);
* idle steps inside an episode are held; when the robot moves again before ``idle_s`` passed they
  are steps of the episode (a short pause, e.g. while the gripper closes);
* once the held idle steps span ``idle_s`` (or two steps lie more than ``idle_s`` apart) the episode
  ends: its final observation (row ``T``) is the first idle step, the state after the last motion;
  the other idle steps are trimmed, never steps;
* outside an episode idle steps are trimmed; the next moving step starts an episode.

At the end of a stream the open episode ends the same way (at its first held idle step, else at its
last step).  :class:`IdleSplitter` is the rule for one step; :func:`idle_windows` runs it over a whole
array of stamps (the reader); :class:`IdleGate` runs it over observations as they come, holding the
idle ones until the rule decides them (the stream rule).  All are O(1) per step (amortised), ROS-free.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .still import element_noise, noise_margin

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
        idle_ns: how long the robot must be idle (ns, > 0) before the episode ends.
    """

    idle_ns: int
    open: bool = False
    trimmed: int = 0  # idle steps that belong to no episode
    _row: int = -1
    _last_stamp: int | None = None
    _last_step: int = -1
    _held: list[tuple[int, int]] = field(default_factory=list)  # (row, stamp) of idle steps

    def __post_init__(self) -> None:
        if self.idle_ns <= 0:
            raise ValueError(f"the idle rule needs idle_s > 0, got {self.idle_ns} ns")

    def push(self, stamp_ns: int, idle: bool) -> list[Cut]:
        """The decisions this step makes possible, in order (an empty list: held or trimmed)."""
        self._row += 1
        row, out = self._row, []
        if self.open and self._last_stamp is not None and stamp_ns - self._last_stamp > self.idle_ns:
            out.extend(self.finish())  # silence longer than idle_s: the episode ended before this step
        self._last_stamp = stamp_ns
        if not self.open:
            if idle:
                self.trimmed += 1
                return out
            self.open, self._last_step = True, row
            out.append(Cut("start", row))
            return out
        if idle:
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
        """How many idle steps are held, not yet decided (O(1))."""
        return len(self._held)

    @property
    def held_rows(self) -> set[int]:
        """Rows of the idle steps held, not yet decided (O(held): for inspection, not per step)."""
        return {r for r, _ in self._held}

    def finish(self) -> list[Cut]:
        """End the open episode now (end of stream, or silence): at its first held idle step, else at
        its last step.  Nothing when no episode is open."""
        if not self.open:
            return []
        final = self._held[0][0] if self._held else self._last_step
        self.trimmed += max(0, len(self._held) - 1)
        self._held.clear()
        self.open = False
        return [Cut("end", final)]


EXACT_SPEED = 1e-9
"""``idle_speed: auto`` on a stream without noise floor: idle only when nothing changes at all."""


@dataclass(frozen=True)
class SpeedElements:
    """Which observation elements give a step's speed (module docstring).

    ``fields``: the JointState fields the observation concatenates, in order (each one value per joint);
    ``None``: any other observation, every element differentiated.  Positions are differentiated,
    velocities read as speeds, efforts ignored; fields without a position or velocity fall back to
    every element."""

    fields: tuple[str, ...] | None = None

    def split(self, width: int) -> tuple[np.ndarray | None, np.ndarray]:
        """``(differentiated elements, None = all; velocity elements)`` of a ``width``-element observation."""
        fields = self.fields
        if not fields or width % len(fields) or not {"position", "velocity"} & set(fields):
            return None, np.zeros(0, dtype=np.int64)
        joints = width // len(fields)
        block = {name: np.arange(k * joints, (k + 1) * joints) for k, name in enumerate(fields)}
        empty = np.zeros(0, dtype=np.int64)
        return block.get("position", empty), block.get("velocity", empty)

    def describe(self) -> str:
        if not self.fields or not {"position", "velocity"} & set(self.fields):
            return "every observation element, per second"
        return " and ".join(n for n in ("position", "velocity") if n in self.fields).join(
            ("joint ", " (rad/s for revolute joints)"))


ALL_ELEMENTS = SpeedElements()


def speeds(stamps_ns: np.ndarray, values: np.ndarray, elements: SpeedElements = ALL_ELEMENTS) -> np.ndarray:
    """Per step, its speed (module docstring); the first step's is 0 (a stream's first step is idle)."""
    values = np.asarray(values, dtype=np.float64)
    n = len(stamps_ns)
    out = np.zeros(n)
    if n == 0:
        return out
    moved, velocity = elements.split(values.shape[1] if values.ndim == 2 else 1)
    if n > 1:
        dt = np.maximum(np.diff(stamps_ns).astype(np.float64), 1.0) / 1e9
        diffs = np.abs(np.diff(values if moved is None else values[:, moved], axis=0))
        out[1:] = diffs.max(axis=1, initial=0.0) / dt
    if velocity.size:
        out[1:] = np.maximum(out[1:], np.abs(values[1:, velocity]).max(axis=1))
    return out


def idle_by_speed(stamps_ns: np.ndarray, values: np.ndarray, idle_speed: float,
                  elements: SpeedElements = ALL_ELEMENTS) -> np.ndarray:
    """Per step, whether its speed (:func:`speeds`) is below ``idle_speed`` (the first step is idle)."""
    idle = speeds(stamps_ns, values, elements) < idle_speed
    if len(idle):
        idle[0] = True
    return idle


def step_idle(prev: np.ndarray | None, prev_ns: int | None, obs: np.ndarray, stamp_ns: int,
              idle_speed: float, elements: SpeedElements = ALL_ELEMENTS) -> bool:
    """:func:`idle_by_speed` for one step (``prev`` = the previous observation, ``None`` at the start)."""
    if prev is None or prev_ns is None or prev.shape != obs.shape:
        return True
    pair = np.stack([np.asarray(prev, dtype=np.float64).ravel(), np.asarray(obs, dtype=np.float64).ravel()])
    return bool(speeds(np.array([prev_ns, stamp_ns]), pair, elements)[1] < idle_speed)


@dataclass(frozen=True)
class IdleSpeed:
    """What ``idle_speed: auto`` derived: the threshold, the two noise floors it rests on (of a position's
    change per second, of a velocity reading) and the read summary's words."""

    speed: float
    position_noise: float
    velocity_noise: float
    text: str


def derive_idle_speed(stamps_ns: np.ndarray, values: np.ndarray,
                      elements: SpeedElements = ALL_ELEMENTS) -> IdleSpeed:
    """``idle_speed: auto``: the stream's own noise floor (:func:`.still.element_noise`, the
    median over the speed's elements: a held joint's position change per second, a held joint's velocity
    reading) times :func:`.still.noise_margin` of their count, so the largest speed of a
    held robot stays below it; :data:`EXACT_SPEED` for a noise-free stream.  Labels are never read."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or len(values) < 3:
        return IdleSpeed(EXACT_SPEED, 0.0, 0.0, f"idle_speed auto -> {EXACT_SPEED:g}: too few steps")
    moved, velocity = elements.split(values.shape[1])
    dt = float(np.median(np.maximum(np.diff(stamps_ns).astype(np.float64), 1.0))) / 1e9
    pos = element_noise(values if moved is None else values[:, moved])
    vel = element_noise(values[:, velocity]) / np.sqrt(2.0) if velocity.size else np.zeros(0)
    pos_floor = float(np.median(pos)) / dt if pos.size else 0.0
    vel_floor = float(np.median(vel)) if vel.size else 0.0
    count = (values.shape[1] if moved is None else moved.size) + velocity.size
    speed = max(pos_floor, vel_floor) * noise_margin(count)
    where = elements.describe()
    if not speed > 0:
        return IdleSpeed(EXACT_SPEED, 0.0, 0.0, f"idle_speed auto -> {EXACT_SPEED:g} on {where}: no noise "
                         "floor, idle only when nothing changes")
    return IdleSpeed(speed, pos_floor, vel_floor, f"idle_speed auto -> {speed:.4g} on {where} (noise floor "
                     f"{pos_floor:.3g} per second of position change, {vel_floor:.3g} of velocity reading)")


def idle_windows(stamps_ns: np.ndarray, idle: np.ndarray,
                 idle_s: float) -> tuple[list[tuple[int, int]], int]:
    """The episodes of a whole stream as ``(first_row, stop_row)`` (stop exclusive; ``stop_row - 1`` is
    the final observation) and the number of trimmed idle steps: :class:`IdleSplitter` over every
    step, then :meth:`IdleSplitter.finish`."""
    splitter = IdleSplitter(round(idle_s * 1e9))
    windows: list[tuple[int, int]] = []
    first = -1
    for i in range(len(stamps_ns)):
        for cut in splitter.push(int(stamps_ns[i]), bool(idle[i])):
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


class IdleGate:
    """``idle_s``: the reader's ``split: idle`` rule (:class:`IdleSplitter`) over the node's
    observations, idle by :func:`step_idle` on ``elements`` (the node sees no commands, so only
    ``idle_speed`` makes a step idle).  Idle observations are held until the rule
    decides them: :meth:`push` returns ``(kind, observation, stamp)`` in order, ``kind`` ``start``
    (reset, then step it), ``step`` (step it) or ``end`` (step it when given, then close the episode;
    ``None``: the last stepped observation is the final one).  After an ``end`` that :meth:`push` gave,
    :attr:`decided` is ``(observations from the final one to the one that decided, its stamp)``: the
    rule waits ``idle_s`` before it can end an episode.  O(1) per step, amortised."""

    def __init__(self, idle_ns: int, idle_speed: float, elements: SpeedElements = ALL_ELEMENTS) -> None:
        self.idle_speed = float(idle_speed)
        self.elements = elements
        self.splitter = IdleSplitter(idle_ns)
        self.decided: tuple[int, int] | None = None
        self._prev: tuple[np.ndarray, int] | None = None
        self._pending: dict[int, tuple[np.ndarray, int]] = {}

    def push(self, obs: np.ndarray, stamp_ns: int) -> list[tuple[str, np.ndarray | None, int]]:
        prev_obs, prev_ns = self._prev if self._prev is not None else (None, None)
        idle = step_idle(prev_obs, prev_ns, obs, stamp_ns, self.idle_speed, self.elements)
        self._prev = (obs, stamp_ns)
        cuts = self.splitter.push(stamp_ns, idle)
        row = self.splitter.rows - 1
        self._pending[row] = (obs, stamp_ns)
        out: list[tuple[str, np.ndarray | None, int]] = []
        for cut in cuts:
            x, s = self._pending.pop(cut.row, (None, stamp_ns))
            out.append((cut.kind, x, s))
            if cut.kind == "end":
                self.decided = (row - cut.row, stamp_ns)
        # Every held row is pending, and a row stops being held only in a push that decides it (a cut,
        # popped above) or ends the episode (nothing held after it): so the pending rows are the held
        # ones once the undecided rest is dropped, which happens only when nothing is held (O(1)
        # amortised, whatever the pause's length; rebuilding the held set here made each idle step
        # cost O(held)).
        if self.splitter.held == 0:
            self._pending.clear()
        return out

    def flush(self) -> list[tuple[str, np.ndarray | None, int]]:
        """An episode marker or ``~/reset``: the stream the rule sees ends here, as a bag ends for the
        reader.  The open episode ends at its first held idle observation (returned as ``end``), the
        other held ones are trimmed, and the next observation is judged afresh."""
        last_ns = self._prev[1] if self._prev is not None else 0
        out: list[tuple[str, np.ndarray | None, int]] = []
        self.decided = None
        for cut in self.splitter.finish():
            x, s = self._pending.get(cut.row, (None, last_ns))
            out.append((cut.kind, x, s))
        self._prev, self._pending = None, {}
        return out

    @property
    def trimmed(self) -> int:
        return self.splitter.trimmed

    def reset(self) -> None:
        """Forget the held observations and the open episode (the episode was ended otherwise)."""
        trimmed = self.splitter.trimmed + len(self._pending)
        self.splitter = IdleSplitter(self.splitter.idle_ns, trimmed=trimmed)
        self._prev, self._pending, self.decided = None, {}, None


__all__ = ["ALL_ELEMENTS", "EXACT_SPEED", "Cut", "IdleGate", "IdleSpeed", "IdleSplitter", "SpeedElements",
           "derive_idle_speed", "idle_by_speed", "idle_windows", "speeds", "step_idle"]
