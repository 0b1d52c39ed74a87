"""Joint states of several publishers on one topic, merged by joint name (the reader and ``ompn_node``).

A real robot's ``/joint_states`` usually carries messages of several drivers: the arm's
(joint_state_broadcaster) and the gripper's, each naming only its own joints.  The merge rule, the same
offline (``VectorSource.merge_s`` of the reader spec) and live (``ompn_node``'s ``joint_merge``):

* every message updates the latest value (and stamp) of each joint it names;
* a message that names the **step joint** (the first of the wanted joints, e.g. the arm's first joint)
  is a step: each wanted joint takes its latest value, if that value is stamped at most ``tolerance``
  from the step (before it or, arriving out of order, after it); otherwise the step is dropped and the
  joint counted missing (a value stamped an hour ahead is never fresh, and never keeps a silent
  publisher's joints looking fresh);
* a field a message leaves empty (a driver that publishes positions only) gives no value for its joints:
  the caller reports it when it needs that field (:attr:`MergedStep.present`); a field whose length
  is neither 0 nor the message's joint count is a malformed message (:class:`MalformedJointState`),
  refused whole;
* the first step dropped for a joint names it once (:meth:`JointMerger.silence_line`: its publisher
  went silent), again only after that joint was fresh at a step.

Messages are taken in the order given (the reader: by the spec's stamps; the node: as they arrive).
O(joints of the message) per message, plus O(wanted joints) per step.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

JOINT_FIELDS = ("position", "velocity", "effort")


class MalformedJointState(ValueError):
    """A message whose field lengths do not fit its joint names (the message is not merged)."""


@dataclass(frozen=True)
class MergedStep:
    """The merged state of one step: per field the wanted joints' values (NaN where absent) and
    whether every wanted joint had that field."""

    stamp_ns: int
    values: dict[str, np.ndarray]
    present: dict[str, bool]


class JointMerger:
    """The merge rule for one topic (see the module docstring).

    Args:
        joints: the wanted joints, in observation order; the first is the step joint.
        tolerance_ns: how much older than the step a joint's latest value may be (ns, >= 0).
    """

    def __init__(self, joints: Sequence[str], tolerance_ns: int) -> None:
        if not joints or len(set(joints)) != len(joints):
            raise ValueError(f"merging needs distinct joint names, got {list(joints)}")
        if tolerance_ns < 0:
            raise ValueError(f"merge tolerance must be >= 0 ns, got {tolerance_ns}")
        self.joints = tuple(joints)
        self.tolerance_ns = int(tolerance_ns)
        self._index = {name: i for i, name in enumerate(self.joints)}
        self._stamp = np.zeros(len(self.joints), dtype=np.int64)
        self._seen = np.zeros(len(self.joints), dtype=bool)
        self._values = {f: np.full(len(self.joints), np.nan) for f in JOINT_FIELDS}
        self._has = {f: np.zeros(len(self.joints), dtype=bool) for f in JOINT_FIELDS}
        self.missing: Counter[str] = Counter()  # wanted joint -> steps dropped for lack of it
        self.steps = 0  # steps merged
        self._silent: dict[str, int | None] = {}  # joints named by silence_line: their age at the drop
        self._told: set[str] = set()  # joints named already (until fresh again at a step)

    def push(self, stamp_ns: int, names: Sequence[str],
             values: Mapping[str, np.ndarray]) -> MergedStep | None:
        """Take one message; the merged step when it is one and every joint is fresh, else ``None``.

        Raises :class:`MalformedJointState` (nothing taken) when a field has neither 0 values nor one
        per joint name."""
        fields = {f: np.asarray(values.get(f, ()), dtype=np.float64) for f in JOINT_FIELDS}
        for f, arr in fields.items():
            if arr.size not in (0, len(names)):
                raise MalformedJointState(field_width_line(f, arr.size, len(names)))
        rows = [(k, self._index[n]) for k, n in enumerate(names) if n in self._index]
        for f, arr in fields.items():
            usable = arr.size == len(names)
            for k, i in rows:
                self._values[f][i] = arr[k] if usable else np.nan
                self._has[f][i] = usable
        for _, i in rows:
            self._stamp[i], self._seen[i] = stamp_ns, True
        if self.joints[0] not in names:
            return None
        age = stamp_ns - self._stamp
        stale = ~self._seen | (age > self.tolerance_ns) | (age < -self.tolerance_ns)
        if stale.any():
            lacking = [self.joints[i] for i in np.flatnonzero(stale)]
            self.missing.update(lacking)
            for i in np.flatnonzero(stale).tolist():
                if self.joints[i] not in self._told:
                    self._told.add(self.joints[i])
                    self._silent[self.joints[i]] = int(age[i]) if self._seen[i] else None
            return None
        self._told.clear()
        self.steps += 1
        return MergedStep(int(stamp_ns), {f: v.copy() for f, v in self._values.items()},
                          {f: bool(h.all()) for f, h in self._has.items()})

    def silence_line(self) -> str | None:
        """Once per joint that went stale (until it is fresh again at a step): the line naming it and
        the publisher that went silent, or ``None``."""
        if not self._silent:
            return None
        joints = ", ".join(f"'{name}' ({_age_words(age)})" for name, age in self._silent.items())
        self._silent.clear()
        return (f"merged steps dropped: no value within {self.tolerance_ns / 1e9:g} s of the step for "
                f"joints {joints}; is the publisher of these joints silent? Each such step is dropped "
                "(counted joint_missing) until they are fresh again")

    def reset(self) -> None:
        """Forget every joint's latest value (a new stream)."""
        self._silent.clear()
        self._told.clear()
        self._seen[:] = False
        for f in JOINT_FIELDS:
            self._values[f][:] = np.nan
            self._has[f][:] = False


def _age_words(age_ns: int | None) -> str:
    if age_ns is None:
        return "never seen"
    if age_ns < 0:
        return f"stamped {-age_ns / 1e9:.3g} s after the step"
    return f"last seen {age_ns / 1e9:.3g} s before the step"


def field_width_line(field: str, width: int, joints: int) -> str:
    """The one line of a JointState field whose length differs from its joint names (the reader's
    and the node's): an empty one names the fix."""
    if width == 0:
        return (f"JointState.{field} is empty for {joints} joint names (the driver does not publish "
                f"{field}): remove '{field}' from the fields")
    return f"JointState.{field} has {width} values for {joints} joint names"


__all__ = ["JOINT_FIELDS", "JointMerger", "MalformedJointState", "MergedStep", "field_width_line"]
