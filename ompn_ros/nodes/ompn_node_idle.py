"""``ompn_node``'s ``idle_speed: auto``: the threshold of the idle rule without a bag to measure it on.

The reader derives ``idle_speed: auto`` from the whole bag's noise floor
(:func:`ompn_ros.data.cuts.idle.derive_idle_speed`).  Live there is no bag, so the node takes, in order:

1. the threshold its checkpoint was trained with: ``ompn_train`` records the one its read used (derived
   or given, the median over the bags) beside the checkpoint (:mod:`ompn_ros.app.idle_record`), when
   that read judged the same speed as the node does (a JointState's joint speed, else every element's
   change per second);
2. else the stream's own noise floor: the first :data:`PROBE_S` seconds of observations (at most
   :data:`PROBE_ROWS`) are held, the threshold is derived from them as the reader derives it from a bag,
   and then they go through the idle rule with it, in order, as if it had been known from the start
   (an episode marker, a sketch message or ``~/reset`` ends the probe early, on what it holds;
   deactivation drops what it holds, as held input is never stepped while inactive).

Either way the node logs one line naming the value and where it came from (docs/design.md#idle-speed-live).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np

from ompn_ros.app.idle_record import trained_idle_speed
from ompn_ros.data.cuts import IdleSpeed, SpeedElements, derive_idle_speed

AUTO: Final = "auto"
PROBE_S: Final = 10.0
"""Seconds of stream (by the observations' stamps) that ``idle_speed: auto`` measures without a record."""
PROBE_ROWS: Final = 5_000
"""The most observations the probe holds (a fast stream fills it before :data:`PROBE_S`)."""


def idle_speed_rule(value: Any) -> str | None:
    """``ParamSpec`` check of ``idle_speed``: ``auto`` or a number >= 0."""
    if value == AUTO:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        return f"{value!r} is not 'auto' or a number >= 0 (the speed below which a step is still)"
    return None


def chosen_idle_speed(values: Mapping[str, Any], checkpoint: str | Path,
                      elements: SpeedElements) -> tuple[float | None, str]:
    """The idle rule's threshold at configure and the line to log: a number as given, the checkpoint's
    record for ``auto`` (``None``: measure the stream, :class:`IdleProbe`).  ``('', ...)`` lines are not
    logged: no idle rule (``idle_s`` 0) or a number given."""
    value = values["idle_speed"]
    if value != AUTO:
        return float(value), ""
    if float(values["idle_s"]) <= 0:
        return None, ""
    record = trained_idle_speed(checkpoint)
    if record is None:
        why = "the checkpoint has no idle speed from its training read"
    elif record.on != elements.describe():
        why = f"the checkpoint's training read measured it on {record.on}, this node on {elements.describe()}"
    else:
        return record.speed, (f"idle_speed auto -> {record.speed:.4g} from the checkpoint's training read "
                              f"({record.source})")
    return None, (f"idle_speed auto: {why}; deriving it from the first {PROBE_S:g} s of the stream "
                  "(held until then); set idle_speed to a number to skip this")


class IdleProbe:
    """The observations of the first :data:`PROBE_S` seconds, held until the threshold is derived."""

    def __init__(self, elements: SpeedElements) -> None:
        self.elements = elements
        self.held: list[tuple[Any, int, int | None]] = []  # (observation, stamp, receive clock)
        self._first_ns: int | None = None

    def hold(self, data: Any, stamp_ns: int, now_ns: int | None) -> bool:
        """Hold one observation; whether the probe has enough now."""
        self.held.append((np.array(data, dtype=np.float32), stamp_ns, now_ns))
        if self._first_ns is None:
            self._first_ns = stamp_ns
        return stamp_ns - self._first_ns >= PROBE_S * 1e9 or len(self.held) >= PROBE_ROWS

    def derive(self) -> IdleSpeed:
        """The threshold of the held observations (:func:`ompn_ros.data.cuts.idle.derive_idle_speed`; too few
        of one size: still only when nothing changes)."""
        size = self.held[-1][0].size if self.held else 0
        kept = [(row, stamp) for row, stamp, _ in self.held if row.size == size]  # a wrong size is rejected
        stamps = np.array([stamp for _, stamp in kept], dtype=np.int64)
        values = np.stack([row for row, _ in kept]).astype(np.float64) if kept else np.zeros((0, 0))
        return derive_idle_speed(stamps, values, self.elements)
