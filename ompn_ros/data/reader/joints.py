"""JointState decoding: bulk when every message shares one layout, else message by message.

Cost: O(N · J) per topic; the bulk path is one ``np.frombuffer`` over the joined messages.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..errors import CorruptBagError, JointNamesError, VectorLengthError
from ..joint_merge import JointMerger, MalformedJointState, MergedStep, field_width_line
from .spec import VectorSource


@dataclass
class JointBlock:
    """Decoded JointState messages of one topic: header stamps, names and NaN-padded field arrays."""

    header: np.ndarray  # int64 [N]
    names: list[tuple[str, ...]]  # per message
    arrays: dict[str, np.ndarray]  # field -> float64 [N, W] (W = the widest message; NaN beyond a row's)
    widths: dict[str, np.ndarray]  # field -> int [N] actual width per message

    @property
    def uniform_names(self) -> bool:
        return all(n == self.names[0] for n in self.names)


def decode_joint_states(path: str, topic: str, stamps: np.ndarray, raws: list[bytes]) -> JointBlock:
    """Every JointState of a topic; an undecodable one raises :class:`CorruptBagError` at its index."""
    fast = m.stack_joint_states(raws)
    if fast is not None:
        shared_names, shared_header, bulk = fast
        n = len(raws)
        return JointBlock(shared_header, [tuple(shared_names)] * n, bulk,
                          {f: np.full(n, a.shape[1]) for f, a in bulk.items()})
    header = np.zeros(len(raws), dtype=np.int64)
    names_list: list[tuple[str, ...]] = []
    rows: dict[str, list[np.ndarray]] = {f: [] for f in layout.JOINT_FIELDS}
    for i, data in enumerate(raws):
        try:
            names, header[i], values = m.parse_joint_state(data)
        except Exception as err:  # rosbags raises several types on bad CDR
            raise CorruptBagError(f"cannot decode JointState: {err}", path=path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        names_list.append(tuple(names))
        for f in layout.JOINT_FIELDS:
            rows[f].append(values[f])
    arrays: dict[str, np.ndarray] = {}
    widths: dict[str, np.ndarray] = {}
    for f in layout.JOINT_FIELDS:
        widths[f] = np.asarray([len(r) for r in rows[f]], dtype=np.int64)
        arr = np.full((len(raws), int(widths[f].max()) if rows[f] else 0), np.nan)
        for i, r in enumerate(rows[f]):
            arr[i, : len(r)] = r  # a message naming more joints than the first keeps them all
        arrays[f] = arr
    return JointBlock(header, names_list, arrays, widths)


def merge_publishers(path: str, topic: str, src: VectorSource, stamps: np.ndarray, raws: list[bytes],
                     header: bool) -> tuple[JointBlock, np.ndarray, Counter[str]]:
    """``VectorSource.merge_s``: the merged steps of a topic several publishers share, as a block of
    the ``joint_names`` (a field some joints lack has width 0; ``header`` holds the step stamps: header
    stamps with ``header``, else ``stamps``), the message index of each step, and the steps dropped per
    missing joint.  Messages are taken in the order of the stamps used (stable)."""
    assert src.joint_names is not None and src.merge_s is not None  # VectorSource checks it
    parsed = []
    for i, data in enumerate(raws):
        try:
            parsed.append(m.parse_joint_state(data))
        except Exception as err:  # rosbags raises several types on bad CDR
            raise CorruptBagError(f"cannot decode JointState: {err}", path=path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
    clock = np.asarray([p[1] for p in parsed], dtype=np.int64) if header else np.asarray(stamps, np.int64)
    merger = JointMerger(src.joint_names, round(src.merge_s * 1e9))
    kept: list[int] = []
    steps: list[MergedStep] = []
    for i in np.argsort(clock, kind="stable").tolist():
        try:
            step = merger.push(int(clock[i]), parsed[i][0], parsed[i][2])
        except MalformedJointState as err:
            raise VectorLengthError(str(err), path=path, topic=topic, index=i, stamp=int(clock[i])) from None
        if step is not None:
            kept.append(i)
            steps.append(step)
    n, width = len(steps), len(src.joint_names)
    arrays = {f: np.array([s.values[f] for s in steps]).reshape(n, width) for f in layout.JOINT_FIELDS}
    widths = {f: np.array([width if s.present[f] else 0 for s in steps], dtype=np.int64).reshape(n)
              for f in layout.JOINT_FIELDS}
    index = np.asarray(kept, dtype=np.int64)
    return JointBlock(clock[index], [src.joint_names] * n, arrays, widths), index, merger.missing


def joint_vectors(path: str, topic: str, src: VectorSource, stamps: np.ndarray, block: JointBlock,
                  orders: dict[str, tuple[str, ...]] | None = None) -> np.ndarray:
    """Vectors ``[N, D]`` from the JointState fields of ``src`` (reordered by joint name if asked, or
    to the order the first message fixed: :func:`first_names_order`; ``orders`` carries that order
    by topic from one bag to the next of a read)."""
    order = src.joint_names
    if order is None:
        order = first_names_order(path, topic, block, orders)
    parts = []
    for name in src.fields:
        if order is None:
            parts.append(_field_as_is(path, topic, name, stamps, block))
        else:
            parts.append(_field_by_name(path, topic, name, order, stamps, block))
    n = len(stamps)
    values = np.concatenate(parts, axis=1).astype(np.float32)
    if src.dim is not None and values.shape[1] != src.dim:
        raise VectorLengthError(f"vector has {values.shape[1]} elements, expected {src.dim}", path=path,
                                topic=topic, index=0, stamp=int(stamps[0]) if n else None)
    return values


def first_names_order(path: str, topic: str, block: JointBlock,
                      orders: dict[str, tuple[str, ...]] | None = None) -> tuple[str, ...] | None:
    """Without ``joint_names`` the first message's names fix the joint order (the first bag's, when
    ``orders`` holds it; this block's first names are put there otherwise): ``None`` when every
    message names those joints in that order (or names none: read as they come), the order when
    some message names the same joints in another order (it is reordered by name).  A message
    naming other joints (a joint appears or vanishes, another URDF) raises
    :class:`JointNamesError`, whatever ``on_error``: it is no corruption.  O(N) tuple compares."""
    if not block.names or not block.names[0]:
        return None
    known = orders.get(topic) if orders is not None else None
    first = known or block.names[0]
    if orders is not None and known is None:
        orders[topic] = first
    seen: set[tuple[str, ...]] = set()
    for i, names in enumerate(block.names):
        if names in seen or names == first:
            continue
        seen.add(names)
        if sorted(names) != sorted(first):
            raise JointNamesError(_names_change(names, first, known is not None), path=path, topic=topic,
                                  index=i)
    return first if seen else None


def _names_change(names: tuple[str, ...], first: tuple[str, ...], earlier_bag: bool) -> str:
    """The line of :class:`JointNamesError`: which joints appear and vanish, and the way out."""
    appear = [n for n in names if n not in first]
    vanish = [n for n in first if n not in names]
    what = "; ".join(part for part in (f"joints {appear} appear" if appear else "",
                                       f"joints {vanish} vanish" if vanish else "") if part)
    origin = "an earlier bag's first message" if earlier_bag else "the first message"
    return (f"JointState names change at this message: {what} ({origin} names {list(first)}); set "
            "joint_names in the reader spec to the joints to read (a driver restarted with another URDF, "
            "recordings of two robots; several publishers on one topic: joint_names with merge_s)")


def _field_as_is(path: str, topic: str, name: str, stamps: np.ndarray, block: JointBlock) -> np.ndarray:
    arr, widths = block.arrays[name], block.widths[name]
    first = int(widths[0]) if widths.size else arr.shape[1]
    joints = np.fromiter((len(n) for n in block.names), dtype=np.int64, count=len(block.names))
    bad = np.flatnonzero((widths != first) | ((joints > 0) & (widths != joints)))
    if bad.size:
        i = int(bad[0])
        if joints[i] > 0 and widths[i] != joints[i]:
            raise VectorLengthError(field_width_line(name, int(widths[i]), int(joints[i])), path=path,
                                    topic=topic, index=i, stamp=int(stamps[i]))
        raise VectorLengthError(f"JointState.{name} has {widths[i]} values, the topic's first "
                                f"message {first}", path=path, topic=topic, index=i,
                                stamp=int(stamps[i]))
    return arr[:, :first]


def _field_by_name(path: str, topic: str, name: str, joint_names: tuple[str, ...], stamps: np.ndarray,
                   block: JointBlock) -> np.ndarray:
    arr, widths = block.arrays[name], block.widths[name]
    n = len(stamps)
    out = np.empty((n, len(joint_names)))
    cache: dict[tuple[str, ...], np.ndarray] = {}
    groups = [range(n)] if block.uniform_names else [[i] for i in range(n)]
    for rows in groups:
        i = rows[0]
        key = block.names[i]
        order = cache.get(key)
        if order is None:
            index = {nm: k for k, nm in enumerate(key)}
            absent = [nm for nm in joint_names if nm not in index]
            if absent:
                raise VectorLengthError(f"JointState lacks joints {absent} (several publishers on one "
                                        "topic? set merge_s on it to merge them by joint name)", path=path,
                                        topic=topic, index=i, stamp=int(stamps[i]))
            order = cache[key] = np.asarray([index[nm] for nm in joint_names])
        sel = np.asarray(rows)
        bad = sel[widths[sel] != len(key)]
        if bad.size:
            j = int(bad[0])
            raise VectorLengthError(field_width_line(name, int(widths[j]), len(key)), path=path, topic=topic,
                                    index=j, stamp=int(stamps[j]))
        out[sel] = arr[sel][:, order]
    return out
