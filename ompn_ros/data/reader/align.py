"""Alignment of per-step topics to the observation clock, and episode windows.

Rule: a message attaches to the latest observation stamped at or before it, if at most
``tolerance`` seconds later; nothing is ever shifted to a neighbouring step.  Cost: one
``searchsorted`` per topic, O(M log N) for M messages and N observations.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ompn_ros import layout

from ..cuts import REPEAT_NS, gap_windows, idle_windows
from ..errors import AlignmentError
from .context import BagContext
from .decode import Marker


def attach(ctx: BagContext, topic: str, obs_stamps: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """Per observation, the index of its first partner message on ``topic`` (-1 = none).

    Unattached messages and duplicate partners are counted in the report; with ``strict`` a
    duplicate raises :class:`AlignmentError` naming the second partner and ``strict: false``.  A
    message sent twice never gets here (:mod:`.repeats` dropped it while reading).
    """
    n_obs = len(obs_stamps)
    tol = round(ctx.spec.tolerance * 1e9)
    idx = np.searchsorted(obs_stamps, stamps, side="right") - 1
    ok = idx >= 0
    ok[ok] = (stamps[ok] - obs_stamps[idx[ok]]) <= tol
    ctx.report.count(ctx.report.unattached, topic, int((~ok).sum()))
    msg_ids = np.flatnonzero(ok)
    count = np.bincount(idx[ok], minlength=n_obs)
    first = np.full(n_obs, -1, dtype=np.int64)
    uniq, pos = np.unique(idx[ok], return_index=True)
    first[uniq] = msg_ids[pos]
    dup_steps = np.flatnonzero(count > 1)
    if dup_steps.size:
        ctx.report.count(ctx.report.duplicates, topic, int((count[dup_steps] - 1).sum()))
        if ctx.spec.strict:
            second = msg_ids[np.flatnonzero(idx[ok] == dup_steps[0])[1]]
            raise AlignmentError(f"second partner for observation #{dup_steps[0]} (not a repeat of the "
                                 f"first: it differs, or came over {REPEAT_NS / 1e6:g} ms later); to keep "
                                 "the first partner and count the others, read with 'strict: false' in the "
                                 "reader spec",
                                 path=ctx.path, topic=topic, index=int(second),
                                 stamp=int(stamps[second]))
    return first


def attach_events(ctx: BagContext, topic: str, obs_stamps: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """Per observation, whether an event message attaches to it (same rule; repeats count once)."""
    tol = round(ctx.spec.tolerance * 1e9)
    idx = np.searchsorted(obs_stamps, stamps, side="right") - 1
    ok = idx >= 0
    ok[ok] = (stamps[ok] - obs_stamps[idx[ok]]) <= tol
    ctx.report.count(ctx.report.unattached, topic, int((~ok).sum()))
    flags = np.zeros(len(obs_stamps), dtype=bool)
    flags[idx[ok]] = True
    return flags


@dataclass
class Window:
    """Observations ``first_obs .. stop_obs - 1`` of one episode, with its markers' key/values."""

    first_obs: int
    stop_obs: int  # exclusive
    start_stamp: int | None = None
    start: dict[str, str] = field(default_factory=dict)
    end: dict[str, str] = field(default_factory=dict)
    end_index: int = -1


def windows_from_markers(ctx: BagContext, markers: list[Marker], obs_stamps: np.ndarray) -> list[Window]:
    """Start/end marker pairs; unfinished episodes and stray end markers are reported, not used."""
    windows: list[Window] = []
    open_start: tuple[int, dict[str, str]] | None = None
    for stamp, kind, values, i in markers:
        if kind == layout.EPISODE_START:
            if open_start is not None:
                ctx.report.drop_episode("no end marker",
                                        f"episode started at {open_start[0]} ns has no end marker")
            open_start = (stamp, values)
        elif kind == layout.EPISODE_END:
            if open_start is None:
                ctx.report.notes.append(f"end marker #{i} without a start marker (recording began "
                                        "mid-episode); its observations are not used")
                continue
            a = int(np.searchsorted(obs_stamps, open_start[0], side="left"))
            b = int(np.searchsorted(obs_stamps, stamp, side="right"))
            windows.append(Window(a, b, open_start[0], open_start[1], values, i))
            open_start = None
    if open_start is not None:
        ctx.report.drop_episode("no end marker", f"last episode (started at {open_start[0]} ns) has no "
                                "end marker (recording stopped or corrupt tail); dropped")
    return windows


def windows_from_gaps(gap_s: float, obs_stamps: np.ndarray) -> list[Window]:
    """``split: gaps`` (:func:`ompn_ros.data.cuts.gap_windows`): split where consecutive observations are
    more than ``gap_s`` seconds apart."""
    return [Window(a, b) for a, b in gap_windows(obs_stamps, round(gap_s * 1e9))]


def windows_from_topic(split_stamps: np.ndarray, obs_stamps: np.ndarray,
                       switch: np.ndarray | None = None) -> list[Window]:
    """Every split-topic message starts an episode at the first observation stamped at or after it;
    observations before the first message are not used.  With ``switch`` (a recording on/off topic:
    per message, True = on) an 'on' starts an episode and an 'off' ends the open one at the last
    observation stamped before it; observations while off are not used."""
    if switch is None:
        starts = np.unique(np.searchsorted(obs_stamps, np.sort(split_stamps), side="left"))
        bounds = np.concatenate([starts, [obs_stamps.size]])
        return [Window(int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]
    windows: list[Window] = []
    first: int | None = None
    for stamp, on in zip(split_stamps.tolist(), switch.tolist(), strict=True):
        row = int(np.searchsorted(obs_stamps, stamp, side="left"))
        if first is not None:  # an 'off' ends the episode, an 'on' while on starts the next
            windows.append(Window(first, row))
            first = None
        if on:
            first = row
    if first is not None:
        windows.append(Window(first, int(obs_stamps.size)))
    return [w for w in windows if w.stop_obs > w.first_obs]


def windows_from_idle(idle_s: float, obs_stamps: np.ndarray, idle: np.ndarray) -> tuple[list[Window], int]:
    """``split: idle`` (:func:`ompn_ros.data.cuts.idle_windows`): windows and trimmed idle steps."""
    pairs, trimmed = idle_windows(obs_stamps, idle, idle_s)
    return [Window(a, b) for a, b in pairs], trimmed
