"""The multi-topic observation of ``ompn_node`` (the ``observation_spec`` parameter).

The node applies :class:`ompn_ros.data.obs.ObservationAssembler`, the rule the bag reader applies
offline: every message of the spec's step topic is one step, assembled from its own fields and the
latest message of each partner topic at or before it (within ``tolerance_s``), else dropped and
counted by reason; a step waits (``wait_s``) for the partners stamped by their headers to offer a
message stamped at or after it, so a late delivery does not change the observation
(:mod:`ompn_ros.data.obs.assembler`).  This module holds the node-side pieces that
need no node: the parameter rule, the message classes of the supported types, the size check against
the checkpoint and the type check against the ROS graph.  Topic names and the YAML form:
:mod:`ompn_ros.data.obs.spec`; the parameter: ``docs/parameters.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.validate_full_topic_name import validate_full_topic_name
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32, Float32MultiArray, Float64, Float64MultiArray

from ompn_ros import layout
from ompn_ros.data.joint_merge import JointMerger, MalformedJointState, field_width_line
from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec, ObservationSpecError
from ompn_ros.nodes.ompn_node_types import message_class

MESSAGE_CLASSES: Final[dict[str, Any]] = {
    layout.JOINT_STATE: JointState,
    layout.FLOAT32_ARRAY: Float32MultiArray,
    layout.FLOAT64_ARRAY: Float64MultiArray,
    layout.FLOAT32: Float32,
    layout.FLOAT64: Float64,
    layout.WRENCH_STAMPED: WrenchStamped,
    layout.POSE_STAMPED: PoseStamped,
}
"""The rclpy message class of the hand-parsed types (canonical spelling); any other installed type is
imported by name (:mod:`ompn_ros.nodes.ompn_node_types`)."""

COUNTER_PREFIX: Final = "obs."


def spec_rule(value: Any) -> str | None:
    """``ParamSpec`` check of ``observation_spec``: ``''`` (single-topic input) or a spec that parses."""
    text = str(value)
    if not text.strip():
        return None
    try:
        load_spec(text, "/")
    except ObservationSpecError as exc:
        return str(exc)
    return None


def load_spec(value: str, namespace: str) -> ObservationSpec | None:
    """The spec of the parameter value with relative topics resolved in ``namespace``; ``None`` for
    ``''``.  Raises :class:`ObservationSpecError` (one line) on a bad spec or an invalid topic name."""
    if not value.strip():
        return None
    spec = ObservationSpec.from_param(value).with_namespace(namespace)
    for topic in spec.topics:
        try:
            validate_full_topic_name(topic)
        except Exception as exc:  # rclpy's InvalidTopicNameException: its text spans several lines
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ObservationSpecError(f"topic '{topic}' is not a valid ROS topic name: {reason}") from exc
    return spec


def spec_line(spec: ObservationSpec) -> str:
    """The configure log line of an ``observation_spec``."""
    return (f"observation_spec: step topic {spec.step_topic}, topics {list(spec.topics)}, tolerance "
            f"{spec.tolerance_s} s, stamp {spec.stamp}, size {spec.declared_dim() or 'from the data'}")


class AssembledInput:
    """The node's assembler with the checks around it (not thread-safe; one per configure).

    Args:
        spec: the spec, namespaces resolved.
        obs_dim: the checkpoint's observation size.
        history: partner messages kept per topic (the ``qos_depth`` parameter is a good value).

    Raises:
        ObservationSpecError: the spec declares a size other than ``obs_dim`` (one line).
    """

    def __init__(self, spec: ObservationSpec, obs_dim: int, history: int = 256) -> None:
        declared = spec.declared_dim()
        if declared is not None and declared != obs_dim:
            raise ObservationSpecError(
                f"observation_spec assembles {declared} values per step, the checkpoint takes "
                f"obs_dim={obs_dim}"
            )
        self.spec = spec
        self.obs_dim = int(obs_dim)
        # the rclpy class of each topic (any installed type: one line naming the package otherwise)
        self.classes = {topic: message_class(typename, MESSAGE_CLASSES)
                        for topic, typename in spec.topics.items()}
        self.asm = ObservationAssembler(spec, history=max(1, history))
        self.size_checked = declared is not None
        self.topic_types: dict[str, str | None] = {}  # last problem line per topic (None = fine)
        self.type_reports = 0

    def first_size_problem(self, obs: np.ndarray) -> str | None:
        """On the first kept step only: the one line when its size differs from ``obs_dim``."""
        if self.size_checked:
            return None
        self.size_checked = True
        if obs.size == self.obs_dim:
            return None
        return (
            f"observation_spec assembled {obs.size} values per step but the checkpoint takes "
            f"obs_dim={self.obs_dim}: every step is rejected (wrong_length)"
        )

    def check_graph(self, publisher_types: Mapping[str, Sequence[str]]) -> list[str]:
        """Compare the types the publishers of the spec's topics use (``topic -> types``, our own
        subscriptions excluded) with the spec; returns the lines to log: a new or changed problem, and
        a problem that went away.  A topic without publishers is skipped.  O(publishers)."""
        lines = []
        for topic, want in self.spec.topics.items():
            types = publisher_types.get(topic)
            if not types:
                continue
            got = want if want in types else types[0]  # a matching publisher keeps the topic usable
            problem = self.asm.check_type(topic, got)
            before = self.topic_types.get(topic)
            if problem != before:
                self.topic_types[topic] = problem
                if problem is not None:
                    self.type_reports += 1
                    lines.append(problem)
                elif before is not None:
                    lines.append(f"topic '{topic}' has the expected type {want} again")
        return lines

    def counters(self) -> dict[str, int]:
        """The assembler's counters prefixed ``obs.`` (``obs.steps``, ``obs.kept``,
        ``obs.dropped.<reason>``, ``obs.rejected.<topic>.<reason>``, ``obs.ignored``)."""
        return {COUNTER_PREFIX + k: int(v) for k, v in self.asm.stats.as_dict().items()}

    @property
    def dropped_total(self) -> int:
        return int(sum(self.asm.stats.dropped.values()))


def drop_line(drop: Drop, dropped: int) -> str:
    """The throttled warning of a dropped step (or a rejected partner message)."""
    return f"step dropped: {drop} [{dropped} dropped so far]"


class JointInput:
    """``obs_source='joint_state'``: the ``joint_fields`` of each JointState as the observation, by the
    reader's rules: joints in ``joint_names`` order (``None`` = the message's order), a field a driver
    leaves empty refused in one line (:func:`ompn_ros.data.joint_merge.field_width_line`), and with
    ``merge_ns`` the messages of several publishers merged by joint name
    (:class:`ompn_ros.data.joint_merge.JointMerger`, the reader's ``merge_s``)."""

    def __init__(self, fields: Sequence[str], names: Sequence[str] | None, merge_ns: int | None) -> None:
        self.fields = tuple(fields)
        self.names = tuple(names) if names else None
        if merge_ns is not None and self.names is None:
            raise ValueError("joint_merge needs joint_names (the first names the step joint)")
        self.merger = JointMerger(self.names, merge_ns) if merge_ns is not None and self.names else None

    def observation(self, stamp_ns: int, names: Sequence[str],
                    values: Mapping[str, np.ndarray]) -> np.ndarray | str | None:
        """The observation (float64), a one-line problem, or ``None``: no step (another publisher's
        message, or a wanted joint missing: counted in :attr:`missing`, named once by
        :meth:`silence_line`)."""
        if self.merger is not None:
            try:
                step = self.merger.push(stamp_ns, names, values)
            except MalformedJointState as exc:  # a field that fits no joint count: the message, refused
                return str(exc)
            if step is None:
                return None
            absent = [f for f in self.fields if not step.present[f]]
            if absent:
                return field_width_line(absent[0], 0, len(self.merger.joints))
            return np.concatenate([step.values[f] for f in self.fields])
        parts = []
        for f in self.fields:
            arr = np.asarray(values[f], dtype=np.float64)
            if names and arr.size != len(names):
                return field_width_line(f, arr.size, len(names))
            parts.append(arr)
        if self.names is None:
            return np.concatenate(parts)
        index = {n: k for k, n in enumerate(names)}
        lacking = [n for n in self.names if n not in index]
        if lacking:
            return f"JointState lacks joints {lacking} (several publishers? set joint_merge)"
        order = [index[n] for n in self.names]
        return np.concatenate([p[order] for p in parts])

    def silence_line(self) -> str | None:
        """``joint_merge``: the line naming joints whose publisher went silent, once (see
        :meth:`ompn_ros.data.joint_merge.JointMerger.silence_line`)."""
        return self.merger.silence_line() if self.merger is not None else None

    @property
    def missing(self) -> int:
        """Steps dropped for a joint without a recent value (``joint_merge``)."""
        return int(sum(self.merger.missing.values())) if self.merger is not None else 0


def joint_input(values: Mapping[str, Any]) -> JointInput | None:
    """The node's :class:`JointInput` from its parameters (``None`` unless ``obs_source`` is
    ``joint_state``); ``ValueError`` (one line) when ``joint_merge`` lacks ``joint_names`` or ``idle_s``
    has no way to see idleness."""
    if float(values["idle_s"]) > 0 and values["idle_speed"] != "auto" and float(values["idle_speed"]) <= 0:
        raise ValueError("idle_s needs idle_speed > 0: the node sees no commands, only the observation's "
                         "speed tells that the robot is idle")
    if values["obs_source"] != "joint_state":
        return None
    names = [str(n) for n in values["joint_names"] if str(n)]
    merge = float(values["joint_merge"])
    if merge > 0 and not names:
        raise ValueError("joint_merge needs joint_names (the first names the step joint, e.g. the arm's)")
    return JointInput(values["joint_fields"], names or None, round(merge * 1e9) if merge > 0 else None)
