"""Decode every used topic of one bag into arrays, isolating a corrupt tail in one bounded step.

Decoding errors are properties of single messages (undecodable CDR, a vector whose length differs
from the spec or from its topic's first message, a JointState lacking a named joint).  With
``on_error='skip_tail'`` every topic is decoded and the first bad message *of each topic* noted;
the bag is cut at the earliest of their stamps and decoded once more.  That second pass cannot
fail: every message left precedes the first bad message of its own topic, and each topic's first
message (the reference length) is kept or the topic is empty.  So a bag is decoded at most twice.

Decoded observation and action vectors must be finite.  A NaN or infinite value (a damaged page or
chunk, a broken publisher) raises :class:`NonFiniteValueError` naming bag, topic and message
(``on_error='raise'``) or drops the episode holding that step (``'skip_tail'``), never reaching
training silently.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..errors import AlignmentError, BagError, CorruptBagError, NonFiniteValueError
from . import generic
from .context import BagContext, Topics
from .joints import JointBlock, decode_joint_states, joint_vectors, merge_publishers
from .observe import AssembledRows, assembled_rows
from .spec import SWITCH_TYPES, OnError, VectorSource
from .steps import check_header_steps
from .vectors import stack_float64_arrays
from .verify import nonfinite_rows

T = TypeVar("T")
Marker = tuple[int, str, dict[str, str], int]  # stamp, 'start' | 'end', key/values, message index


@dataclass
class Decoded:
    """Arrays of one bag.  ``obs_stamps`` is the step clock (sorted)."""

    obs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    obs_stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    act: np.ndarray = field(default_factory=lambda: np.zeros(0))
    act_stamps: np.ndarray | None = None  # None: the action comes with each observation
    sub: np.ndarray | None = None
    sub_stamps: np.ndarray | None = None
    joints: JointBlock | None = None
    joint_stamps: np.ndarray | None = None
    sketches: list[tuple[int, np.ndarray]] = field(default_factory=list)
    markers: list[Marker] | None = None  # None: no episode topic
    split_stamps: np.ndarray | None = None  # messages of the split topic
    split_switch: np.ndarray | None = None  # a recording on/off topic: per message, True = on
    obs_order: np.ndarray | None = None  # bag message index of each observation row (header clock)
    nonfinite: list[tuple[int, NonFiniteValueError]] = field(default_factory=list)  # (obs row, error)
    assembled: AssembledRows | None = None  # ReaderSpec.assemble: kept rows, names, drops by reason
    obs_log_stamps: np.ndarray | None = None  # bag log stamp of each observation row (rows as obs)


def decode_bag(ctx: BagContext, topics: Topics, on_error: OnError) -> Decoded:
    """Decoded arrays of ``ctx.raw`` (see the module docstring for the corrupt-tail rule)."""
    errors: list[BagError] | None = [] if on_error == "skip_tail" else None
    decoded = _decode_all(ctx, topics, errors)
    if errors:
        first = min(errors, key=lambda e: e.stamp if e.stamp is not None else 0)
        assert first.stamp is not None  # unstamped errors are raised by _guard
        ctx.raw.truncate(first.stamp)
        ctx.raw.corrupt = CorruptBagError(first.reason, path=ctx.path, topic=first.topic, index=first.index)
        ctx.report.error = str(first)
        decoded = _decode_all(ctx, topics, None)
    decoded.nonfinite = _nonfinite(ctx, topics, decoded)
    if decoded.nonfinite and on_error == "raise":
        raise decoded.nonfinite[0][1]
    return decoded


def _nonfinite(ctx: BagContext, topics: Topics, dec: Decoded) -> list[tuple[int, NonFiniteValueError]]:
    """Observation rows whose observation or action message holds NaN/inf, in row order."""
    found: list[tuple[int, NonFiniteValueError]] = []
    for row in nonfinite_rows(dec.obs):
        index = int(row if dec.obs_order is None else dec.obs_order[row])
        found.append((int(row), NonFiniteValueError(
            "observation holds NaN or infinite values", path=ctx.path, topic=topics.obs, index=index,
            stamp=int(dec.obs_stamps[row]))))
    for k in nonfinite_rows(dec.act):
        if dec.act_stamps is None:
            row, index, stamp = int(k), int(k if dec.obs_order is None else dec.obs_order[k]), 0
        else:
            stamp = int(dec.act_stamps[k])
            row, index = int(np.searchsorted(dec.obs_stamps, stamp, side="right")) - 1, int(k)
        found.append((row, NonFiniteValueError("action holds NaN or infinite values", path=ctx.path,
                                               topic=topics.act, index=index, stamp=stamp)))
    return sorted(found, key=lambda item: item[0])


def _guard(errors: list[BagError] | None, fn: Callable[[], T]) -> T | None:
    """``fn()``; a stamped BagError is collected (skip_tail) instead of raised."""
    try:
        return fn()
    except BagError as err:
        if errors is None or err.stamp is None:
            raise
        errors.append(err)
        return None


def _decode_all(ctx: BagContext, topics: Topics, errors: list[BagError] | None) -> Decoded:
    out = Decoded()
    if topics.assemble is not None:
        out.assembled = rows = assembled_rows(ctx, topics.assemble)  # drops, never raises, on bad messages
        out.obs, out.obs_stamps, out.obs_order = rows.values, rows.stamps, rows.order
        out.obs_log_stamps = rows.stamps
        # rows and ctx.data() are both the step messages stably sorted by log stamp: no reorder for actions
        obs: ObsParts | None = (rows.values, rows.stamps, None, ctx.stamps(topics.obs), None)
    else:
        obs = _guard(errors, lambda: _observations(ctx, topics))
        if obs is not None:
            out.obs, out.obs_stamps, out.obs_order = obs[0], obs[1], obs[2]
            out.obs_log_stamps = obs[3] if obs[2] is None else obs[3][obs[2]]
    act = _guard(errors, lambda: _actions(ctx, topics, obs))  # decoded even after a bad observation
    if act is not None:
        out.act, out.act_stamps = act
    if topics.sub:
        sub = topics.sub
        sub_stamps, raws = ctx.data(sub)
        out.sub_stamps = sub_stamps
        if topics.labels != layout.LABELS_BOUNDARY and ctx.spec.subtask_field is not None:
            out.sub = _guard(errors, lambda: generic.labels(ctx, sub, sub_stamps, raws, topics.labels))
        elif topics.labels != layout.LABELS_BOUNDARY:  # boundary events: only their stamps count
            out.sub = _guard(errors, lambda: m.stack_int32(raws, path=ctx.path, topic=sub, stamps=sub_stamps))
    if topics.split:
        split = topics.split
        out.split_stamps = ctx.stamps(split)
        if set(ctx.raw.topic_types(split)) <= SWITCH_TYPES:  # several types: each switches (resolve_all)
            out.split_switch = _guard(errors, lambda: _switch(ctx, split))  # None: start events
    if topics.joints:
        js = topics.joints
        stamps, raws = ctx.data(js)
        out.joints = _guard(errors, lambda: decode_joint_states(ctx.path, js, stamps, raws))
        if out.joints is not None:
            header = ctx.clock(js) == "header"
            out.joint_stamps = _header_clock(ctx, js, out.joints, stamps) if header else stamps
    if topics.sketch:
        stamps, raws = ctx.data(topics.sketch)
        out.sketches = [(int(s), m.parse_int32_array(r)) for s, r in zip(stamps, raws)]
    if topics.episode:
        out.markers = _guard(errors, lambda: _markers(ctx, topics.episode or ""))
    return out


ObsParts = tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, JointBlock | None]


def _observations(ctx: BagContext, topics: Topics) -> ObsParts:
    """Observations sorted by their clock, the reorder applied (if any), log stamps, JointBlock."""
    column = ctx.column(topics.obs) if topics.obs_type == layout.FLOAT32_ARRAY else None
    if column is not None:  # decoded while reading (reader.columns): the same rows, no raw bytes
        log_stamps, values = column
        stamps, block = log_stamps, None
    else:
        log_stamps, raws = ctx.data(topics.obs)
        values, stamps, block, log_stamps = _vectors(ctx, topics.obs, topics.obs_type, ctx.spec.observation,
                                                     log_stamps, raws)
    order = None  # header stamps may order the steps differently from the bag
    if stamps is not log_stamps and np.any(np.diff(stamps) < 0):
        order = np.argsort(stamps, kind="stable")
        values, stamps = values[order], stamps[order]
    return values, stamps, order, log_stamps, block


def _actions(ctx: BagContext, topics: Topics, obs: ObsParts | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Action values and their stamps (``None`` stamps: one action per observation, same topic)."""
    spec = ctx.spec
    if topics.act == topics.obs:  # e.g. JointState: observation = position, action = velocity
        obs_order, obs_log, obs_block = _same_topic_parts(ctx, topics, obs)
        if obs_block is not None:
            values = joint_vectors(ctx.path, topics.act, spec.action, obs_log, obs_block, ctx.joint_orders)
        else:
            raws = ctx.data(topics.obs)[1]
            values = _vectors(ctx, topics.act, topics.act_type, spec.action, obs_log, raws)[0]
        return (values if obs_order is None else values[obs_order]), None
    column = ctx.column(topics.act) if topics.act_type == layout.FLOAT32_ARRAY else None
    if column is not None:  # decoded while reading (reader.columns), as the observation column
        return column[1], column[0]
    stamps, raws = ctx.data(topics.act)
    if topics.act_type == layout.INT32:
        return m.stack_int32(raws, path=ctx.path, topic=topics.act, stamps=stamps), stamps
    values, act_stamps, _, _ = _vectors(ctx, topics.act, topics.act_type, spec.action, stamps, raws)
    return values, act_stamps


def _same_topic_parts(ctx: BagContext, topics: Topics,
                      obs: ObsParts | None) -> tuple[np.ndarray | None, np.ndarray, JointBlock | None]:
    """Observation reorder, log stamps and JointBlock; decoded afresh when the observations failed
    (so a bad action field earlier than the bad observation is still found in the same pass)."""
    if obs is not None:
        return obs[2], obs[3], obs[4]
    stamps, raws = ctx.data(topics.obs)
    if topics.obs_type != layout.JOINT_STATE:
        return None, stamps, None
    return None, stamps, decode_joint_states(ctx.path, topics.obs, stamps, raws)


def _vectors(ctx: BagContext, topic: str, msgtype: str, src: VectorSource, stamps: np.ndarray,
             raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, JointBlock | None, np.ndarray]:
    """Decode a vector topic: values ``[N, D]``, the stamps to align with, the JointBlock (if any) and
    the log stamps of the rows (fewer than the messages when ``src.merge_s`` merges publishers). A topic
    without messages gives no rows (the episodes then lack it: :class:`NoEpisodeError`)."""
    if not raws:
        names = len(src.joint_names) * len(src.fields) if src.joint_names else 0
        return np.zeros((0, src.dim or names), dtype=np.float32), stamps, None, stamps
    if src.field is not None or len(ctx.raw.topic_types(topic)) > 1:  # a field path, or per connection
        values = generic.vectors(ctx, topic, src, stamps, raws, ctx.message_types(topic))
        if ctx.clock(topic) != "header":
            return values, stamps, None, stamps
        robot = generic.header_stamps(ctx, topic, raws, ctx.message_types(topic))
        ctx.header_lag[topic] = stamps - robot
        return values, robot, None, stamps
    if msgtype == layout.FLOAT32_ARRAY:
        values = m.stack_float32_arrays(raws, expected_dim=src.dim, path=ctx.path, topic=topic, stamps=stamps)
        return values, stamps, None, stamps
    if msgtype == layout.FLOAT64_ARRAY:
        return stack_float64_arrays(raws, src.dim, ctx.path, topic, stamps), stamps, None, stamps
    header = ctx.clock(topic) == "header"
    if src.merge_s is not None:
        block, index, missing = merge_publishers(ctx.path, topic, src, stamps, raws, header)
        for joint, n in sorted(missing.items()):
            ctx.report.count(ctx.report.missing, f"{topic}[{joint}]", n)
        stamps = stamps[index]
    else:
        block = decode_joint_states(ctx.path, topic, stamps, raws)
    values = joint_vectors(ctx.path, topic, src, stamps, block, ctx.joint_orders)
    if header:
        ctx.header_lag[topic] = stamps - block.header
    return values, (_header_clock(ctx, topic, block, stamps) if header else stamps), block, stamps


def _header_clock(ctx: BagContext, topic: str, block: JointBlock, log: np.ndarray) -> np.ndarray:
    """``header.stamp`` of every message of ``topic``; a stamp of 0 (a publisher that leaves the header
    unset) raises :class:`AlignmentError` and a header clock that steps against the log stamps ``log``
    :class:`ClockStepError` (:mod:`.steps`), whatever ``on_error``: no step order can be trusted."""
    zero = np.flatnonzero(block.header == 0)
    if zero.size:
        raise AlignmentError(f"header.stamp is 0 in {zero.size} of {len(block.header)} messages (the "
                             "publisher leaves it unset); read with stamp: log", path=ctx.path, topic=topic,
                             index=int(zero[0]))
    check_header_steps(ctx.path, topic, log, block.header)
    return block.header


SWITCH_ON = frozenset({"start", "on", "true", "1", "record", "recording", "begin"})
SWITCH_OFF = frozenset({"stop", "off", "false", "0", "pause", "paused", "end"})


def _switch(ctx: BagContext, topic: str) -> np.ndarray | None:
    """Per message of a recording on/off topic, whether it switches recording on; ``None`` when the
    values are no switch (a String other than the on/off words, an integer other than 0/1: then each
    message is an episode start, as for any other type)."""
    stamps, raws = ctx.data(topic)
    types = ctx.message_types(topic)  # each message by its own type (a split bag may change it)
    words: list[str] = []
    for i, data in enumerate(raws):
        try:
            value = m.deserialize(data, types[i]).data
        except Exception as err:  # rosbags raises several types on bad CDR
            raise CorruptBagError(f"cannot decode {types[i]}: {err}", path=ctx.path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        words.append(str(value).strip().lower() if types[i].endswith("/String") else str(int(value)))
    if not set(words) <= SWITCH_ON | SWITCH_OFF:
        return None
    return np.asarray([w in SWITCH_ON for w in words], dtype=bool)


def _markers(ctx: BagContext, topic: str) -> list[Marker]:
    stamps, raws = ctx.data(topic)
    types = ctx.message_types(topic)  # each message by its own type: typed markers and the old form
    markers: list[Marker] = []
    for i, data in enumerate(raws):
        try:
            parsed = m.parse_marker(data, types[i])
        except Exception as err:  # rosbags raises several types on bad CDR
            raise CorruptBagError(f"cannot decode episode marker: {err}", path=ctx.path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        if parsed is not None:
            markers.append((int(stamps[i]), parsed[0], parsed[1], i))
    return markers
