"""Assemble the episodes of one decoded bag: windows, steps with actions, labels, extras, metadata.

Within an episode the last observation without an action becomes row ``T`` (the final observation
of the step contract).  If every observation has an action (foreign bags), the last observation is
duplicated as row ``T`` and the report notes it.  Cost: O(N) over the bag's observations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..episode import Episode
from ..errors import AlignmentError
from .align import Window, attach, windows_from_gaps, windows_from_markers
from .context import BagContext, Topics
from .decode import Decoded
from .joints import JointBlock


@dataclass
class Partners:
    """Per observation, the index of its action / subtask / joint-state message (-1 = none)."""

    act: np.ndarray
    sub: np.ndarray | None = None
    joints: np.ndarray | None = None


def bag_episodes(ctx: BagContext, topics: Topics, dec: Decoded) -> list[Episode]:
    """The episodes of one bag (see the module docstrings for the rules)."""
    report = ctx.report
    partners = _attach_all(ctx, topics, dec)
    windows = _windows(ctx, dec)
    used = sum(w.stop_obs - w.first_obs for w in windows)
    report._add(report.unattached, topics.obs, len(dec.obs_stamps) - used)
    episodes: list[Episode] = []
    prev_stop_stamp = -1
    for w in windows:
        if not _trusted(ctx, dec, w):
            continue
        steps = _steps(ctx, topics, dec, partners, w)
        if steps is None:
            continue
        episodes.append(_episode(ctx, topics, dec, partners, w, steps, prev_stop_stamp))
        prev_stop_stamp = int(dec.obs_stamps[w.stop_obs - 1])
        report.steps += len(steps)
    if report.final_duplicated:
        report.notes.append(f"every observation had an action in {report.final_duplicated} episode(s): "
                            "the last observation was duplicated as row T (s_{T+1} = s_T)")
    report.episodes = len(episodes)
    return episodes


def _trusted(ctx: BagContext, dec: Decoded, w: Window) -> bool:
    """False (and the drop reported) when the window holds a non-finite value or the bag is untrusted."""
    if ctx.raw.untrusted is not None:
        ctx.report.drop_episode("storage damage not located")
        return False
    for row, err in dec.nonfinite:
        if w.first_obs <= row < w.stop_obs:
            ctx.report.drop_episode("non-finite values", f"{err}; episode dropped")
            return False
    return True


def _attach_all(ctx: BagContext, topics: Topics, dec: Decoded) -> Partners:
    if dec.act_stamps is None:
        act = np.arange(len(dec.obs_stamps))
    else:
        act = attach(ctx, topics.act, dec.obs_stamps, dec.act_stamps)
    out = Partners(act)
    if topics.sub and dec.sub_stamps is not None:
        out.sub = attach(ctx, topics.sub, dec.obs_stamps, dec.sub_stamps)
    if topics.joints and dec.joint_stamps is not None:
        out.joints = attach(ctx, topics.joints, dec.obs_stamps, dec.joint_stamps)
    return out


def _windows(ctx: BagContext, dec: Decoded) -> list[Window]:
    if dec.markers:
        ctx.report.split = "markers"
        return windows_from_markers(ctx, dec.markers, dec.obs_stamps)
    ctx.report.split = "time_gap"
    windows = windows_from_gaps(ctx.spec.time_gap, dec.obs_stamps)
    if ctx.raw.corrupt is not None and windows:
        windows.pop()
        ctx.report.drop_episode("precedes the corruption", "last time-gap episode dropped: it precedes "
                                "the corruption")
    return windows


def _steps(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners, w: Window) -> np.ndarray | None:
    """Observation indices of the episode's action steps (``None``: the episode is dropped)."""
    report = ctx.report
    a, b = w.first_obs, w.stop_obs
    if b - a == 0:
        report.drop_episode("no observations", f"episode at {w.start_stamp} ns has no observations; dropped")
        return None
    act = partners.act
    if act[b - 1] >= 0:
        steps = np.arange(a, b)
        report.final_duplicated += 1
    else:
        steps = np.arange(a, b - 1)
    lacking = steps[act[steps] < 0]
    if lacking.size:
        report._add(report.missing, topics.act, lacking.size)
        if ctx.spec.strict:
            raise AlignmentError(f"observation #{lacking[0]} has no action partner within "
                                 f"{ctx.spec.tolerance} s", path=ctx.path, topic=topics.obs,
                                 index=int(lacking[0]), stamp=int(dec.obs_stamps[lacking[0]]))
        report.dropped_steps += int(lacking.size)
        steps = steps[act[steps] >= 0]
    if steps.size == 0:
        report.drop_episode("no action", f"episode of observations #{a}..#{b - 1} has no step with an "
                            "action; dropped")
        return None
    return steps


def _episode(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners, w: Window,
             steps: np.ndarray, prev_stop_stamp: int) -> Episode:
    final = w.stop_obs - 1
    rows = np.concatenate([steps, [final]])
    actions = dec.act[partners.act[steps]]
    subtask = _subtask(ctx, topics, dec, partners, steps)
    extras: dict[str, Any] = {}
    if partners.joints is not None and dec.joints is not None:
        extras = _joint_extras(ctx, topics.joints or "", partners.joints, dec.joints, steps, final)
    sketch = _episode_sketch(dec.sketches, w, int(dec.obs_stamps[w.first_obs]), prev_stop_stamp)
    task = w.start.get(layout.KEY_TASK, ctx.spec.task)
    seed = _int_or(w.start.get(layout.KEY_SEED), -1)
    success = w.end.get(layout.KEY_SUCCESS, "true").lower() == "true"
    if w.end and _int_or(w.end.get(layout.KEY_STEPS), len(steps)) != len(steps):
        msg = (f"end marker says {w.end.get(layout.KEY_STEPS)} steps, the bag holds {len(steps)} "
               f"for episode '{task}' seed {seed}")
        if ctx.spec.strict:
            raise AlignmentError(msg, path=ctx.path, topic=topics.episode, index=w.end_index)
        ctx.report.notes.append(msg)
    return Episode(
        observations=dec.obs[rows],
        actions=np.asarray(actions, dtype=np.int64 if topics.act_type == layout.INT32 else np.float32),
        subtask=subtask, sketch=sketch, task=task, seed=seed, success=success, extras=extras,
    )


def _subtask(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners,
             steps: np.ndarray) -> np.ndarray | None:
    if partners.sub is None or dec.sub is None:
        return None
    sidx = partners.sub[steps]
    n_missing = int((sidx < 0).sum())
    if n_missing:
        ctx.report._add(ctx.report.missing, topics.sub or "", n_missing)
        if ctx.spec.strict:
            bad = int(steps[np.flatnonzero(sidx < 0)[0]])
            raise AlignmentError(f"observation #{bad} has no subtask partner", path=ctx.path,
                                 topic=topics.obs, index=bad, stamp=int(dec.obs_stamps[bad]))
    return np.where(sidx >= 0, dec.sub[np.maximum(sidx, 0)], -1).astype(np.int64)


def _int_or(text: str | None, default: int) -> int:
    try:
        return int(text) if text is not None else default
    except ValueError:
        return default


def _episode_sketch(sketches: list[tuple[int, np.ndarray]], w: Window, first_obs_stamp: int,
                    prev_stop_stamp: int) -> np.ndarray | None:
    lower = w.start_stamp if w.start_stamp is not None else prev_stop_stamp + 1
    chosen = None
    for stamp, values in sketches:
        if lower <= stamp <= first_obs_stamp:
            chosen = values
    if chosen is None and w.start.get(layout.KEY_SKETCH):
        chosen = m.parse_sketch_value(w.start[layout.KEY_SKETCH])
    return chosen


def _joint_extras(ctx: BagContext, topic: str, first: np.ndarray, block: JointBlock, steps: np.ndarray,
                  final: int) -> dict[str, Any]:
    """``joint_<field>`` arrays aligned with the episode rows (NaN where a step has no joint state);
    ``T + 1`` rows when the final observation has a joint state, else ``T``."""
    idx = first[steps]
    lacking = int((idx < 0).sum())
    if lacking:
        ctx.report._add(ctx.report.missing, topic, lacking)
    rows = np.concatenate([idx, [first[final]]]) if first[final] >= 0 else idx
    present = rows[rows >= 0]
    if present.size == 0:
        return {}
    extras: dict[str, Any] = {"joint_names": list(block.names[int(present[0])])}
    for name in layout.JOINT_FIELDS:
        arr = block.arrays[name]
        if arr.shape[1] == 0:
            continue
        out = np.full((len(rows), arr.shape[1]), np.nan)
        out[rows >= 0] = arr[present]
        extras[f"joint_{name}"] = out
    return extras
