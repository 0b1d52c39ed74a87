"""Topics stamped on different clocks (``ReaderSpec.stamps``): found and refused in one line.

A robot's driver stamps its headers with the robot's clock; a label or command node may only have the
bag's receive time.  Aligned on such stamps, partners land on no observation (or on the wrong one).
The check runs once per bag before the partners are attached, for partners on another time base than
the observations (header and receive stamps): when more than half of the partner's messages would
attach to no observation and the two are offset by a constant larger than ``tolerance``, or when they
would attach but a measured constant offset spans :data:`SHIFT_STEPS` observation periods or more
(every label shifted by as many steps), the read stops with
:class:`~ompn_ros.data.errors.AlignmentError` naming both topics, their time bases and the offset.

The offset is measured where both clocks are in the bag (a header-stamped topic also has receive
stamps: the median of receive − header, a constant when its 5-95 % spread is within ``tolerance``,
or one observation period for the shift), else, for unattached partners, from the first and the last
stamps of both topics (the same difference at both ends, within two observation periods).  O(N) per
topic.
"""

from __future__ import annotations

import numpy as np

from ..errors import AlignmentError
from .context import BagContext

MOST = 0.5
"""Share of a partner's messages that must be unattached before the clocks are checked."""
SHIFT_STEPS = 2
"""A measured offset of at least this many observation periods is refused even when partners attach."""


def check_clocks(ctx: BagContext, obs_topic: str, obs_stamps: np.ndarray,
                 partners: list[tuple[str, np.ndarray]]) -> None:
    """Raise when a partner's stamps are on another clock than the observations' (module docstring)."""
    period = int(np.median(np.diff(obs_stamps))) if obs_stamps.size > 1 else 0
    for topic, stamps in partners:
        if topic == obs_topic or stamps.size == 0 or obs_stamps.size == 0:
            continue
        if ctx.clock(topic) == ctx.clock(obs_topic):  # one time base: a lag is a matter of tolerance
            continue
        problem = _problem(ctx, obs_topic, obs_stamps, topic, stamps, period)
        if problem is not None:
            what, offset = problem
            raise AlignmentError(
                f"{what}: their stamps ({ctx.clock(topic)}) and the observations' "
                f"({ctx.clock(obs_topic)}) are offset by a constant {offset / 1e9:+.3f} s, two clocks; give "
                f"both topics one time base in the reader spec's stamps (e.g. stamps: {{{obs_topic}: log, "
                f"{topic}: log}})",
                path=ctx.path, topic=topic)


def _problem(ctx: BagContext, obs_topic: str, obs_stamps: np.ndarray, topic: str, stamps: np.ndarray,
             period: int) -> tuple[str, int] | None:
    """What is wrong with ``topic``'s stamps against the observations', and the offset (ns)."""
    tol = round(ctx.spec.tolerance * 1e9)
    idx = np.searchsorted(obs_stamps, stamps, side="right") - 1
    ok = idx >= 0
    ok[ok] = (stamps[ok] - obs_stamps[idx[ok]]) <= tol
    lost = int((~ok).sum())
    if lost > MOST * stamps.size:
        offset = _measured(ctx, obs_topic, topic, tol)
        offset = _ends(obs_stamps, stamps, max(tol, 2 * period)) if offset is None else offset
        if offset is None or abs(offset) <= tol:
            return None
        return f"{lost} of {stamps.size} messages attach to no observation on '{obs_topic}'", offset
    offset = _measured(ctx, obs_topic, topic, period) if period > 0 else None
    if offset is None or abs(offset) < SHIFT_STEPS * period:
        return None
    steps = abs(offset) / period
    return f"messages would attach about {steps:.0f} steps off the observations on '{obs_topic}'", offset


def _measured(ctx: BagContext, obs_topic: str, topic: str, spread: int) -> int | None:
    """Partner − observation offset (ns) from receive − header of the header-stamped topic(s), when
    each is constant within ``spread``; ``None`` when not measurable."""
    lags = [_lag(ctx, t, spread) for t in (obs_topic, topic)]
    if lags[0] is None or lags[1] is None:
        return None
    return lags[0] - lags[1]


def _ends(obs_stamps: np.ndarray, stamps: np.ndarray, slack: int) -> int | None:
    """The offset of the first and the last stamps, when the same at both ends (within ``slack``)."""
    first, last = int(stamps[0] - obs_stamps[0]), int(stamps[-1] - obs_stamps[-1])
    return (first + last) // 2 if abs(first - last) <= slack else None


def _lag(ctx: BagContext, topic: str, spread: int) -> int | None:
    """Median receive − header stamp of ``topic`` (0 on the receive clock); ``None`` when not constant."""
    if ctx.clock(topic) != "header":
        return 0
    lag = ctx.header_lag.get(topic)
    if lag is None or lag.size == 0:
        return None
    low, mid, high = np.percentile(lag, [5, 50, 95])
    return int(mid) if high - low <= max(spread, 1) else None
