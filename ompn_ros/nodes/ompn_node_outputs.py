"""``ompn_node``'s outputs: the publishers, the per-step messages, boundary events, warnings, counters.

:class:`NodeOutputs` is the :class:`~ompn_ros.stream.rule.StreamSink` of the node's stream rule: what
the rule decides (a step, a boundary, a skipped input, a line worth a warning) goes out here, built by
:mod:`ompn_ros.data.messages` (topics and message layouts: the
module docstring of :mod:`ompn_ros.nodes.ompn_node`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.lifecycle import LifecycleNode
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray, Int32

from ompn_interfaces.msg import SubtaskBoundary, SubtaskState
from ompn_ros import layout
from ompn_ros.data.messages import SubtaskBoundary as BoundaryFields
from ompn_ros.data.messages import (
    encode_diagnostic_status,
    encode_float32_array,
    encode_int32,
    encode_subtask_boundary,
    encode_subtask_state,
)
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.nodes.ompn_node_obs import AssembledInput, JointInput
from ompn_ros.nodes.ompn_node_params import boundary_qos, policy_kind_name
from ompn_ros.segmenter import SegmenterOutput
from ompn_ros.stream.rule import StreamRule

LEVEL_OK, LEVEL_WARN = 0, 1
EVENT_COUNTERS = (
    "episodes", "episode_starts", "episodes_ended", "episode_gaps", "markers", "markers_lost",
    "messages_lost", "boundaries", "clock_jumps", "clock_jumps_forward", "clock_stalls", "clock_negative",
    "bad_end_markers", "qos_incompatible", "messages_missed", "clock_steps",
)  # fmt: skip
"""The event counters on ``/diagnostics``, in this order (:meth:`NodeOutputs.counters`)."""


class NodeOutputs(LifecycleNode):
    """The publishing part of ``OMPNNode`` (its base class; ``OMPNNode.__init__`` sets these attributes)."""

    stream: StreamRule
    values: dict[str, Any]
    assembled: AssembledInput | None
    _joints: JointInput | None
    _pubs: dict[str, Any]
    _fq_name: str
    _frame_id: str
    _n_slots: int
    _last_warn: float
    _duplicates: int
    qos_warnings: list[str]

    def create_outputs(self, config: Any) -> None:
        """The lifecycle publishers for a policy of ``config`` (its action type)."""
        per_step = QoSProfile(depth=int(self.values["qos_depth"]), reliability=ReliabilityPolicy.RELIABLE,
                              history=HistoryPolicy.KEEP_LAST)
        action_type = Int32 if config.action_type == "discrete" else Float32MultiArray
        events = PublisherEventCallbacks(
            incompatible_qos=lambda info: self._qos_mismatch("~/boundary", "boundary_replay", info)
        )
        self._n_slots = int(config.n_slots)
        self._pubs = {
            "action": self.create_lifecycle_publisher(action_type, layout.CMD_ACTION, per_step),
            "pi": self.create_lifecycle_publisher(Float32MultiArray, layout.PI, per_step),
            "state": self.create_lifecycle_publisher(SubtaskState, layout.STATE, per_step),
            "boundary": self.create_lifecycle_publisher(
                SubtaskBoundary,
                layout.BOUNDARY,
                boundary_qos(str(self.values["boundary_replay"])),
                event_callbacks=events,
            ),
            "diagnostics": self.create_lifecycle_publisher(DiagnosticArray, layout.DIAGNOSTICS, 10),
        }

    def _qos_mismatch(self, topic: str, param: str | None, info: Any) -> None:
        """One line per incompatible QoS pairing, naming the parameter to change."""
        policy = policy_kind_name(info.last_policy_kind)
        fix = (
            f"set parameter '{param}' (now '{self.values[param]}') to match the peer"
            if param
            else "the peer must use RELIABLE, VOLATILE-compatible QoS"
        )
        text = f"QoS of '{topic}' incompatible with a peer ({policy}, {info.total_count} so far): {fix}"
        self.stream.events["qos_incompatible"] += 1
        self.qos_warnings.append(text)
        self.get_logger().error(text)

    # --- the stream rule's sink ------------------------------------------------------------------
    def step_out(self, out: SegmenterOutput, stamp_ns: int, episode: int) -> None:
        """Publish one step's action, ``~/pi`` and ``~/state`` (its boundary went out just before)."""
        so = out.step_output
        seg = self.stream.segmenter
        assert seg is not None
        config = seg.policy.config
        if config.action_type == "discrete":
            done = so.done_prob > self.values["done_threshold"]
            self._pubs["action"].publish(encode_int32(config.action_dim if done else so.action))
        else:
            self._pubs["action"].publish(encode_float32_array(so.action, "action"))
        n = self._n_slots
        pi_values = np.empty(n + 2, np.float32)
        pi_values[:n] = so.pi
        pi_values[n] = so.expected_position
        pi_values[n + 1] = so.pi_end
        self._pubs["pi"].publish(encode_float32_array(pi_values, layout.PI_LABEL))
        self._pubs["state"].publish(encode_subtask_state(
            stamp_ns, self._frame_id, episode, out.step_index, so.pi, so.expected_position, so.pi_end))
        if out.boundary is not None:
            self.log_boundary(out.boundary)

    def boundary_out(self, event: BoundaryEvent, decided_ns: int, episode: int, log: bool) -> None:
        """Publish ``event`` on ``~/boundary`` (the codec's bytes, the node name and frame id encoded
        once) and, with ``log``, log it."""
        stamp = event.stamp_ns or self.get_clock().now().nanoseconds
        self._pubs["boundary"].publish(encode_subtask_boundary(BoundaryFields.from_event(
            event, node=self._fq_name, episode=episode, frame_id=self._frame_id,
            sketch=self.stream.episode_sketch, decided_stamp_ns=decided_ns, stamp_ns=stamp)))
        if log:
            self.log_boundary(event)

    def publish_boundary(self, event: BoundaryEvent, log: bool = True, decided_ns: int | None = None) -> None:
        """Publish ``event`` as the stream rule does (it is then the episode's last boundary)."""
        self.stream.emit_boundary(event, decided_ns, log)

    def log_boundary(self, event: BoundaryEvent) -> None:
        if event.episode_end:
            self.get_logger().info(f"episode end: step={event.step} subtasks={event.subtask}")
            return
        self.get_logger().info(
            f"subtask boundary: step={event.step} subtask={event.subtask} score={event.score:.3f} "
            f"level={event.level} detected_at={event.detected_at}{' (episode end)' if event.final else ''}"
        )

    def warn_throttled(self, text: str, with_total: bool = True) -> None:
        now = time.monotonic()
        if now - self._last_warn >= float(self.values["warn_throttle"]):
            self._last_warn = now
            seg = self.stream.segmenter
            total = seg.rejected_total if seg else 0
            self.get_logger().warning(f"{text} [{total} rejected so far]" if with_total else text)

    def warning(self, text: str) -> None:
        self.get_logger().warning(text)

    # --- health ----------------------------------------------------------------------------------
    def counters(self) -> dict[str, int]:
        """Health counters (also on /diagnostics): accepted steps, rejected inputs (total and by
        reason), episodes (that had a step), episode_starts (accepted start markers, ~/reset calls and
        clock restarts), episodes_ended (end markers, pauses and clock restarts that closed an episode),
        episode_gaps (pauses of ``episode_gap`` seen), markers (episode markers handled: every marker
        received is counted here or, when the middleware lost it, in markers_lost), messages_lost (all
        topics, reported by the middleware), messages_missed (input messages a publisher sent that the
        node never received: gaps in its sequence numbers, :mod:`ompn_ros.stream.delivery`),
        boundaries published, clock_jumps (input stamps back by more than ``clock_jump_back``),
        clock_steps (steps of the robot's header clock that cut nothing, docs/specs.md "Clocks"),
        clock_jumps_forward (``/clock`` ahead by more than ``clock_jump_forward``), clock_stalls (``/clock``
        stood still for ``clock_stall``), clock_negative (negative ``/clock`` times dropped),
        bad_end_markers, qos_incompatible (and duplicate_names on /diagnostics); with ``observation_spec``
        also the assembler's ``obs.*`` counters (steps, kept, dropped by reason, rejected partner
        messages by topic and reason), ``obs_type_reports`` (wrong advertised types seen) and
        ``obs_size_mismatch``; with ``idle_s`` ``idle_trimmed`` (idle observations in no episode), with
        ``joint_merge`` ``joint_missing`` (steps dropped for a joint without a recent value); with a model's
        ``still_tolerance`` ``still_observations`` (observations that moved nothing: not stepped);
        ``repeated_messages``: messages a driver sent twice, stepped once (:mod:`ompn_ros.data.cuts`)."""
        stream, seg = self.stream, self.stream.segmenter
        out = {"accepted": 0, "rejected": 0}
        if seg is not None:
            out.update(accepted=seg.accepted, rejected=seg.rejected_total)
        for key in EVENT_COUNTERS:
            out[key] = int(stream.events[key])
        if seg is not None:
            out.update({f"rejected_{k}": int(v) for k, v in seg.rejected.items()})
        out["repeated_messages"] = stream.repeats.total
        if stream.idle is not None:
            out["idle_trimmed"] = stream.idle.trimmed
        if seg is not None and seg.still_tolerance > 0:
            out["still_observations"] = int(stream.events["still_observations"])
        if self._joints is not None and self._joints.merger is not None:
            out["joint_missing"] = self._joints.missing
        if self.assembled is not None:
            out.update(self.assembled.counters())
            out["obs_type_reports"] = self.assembled.type_reports
            out["obs_size_mismatch"] = int(stream.events["obs_size_mismatch"])
        return out

    def publish_diagnostics(self) -> None:
        """Publish the counters on /diagnostics (silently skipped once the context is shutting down)."""
        pub = self._pubs.get("diagnostics")
        if pub is None or not self.context.ok():
            return
        counters = self.counters()
        dropped = self.assembled.dropped_total if self.assembled is not None else 0
        rejected = counters["rejected"] > 0 or dropped > 0
        counters["duplicate_names"] = self._duplicates
        message = "rejected input" if rejected else "ok"
        if self._duplicates:
            message = f"duplicate node name: {self._duplicates + 1} nodes publish this status"
        raw = encode_diagnostic_status(
            self.get_clock().now().nanoseconds, f"{self.get_fully_qualified_name()}: segmenter",
            message, counters, LEVEL_WARN if rejected or self._duplicates else LEVEL_OK,
        )  # fmt: skip
        try:
            pub.publish(raw)
        except Exception as exc:  # SIGINT tears the context down while the timer is due: not an error
            # (checked again here: the context may have gone between the check above and the call,
            # and then logging, which publishes to /rosout, would raise in its turn)
            if self.context.ok() and "context" not in str(exc):
                self.warn_throttled(f"/diagnostics not published: {exc}")
