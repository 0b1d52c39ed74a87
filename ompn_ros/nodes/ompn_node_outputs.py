"""``ompn_node``'s outputs: the publishers, the per-step messages, boundary events, warnings, counters.

:class:`NodePublishers` is the :class:`~ompn_ros.stream.rule.StreamSink` of the node's stream rule, which
it builds around itself: what the rule decides (a step, a boundary, a skipped input, a line worth a
warning) goes out here, built by :mod:`ompn_ros.data.messages` (topics and message layouts: the module
docstring of :mod:`ompn_ros.nodes.ompn_node`).  The node holds one and passes it what it needs.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
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
from ompn_ros.nodes.ompn_node_params import boundary_qos, policy_kind_name
from ompn_ros.segmenter import SegmenterOutput
from ompn_ros.stream.rule import StreamRule
from ompn_ros.validate import InvalidInput, WrongObservationLength

LEVEL_OK, LEVEL_WARN = 0, 1
EVENT_COUNTERS = (
    "episodes", "episode_starts", "episodes_ended", "episode_gaps", "markers", "markers_lost",
    "messages_lost", "boundaries", "clock_jumps", "clock_jumps_forward", "clock_stalls", "clock_negative",
    "bad_end_markers", "qos_incompatible", "messages_missed", "clock_steps",
)  # fmt: skip
"""The event counters on ``/diagnostics``, in this order (:meth:`NodePublishers.counters`)."""


class NodePublishers:
    """The node's publishers and the stream rule they publish for (:attr:`stream`).

    Args:
        node: the lifecycle node that owns the publishers (and logs).
        values: the node's parameter values (the same dict, kept current by the node).
        clock: the node's clock in ns (the stream rule's receive time).
    """

    def __init__(self, node: LifecycleNode, values: dict[str, Any], clock: Callable[[], int]) -> None:
        self.node, self.values = node, values
        self.stream = StreamRule(self, clock)
        self.pubs: dict[str, Any] = {}
        self.frame_id = ""  # the observation's header.frame_id (JointState input), set by the inputs
        self.qos_warnings: list[str] = []
        self._fq_name = node.get_fully_qualified_name()  # the node field of ~/boundary
        self._n_slots = 0
        self._discrete = False
        self._action_dim = 0
        self._last_warn = -float("inf")
        self._source = ""
        self._sizes_reported: set[str] = set()  # observation size mismatches logged (once each)

    def create(self, config: Any, source: str) -> None:
        """The lifecycle publishers for a policy of ``config`` (its action type); ``source``: where the
        observations come from (``NodeInputs.source``), named by a size mismatch's line."""
        node = self.node
        self._source = source
        per_step = QoSProfile(depth=int(self.values["qos_depth"]), reliability=ReliabilityPolicy.RELIABLE,
                              history=HistoryPolicy.KEEP_LAST)
        self._discrete = config.action_type == "discrete"
        self._action_dim = int(config.action_dim)
        events = PublisherEventCallbacks(
            incompatible_qos=lambda info: self.qos_mismatch("~/boundary", "boundary_replay", info)
        )
        self._n_slots = int(config.n_slots)
        self.pubs = {
            "action": node.create_lifecycle_publisher(Int32 if self._discrete else Float32MultiArray,
                                                      layout.CMD_ACTION, per_step),
            "pi": node.create_lifecycle_publisher(Float32MultiArray, layout.PI, per_step),
            "state": node.create_lifecycle_publisher(SubtaskState, layout.STATE, per_step),
            "boundary": node.create_lifecycle_publisher(
                SubtaskBoundary,
                layout.BOUNDARY,
                boundary_qos(str(self.values["boundary_replay"])),
                event_callbacks=events,
            ),
            "diagnostics": node.create_lifecycle_publisher(DiagnosticArray, layout.DIAGNOSTICS, 10),
        }

    def destroy(self) -> None:
        """Destroy the publishers (cleanup)."""
        for pub in self.pubs.values():
            self.node.destroy_lifecycle_publisher(pub)
        self.pubs = {}

    def qos_mismatch(self, topic: str, param: str | None, info: Any) -> None:
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
        self.node.get_logger().error(text)

    # --- the stream rule's sink ------------------------------------------------------------------
    def step_out(self, out: SegmenterOutput, stamp_ns: int, episode: int) -> None:
        """Publish one step's action, ``~/pi`` and ``~/state`` (its boundary went out just before)."""
        so = out.step_output
        pubs = self.pubs
        if self._discrete:
            done = so.done_prob > self.values["done_threshold"]
            pubs["action"].publish(encode_int32(self._action_dim if done else so.action))
        else:
            pubs["action"].publish(encode_float32_array(so.action, "action"))
        n = self._n_slots
        pi_values = np.empty(n + 2, np.float32)
        pi_values[:n] = so.pi
        pi_values[n] = so.expected_position
        pi_values[n + 1] = so.pi_end
        pubs["pi"].publish(encode_float32_array(pi_values, layout.PI_LABEL))
        pubs["state"].publish(encode_subtask_state(
            stamp_ns, self.frame_id, episode, out.step_index, so.pi, so.expected_position, so.pi_end))
        if out.boundary is not None:
            self.log_boundary(out.boundary)

    def boundary_out(self, event: BoundaryEvent, decided_ns: int, episode: int, log: bool) -> None:
        """Publish ``event`` on ``~/boundary`` (the codec's bytes, the node name and frame id encoded
        once) and, with ``log``, log it."""
        stamp = event.stamp_ns or self.node.get_clock().now().nanoseconds
        self.pubs["boundary"].publish(encode_subtask_boundary(BoundaryFields.from_event(
            event, node=self._fq_name, episode=episode, frame_id=self.frame_id,
            sketch=self.stream.episode_sketch, decided_stamp_ns=decided_ns, stamp_ns=stamp)))
        if log:
            self.log_boundary(event)

    def publish_boundary(self, event: BoundaryEvent, log: bool = True, decided_ns: int | None = None) -> None:
        """Publish ``event`` as the stream rule does (it is then the episode's last boundary)."""
        self.stream.emit_boundary(event, decided_ns, log)

    def log_boundary(self, event: BoundaryEvent) -> None:
        if event.episode_end:
            self.node.get_logger().info(f"episode end: step={event.step} subtasks={event.subtask}")
            return
        self.node.get_logger().info(
            f"subtask boundary: step={event.step} subtask={event.subtask} score={event.score:.3f} "
            f"level={event.level} detected_at={event.detected_at}{' (episode end)' if event.final else ''}"
        )

    def skipped(self, error: InvalidInput, by_segmenter: bool) -> None:
        """A skipped input, warned (throttled); a size that does not fit the checkpoint is one error
        line per size instead."""
        if not by_segmenter:
            self.warn_throttled(f"skipped input ({error.reason}): {error}")
        elif isinstance(error, WrongObservationLength):
            self._report_size_mismatch(error)
        else:
            self.warn_throttled(f"skipped observation ({error.reason}): {error}")

    def _report_size_mismatch(self, exc: WrongObservationLength) -> None:
        """One error line per observed size that does not fit the checkpoint (each such message is
        still skipped and counted as ``rejected_wrong_length``), naming where the size comes from."""
        if str(exc) in self._sizes_reported:
            return
        self._sizes_reported.add(str(exc))
        self.node.get_logger().error(
            f"{exc} from {self._source}: every such message is skipped (counted as rejected_wrong_length); "
            "publish what the model was trained on, or use a checkpoint trained on this robot")

    def warn_throttled(self, text: str, with_total: bool = True) -> None:
        now = time.monotonic()
        if now - self._last_warn >= float(self.values["warn_throttle"]):
            self._last_warn = now
            seg = self.stream.segmenter
            total = seg.rejected_total if seg else 0
            self.node.get_logger().warning(f"{text} [{total} rejected so far]" if with_total else text)

    def warning(self, text: str) -> None:
        self.node.get_logger().warning(text)

    # --- health ----------------------------------------------------------------------------------
    def counters(self, inputs: Mapping[str, int]) -> dict[str, int]:
        """Health counters (also on /diagnostics), the ``inputs``' own last: accepted steps, rejected inputs
        (total and by reason), episodes (that had a step), episode_starts (accepted start markers, ~/reset
        calls and clock restarts), episodes_ended (end markers, pauses and clock restarts that closed an
        episode), episode_gaps (pauses of ``episode_gap`` seen), markers (episode markers handled: every
        marker received is counted here or, when the middleware lost it, in markers_lost), messages_lost (all
        topics, reported by the middleware), messages_missed (input messages a publisher sent that the node
        never received: gaps in its sequence numbers, :mod:`ompn_ros.stream.delivery`), boundaries published,
        clock_jumps (input stamps back by more than ``clock_jump_back``), clock_steps (steps of the robot's
        header clock that cut nothing, docs/specs.md "Clocks"), clock_jumps_forward (``/clock``
        ahead by more than ``clock_jump_forward``), clock_stalls (``/clock`` stood still for ``clock_stall``),
        clock_negative (negative ``/clock`` times dropped), bad_end_markers, qos_incompatible (and
        duplicate_names on /diagnostics); with ``observation_spec`` also the assembler's ``obs.*`` counters
        (steps, kept, dropped by reason, rejected partner messages by topic and reason), ``obs_type_reports``
        (wrong advertised types seen) and ``obs_size_mismatch``; with ``idle_s`` ``idle_trimmed`` (idle
        observations in no episode), with ``joint_merge`` ``joint_missing`` (steps dropped for a joint without
        a recent value); with a model's ``still_tolerance`` ``still_observations`` (observations that moved
        nothing: not stepped); ``repeated_messages``: messages a driver sent twice, stepped once
        (:mod:`ompn_ros.data.cuts`)."""
        stream, seg = self.stream, self.stream.segmenter
        out = {"accepted": 0, "rejected": 0}
        if seg is not None:
            out.update(accepted=seg.accepted, rejected=seg.rejected_total)
        for key in EVENT_COUNTERS:
            out[key] = int(stream.events[key])
        if seg is not None:
            out.update({f"rejected_{k}": int(v) for k, v in seg.rejected.items()})
        out["repeated_messages"] = stream.repeats.total
        idle = stream.pauses.idle
        if idle is not None:
            out["idle_trimmed"] = idle.trimmed
        if seg is not None and seg.still_tolerance > 0:
            out["still_observations"] = int(stream.events["still_observations"])
        out.update(inputs)
        return out

    def publish_diagnostics(self, counters: dict[str, int], dropped: int, duplicates: int) -> None:
        """Publish ``counters`` on /diagnostics (silently skipped once the context is shutting down);
        ``dropped``: steps the assembler dropped, ``duplicates``: other nodes of this node's name."""
        pub = self.pubs.get("diagnostics")
        context = self.node.context
        if pub is None or not context.ok():
            return
        rejected = counters["rejected"] > 0 or dropped > 0
        counters["duplicate_names"] = duplicates
        message = "rejected input" if rejected else "ok"
        if duplicates:
            message = f"duplicate node name: {duplicates + 1} nodes publish this status"
        raw = encode_diagnostic_status(
            self.node.get_clock().now().nanoseconds, f"{self.node.get_fully_qualified_name()}: segmenter",
            message, counters, LEVEL_WARN if rejected or duplicates else LEVEL_OK,
        )  # fmt: skip
        try:
            pub.publish(raw)
        except Exception as exc:  # SIGINT tears the context down while the timer is due: not an error
            # (checked again here: the context may have gone between the check above and the call,
            # and then logging, which publishes to /rosout, would raise in its turn)
            if context.ok() and "context" not in str(exc):
                self.warn_throttled(f"/diagnostics not published: {exc}")
