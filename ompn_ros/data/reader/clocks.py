"""Topics stamped on different clocks (``ReaderSpec.stamps``): found and refused in one line.

A robot's driver stamps its headers with the robot's clock; a label or command node may only have the
bag's receive time.  Aligned on such stamps, partners land on no observation (or on the wrong one).
The check runs once per bag before the partners are attached: when more than half of a partner topic's
messages would attach to no observation, and the partner's stamps and the observations' are on two
time bases (header and receive) offset by a constant larger than ``tolerance``, the read stops with
:class:`~ompn_ros.data.errors.AlignmentError` naming both topics, their time bases and the offset.

The offset is measured where both clocks are in the bag (a header-stamped topic also has receive
stamps: the median of receive − header, a constant when its spread is within ``tolerance``), else
from the first and the last stamps of both topics (the same difference at both ends, within two
observation periods).  O(N) per topic.
"""

from __future__ import annotations

import numpy as np

from ..errors import AlignmentError
from .context import BagContext

MOST = 0.5
"""Share of a partner's messages that must be unattached before the clocks are checked."""


def check_clocks(ctx: BagContext, obs_topic: str, obs_stamps: np.ndarray,
                 partners: list[tuple[str, np.ndarray]]) -> None:
    """Raise when a partner's stamps are on another clock than the observations' (module docstring)."""
    tol = round(ctx.spec.tolerance * 1e9)
    for topic, stamps in partners:
        if topic == obs_topic or stamps.size == 0 or obs_stamps.size == 0:
            continue
        idx = np.searchsorted(obs_stamps, stamps, side="right") - 1
        ok = idx >= 0
        ok[ok] = (stamps[ok] - obs_stamps[idx[ok]]) <= tol
        lost = int((~ok).sum())
        if lost <= MOST * stamps.size:
            continue
        offset = _offset(ctx, obs_topic, obs_stamps, topic, stamps, tol)
        if offset is None:
            continue
        raise AlignmentError(
            f"{lost} of {stamps.size} messages attach to no observation on '{obs_topic}': their stamps "
            f"({ctx.clock(topic)}) and the observations' ({ctx.clock(obs_topic)}) are offset by a constant "
            f"{offset / 1e9:+.3f} s, two clocks; give both topics one time base in the reader spec's "
            f"stamps (e.g. stamps: {{{obs_topic}: log, {topic}: log}})", path=ctx.path, topic=topic)


def _offset(ctx: BagContext, obs_topic: str, obs_stamps: np.ndarray, topic: str, stamps: np.ndarray,
            tol: int) -> int | None:
    """The constant offset (partner − observation, ns) between two time bases, when larger than ``tol``
    (``None`` for topics on one time base: a lag there is a matter of ``tolerance``)."""
    if ctx.clock(topic) == ctx.clock(obs_topic):
        return None
    lags = [_lag(ctx, t, tol) for t in (obs_topic, topic)]
    if all(lag is not None for lag in lags):  # receive − header of the header-stamped one(s)
        obs_lag, lag = (lag or 0 for lag in lags)
        offset = obs_lag - lag
        return offset if abs(offset) > tol else None
    first, last = int(stamps[0] - obs_stamps[0]), int(stamps[-1] - obs_stamps[-1])
    period = int(np.median(np.diff(obs_stamps))) if obs_stamps.size > 1 else 0
    if abs(first - last) <= max(tol, 2 * period) and abs(first) > tol and abs(last) > tol:
        return (first + last) // 2
    return None


def _lag(ctx: BagContext, topic: str, tol: int) -> int | None:
    """Median receive − header stamp of ``topic`` (0 on the receive clock); ``None`` when not constant."""
    if ctx.clock(topic) != "header":
        return 0
    lag = ctx.header_lag.get(topic)
    if lag is None or lag.size == 0:
        return None
    low, mid, high = np.percentile(lag, [5, 50, 95])
    return int(mid) if high - low <= max(tol, 1) else None
