"""Assemble the episodes of one decoded bag: windows, steps with actions, labels, extras, metadata.

Within an episode the last observation without an action becomes row ``T`` (the final observation
of the step contract).  When every observation has an action (the observation after the last
command was not recorded) ``ReaderSpec.final_observation`` decides.  Cost: O(N) over the bag's
observations; an episode's observations are a view of the bag's observation array when its rows
are consecutive (the usual case), so the episodes add no copy of the observations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..cuts import ALL_ELEMENTS, SpeedElements, derive_idle_speed, idle_by_speed
from ..episode import OBS_STAMPS, Episode
from ..errors import AlignmentError
from .align import (
    Window,
    attach,
    attach_events,
    windows_from_gaps,
    windows_from_idle,
    windows_from_markers,
    windows_from_topic,
)
from .clocks import check_clocks
from .context import BagContext, Topics
from .decode import Decoded
from .joints import JointBlock
from .labels import LabelSite, ordinals_from_events, ordinals_from_ids, ordinals_from_values
from .report import BLANK_LAST, DROPPED_LAST, DUPLICATED_LAST, EXTRAPOLATED_LAST, FINAL_GUESS


@dataclass
class Partners:
    """Per observation, the index of its action / subtask / joint-state message (-1 = none)."""

    act: np.ndarray
    sub: np.ndarray | None = None
    events: np.ndarray | None = None  # boundary labels: the observation's step ends a subtask
    joints: np.ndarray | None = None


def bag_episodes(ctx: BagContext, topics: Topics, dec: Decoded) -> list[Episode]:
    """The episodes of one bag (see the module docstrings for the rules)."""
    report = ctx.report
    clocked = [(topics.act, dec.act_stamps), (topics.sub, dec.sub_stamps), (topics.joints, dec.joint_stamps)]
    check_clocks(ctx, topics.obs, dec.obs_stamps, [(t, st) for t, st in clocked if t and st is not None])
    partners = _attach_all(ctx, topics, dec)
    windows = _windows(ctx, topics, dec, partners)
    used = sum(w.stop_obs - w.first_obs for w in windows)
    report.count(report.unattached, topics.obs, len(dec.obs_stamps) - used)
    if dec.assembled is not None:
        for key, n in dec.assembled.dropped.items():
            report.count(report.obs_dropped, key, n)
        for key, n in dec.assembled.rejected.items():
            report.count(report.obs_rejected, key, n)
    episodes: list[Episode] = []
    prev_stop_stamp = -1
    for w in windows:
        if not _trusted(ctx, dec, w) or not _ends_kept(ctx, dec, w):
            continue
        steps = _steps(ctx, topics, dec, partners, w, len(episodes))
        if steps is None:
            continue
        episodes.append(_episode(ctx, topics, dec, partners, w, steps, prev_stop_stamp, len(episodes)))
        prev_stop_stamp = int(dec.obs_stamps[w.stop_obs - 1])
        report.steps += len(steps)
    if report.final_duplicated:
        report.notes.append(f"every observation had an action in {report.final_duplicated} episode(s): "
                            "the last observation was duplicated as row T (s_{T+1} = s_T)")
        report.guessed.append(FINAL_GUESS + "the last observation (final_observation: duplicate)")
    if report.adjusted.get(BLANK_LAST):
        report.guessed.append(FINAL_GUESS + "zeros (final_observation: blank)")
    if report.adjusted.get(EXTRAPOLATED_LAST):
        report.guessed.append(FINAL_GUESS + "2 s_T - s_{T-1} (final_observation: extrapolate)")
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


def _ends_kept(ctx: BagContext, dec: Decoded, w: Window) -> bool:
    """``ReaderSpec.assemble``: end the window at its last row the observation rule kept (row ``T``
    must be a real observation); False (and the drop reported) when it kept none."""
    if dec.assembled is None:
        return True
    kept = np.flatnonzero(dec.assembled.kept[w.first_obs:w.stop_obs])
    if kept.size == 0:
        ctx.report.drop_episode("no observation kept", f"the observation rule dropped every step of the "
                                f"episode of observations #{w.first_obs}..#{w.stop_obs - 1}")
        return False
    w.stop_obs = w.first_obs + int(kept[-1]) + 1
    return True


def _attach_all(ctx: BagContext, topics: Topics, dec: Decoded) -> Partners:
    if dec.act_stamps is None:
        act = np.arange(len(dec.obs_stamps))
    else:
        act = attach(ctx, topics.act, dec.obs_stamps, dec.act_stamps)
    out = Partners(act)
    if topics.sub and dec.sub_stamps is not None:
        if topics.labels == layout.LABELS_BOUNDARY:
            out.events = attach_events(ctx, topics.sub, dec.obs_stamps, dec.sub_stamps)
        else:
            out.sub = attach(ctx, topics.sub, dec.obs_stamps, dec.sub_stamps)
    if topics.joints and dec.joint_stamps is not None:
        out.joints = attach(ctx, topics.joints, dec.obs_stamps, dec.joint_stamps)
    return out


def _windows(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners) -> list[Window]:
    split = ctx.spec.split
    if split == "topic" and dec.split_stamps is not None:
        ctx.report.split = "topic"
        windows = windows_from_topic(dec.split_stamps, dec.obs_stamps, dec.split_switch)
    elif split == "idle":
        ctx.report.split = "idle"
        windows, trimmed = windows_from_idle(ctx.spec.idle_s, dec.obs_stamps, _idle(ctx, dec, partners))
        ctx.report.idle_trimmed += trimmed
    elif split == "bag":
        ctx.report.split = "bag"
        windows = [Window(0, int(dec.obs_stamps.size))] if dec.obs_stamps.size else []
    elif split == "markers" or (split == "auto" and dec.markers):
        ctx.report.split = "markers"
        return windows_from_markers(ctx, dec.markers or [], dec.obs_stamps)
    else:
        ctx.report.split = "time_gap"
        windows = windows_from_gaps(ctx.spec.time_gap, dec.obs_stamps)
    if ctx.raw.corrupt is not None and windows:
        windows.pop()
        ctx.report.drop_episode("precedes the corruption", f"last {ctx.report.split} episode dropped: it "
                                "precedes the corruption")
    return windows


def speed_elements(spec: Any) -> SpeedElements:
    """The elements whose speed tells an idle step (:class:`ompn_ros.data.cuts.SpeedElements`): a JointState
    observation's fields, every element of any other (an assembled one included)."""
    src = spec.observation
    if spec.assemble is None and src.type == layout.JOINT_STATE:
        return SpeedElements(tuple(src.fields))
    return ALL_ELEMENTS


def _idle(ctx: BagContext, dec: Decoded, partners: Partners) -> np.ndarray:
    """``split: idle``: per observation, whether the robot is idle (no command attached, or its speed
    below ``idle_speed``, derived from the bag with ``auto``; :mod:`ompn_ros.data.cuts.idle`)."""
    idle = partners.act < 0 if dec.act_stamps is not None else np.zeros(len(dec.obs_stamps), dtype=bool)
    elements = speed_elements(ctx.spec)
    speed = ctx.spec.idle_speed
    if speed == "auto":
        derived = derive_idle_speed(dec.obs_stamps, dec.obs, elements)
        speed = derived.speed
        ctx.report.idle_rule = derived.text
    else:
        ctx.report.idle_rule = f"idle_speed {float(speed):g} on {elements.describe()}"
    ctx.report.idle_speed, ctx.report.idle_on = float(speed), elements.describe()
    if dec.act_stamps is None and float(speed) <= 0:
        ctx.report.notes.append("split: idle cannot see the robot idle: every observation carries its "
                                "action and idle_speed is 0; set idle_speed (rad/s of joint speed) or auto")
    if float(speed) > 0:
        idle = idle | idle_by_speed(dec.obs_stamps, dec.obs, float(speed), elements)
    return idle


def _steps(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners, w: Window,
           number: int) -> np.ndarray | None:
    """Observation indices of the episode's action steps (``None``: the episode is dropped)."""
    report = ctx.report
    a, b = w.first_obs, w.stop_obs
    if b - a == 0:
        report.drop_episode("no observations", f"episode at {w.start_stamp} ns has no observations; dropped")
        return None
    act = partners.act
    steps = _final_observation(ctx, topics, dec, w, number) if act[b - 1] >= 0 else np.arange(a, b - 1)
    if steps is None:
        return None
    if dec.assembled is not None:  # steps the observation rule dropped (counted in obs_dropped)
        steps = steps[dec.assembled.kept[steps]]
    lacking = steps[act[steps] < 0]
    if lacking.size:
        report.count(report.missing, topics.act, lacking.size)
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
    if steps.size < 2 and number in report.adjusted.get(EXTRAPOLATED_LAST, ()):
        _extrapolation_to_duplicate(ctx, number)  # one step left: nothing to extrapolate from
    return steps


def _extrapolation_to_duplicate(ctx: BagContext, number: int) -> None:
    """Episode ``number`` keeps one step only: row ``T`` duplicates it instead of extrapolating."""
    report = ctx.report
    report.adjusted[EXTRAPOLATED_LAST].remove(number)
    if not report.adjusted[EXTRAPOLATED_LAST]:
        del report.adjusted[EXTRAPOLATED_LAST]
    report.final_duplicated += 1
    report.adjusted.setdefault(DUPLICATED_LAST, []).append(number)


def _final_observation(ctx: BagContext, topics: Topics, dec: Decoded, w: Window,
                       number: int) -> np.ndarray | None:
    """Steps of an episode whose last observation has an action (``ReaderSpec.final_observation``)."""
    a, b = w.first_obs, w.stop_obs
    report, how = ctx.report, ctx.spec.final_guess
    if how == "extrapolate" and b - a < 2:
        how = "duplicate"  # one recorded step: nothing to extrapolate from
    if how == "duplicate":
        report.final_duplicated += 1
        report.adjusted.setdefault(DUPLICATED_LAST, []).append(number)
        return np.arange(a, b)
    if how in ("blank", "extrapolate"):
        report.adjusted.setdefault(BLANK_LAST if how == "blank" else EXTRAPOLATED_LAST, []).append(number)
        return np.arange(a, b)
    if how == "drop_last_step":
        report.adjusted.setdefault(DROPPED_LAST, []).append(number)
        return np.arange(a, b - 1)
    msg = (f"episode #{number} (observations #{a}..#{b - 1}) has no observation after its last action; "
           "set final_observation: duplicate, blank, extrapolate or drop_last_step")
    if ctx.spec.strict:
        raise AlignmentError(msg, path=ctx.path, topic=topics.obs, index=b - 1,
                             stamp=int(dec.obs_stamps[b - 1]))
    report.drop_episode("no final observation", msg)
    return None


def _episode(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners, w: Window,
             steps: np.ndarray, prev_stop_stamp: int, number: int) -> Episode:
    final = w.stop_obs - 1  # row T: the observation after the last action (or its duplicate)
    rows = np.concatenate([steps, [final]])
    actions = _rows(dec.act, partners.act[steps])  # a view when consecutive, as the observations
    sketch = _episode_sketch(dec.sketches, w, int(dec.obs_stamps[w.first_obs]), prev_stop_stamp)
    subtask, extras = _labels(ctx, topics, dec, partners, w, steps, sketch, number)
    if dec.assembled is not None:
        extras["obs_names"] = list(dec.assembled.names)
    if dec.obs_log_stamps is not None and len(dec.obs_log_stamps) == len(dec.obs):
        stamps = np.asarray(dec.obs_log_stamps[rows], dtype=np.int64)
        # a final observation copied from the last step's message has no stamp of its own
        extras[OBS_STAMPS] = stamps[:-1] if len(stamps) > 1 and stamps[-1] <= stamps[-2] else stamps
    if partners.joints is not None and dec.joints is not None:
        extras.update(_joint_extras(ctx, topics.joints or "", partners.joints, dec.joints, steps, final))
    task = w.start.get(layout.KEY_TASK, ctx.spec.task)
    seed = _int_or(w.start.get(layout.KEY_SEED), -1)
    success = w.end.get(layout.KEY_SUCCESS, "true").lower() == "true"
    # final_observation: drop_last_step removed one recorded step on purpose: the marker counts it
    recorded = len(steps) + (number in ctx.report.adjusted.get(DROPPED_LAST, ()))
    if w.end and _int_or(w.end.get(layout.KEY_STEPS), recorded) != recorded:
        msg = (f"end marker says {w.end.get(layout.KEY_STEPS)} steps, the bag holds {recorded} "
               f"for episode '{task}' seed {seed}")
        if ctx.spec.strict:
            raise AlignmentError(msg, path=ctx.path, topic=topics.episode, index=w.end_index)
        ctx.report.notes.append(msg)
    observations = _final_row(_rows(dec.obs, rows), ctx.report.adjusted, number)
    return Episode(
        observations=observations,
        actions=np.asarray(actions, dtype=np.int64 if topics.act_type == layout.INT32 else np.float32),
        subtask=subtask, sketch=sketch, task=task, seed=seed, success=success, extras=extras,
    )


def _final_row(observations: np.ndarray, adjusted: dict[str, list[int]], number: int) -> np.ndarray:
    """Row ``T`` of an episode recorded without its final observation (a copy of the last one in
    ``observations``): zeros for ``blank``, ``2 s_T - s_{T-1}`` for ``extrapolate`` (episodes of
    two steps or more; see :func:`_final_observation`).  Other episodes are returned unchanged."""
    blank = number in adjusted.get(BLANK_LAST, ())
    extrapolate = number in adjusted.get(EXTRAPOLATED_LAST, ())
    if not (blank or extrapolate):
        return observations
    out = observations.copy()
    out[-1] = 0.0 if blank else 2.0 * out[-2] - out[-3]
    return out


def _rows(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``values[rows]``: a view when ``rows`` are consecutive (the usual episode), else a copy.

    Views keep the bag's one observation array alive while any of its episodes is, instead of
    holding it twice."""
    if rows.size and int(rows[-1]) - int(rows[0]) == rows.size - 1 and np.all(np.diff(rows) == 1):
        return values[int(rows[0]): int(rows[-1]) + 1]
    return values[rows]


def _labels(ctx: BagContext, topics: Topics, dec: Decoded, partners: Partners, w: Window, steps: np.ndarray,
            sketch: np.ndarray | None, number: int) -> tuple[np.ndarray | None, dict[str, Any]]:
    """Ordinals of the steps (``ReaderSpec.labels``) and the extras keeping the user's ids."""
    site = LabelSite(ctx.path, topics.sub or "", number, w.first_obs, w.stop_obs - 1)
    if partners.events is not None:
        return ordinals_from_events(partners.events[steps], site).ordinals, {}
    if partners.sub is None or dec.sub is None:
        return None, {}
    sidx = partners.sub[steps]
    n_missing = int((sidx < 0).sum())
    if n_missing:
        ctx.report.count(ctx.report.missing, topics.sub or "", n_missing)
        if ctx.spec.strict:
            bad = int(steps[np.flatnonzero(sidx < 0)[0]])
            raise AlignmentError(f"observation #{bad} has no subtask partner", path=ctx.path,
                                 topic=topics.obs, index=bad, stamp=int(dec.obs_stamps[bad]))
    values = np.where(sidx >= 0, dec.sub[np.maximum(sidx, 0)], -1).astype(np.int64)
    if topics.labels == layout.LABELS_ID:
        labels = ordinals_from_ids(values)
        return labels.ordinals, {"subtask_id": labels.ids}
    return ordinals_from_values(values, None if sketch is None else len(sketch), site).ordinals, {}


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
        ctx.report.count(ctx.report.missing, topic, lacking)
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
