"""``ompn_node``'s inputs: the subscriptions and their callbacks, each surviving any message.

:class:`NodeInputs` turns ROS messages into the stream rule's plain inputs (:mod:`ompn_ros.stream.rule`:
an observation and its stamp, a marker's text, a sketch) and reports what cannot be used.  It owns
the parts for each kind of input: :attr:`NodeInputs.markers` (episode markers and sketches,
:mod:`ompn_ros.nodes.ompn_node_markers`), :attr:`NodeInputs.joint_states` (``obs_source: joint_state``,
:mod:`ompn_ros.nodes.ompn_node_joints`) and :attr:`NodeInputs.spec` (``observation_spec``,
:mod:`ompn_ros.nodes.ompn_node_spec`); the array input is its own.  Every input topic (those of
``obs_qos``) also counts the messages its publisher sent that never reached a callback (an input queue
overwritten while the node was busy), from the gaps in the publication sequence numbers of the message
info (``messages_missed``, :mod:`ompn_ros.stream.delivery`).  Topics, stamps and QoS: the module
docstring of :mod:`ompn_ros.nodes.ompn_node`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray, Int32MultiArray

from ompn_interfaces.msg import EpisodeMarker
from ompn_ros import layout
from ompn_ros.data.cuts import IdleSpeed
from ompn_ros.data.messages import parse_float32_array
from ompn_ros.nodes.ompn_node_idle import IdleProbe
from ompn_ros.nodes.ompn_node_joints import JointStates
from ompn_ros.nodes.ompn_node_markers import NodeMarkers
from ompn_ros.nodes.ompn_node_obs import AssembledInput, JointInput
from ompn_ros.nodes.ompn_node_outputs import NodePublishers
from ompn_ros.nodes.ompn_node_params import input_qos
from ompn_ros.nodes.ompn_node_spec import SpecInput
from ompn_ros.stream.delivery import SequenceGaps
from ompn_ros.validate import InvalidInput, MalformedMessage

MARKER_QUEUE = 5_000  # depth of the marker (and sketch) topics, KEEP_ALL: a full queue holds publishers back
MARKER_TOPICS = (layout.EPISODE_MARKER, layout.EPISODE)


class NodeInputs:
    """The node's subscriptions and their callbacks; they feed :attr:`stream` while :attr:`active`.

    It owns a part per kind of input: :attr:`markers` (``NodeMarkers``), :attr:`joint_states`
    (``JointStates``) and :attr:`spec` (``SpecInput``); their observations come to
    :meth:`process_observation`, their unusable messages to :meth:`reject`.

    Args:
        node: the lifecycle node that owns the subscriptions and timers (and logs).
        values: the node's parameter values (the same dict, kept current by the node).
        outputs: the node's publishers: their stream rule is fed, their warnings are used.
        idle_found: the node's: the idle probe derived the idle speed (and from how many observations).
    """

    def __init__(self, node: LifecycleNode, values: dict[str, Any], outputs: NodePublishers,
                 idle_found: Callable[[IdleSpeed, int], None]) -> None:
        self.node, self.values, self.outputs = node, values, outputs
        self.stream = outputs.stream
        self.probe: IdleProbe | None = None  # idle_speed auto measured on the stream: observations held
        self._idle_found = idle_found  # the node's: the probe derived the idle speed (and from how many)
        self.active = False  # subscribed (between subscribe() and unsubscribe())
        self._subs: list[Any] = []
        self._missed_warned: set[str] = set()  # input topics whose first unreceived messages were warned
        self._lost_warned: set[str] = set()  # topics whose first middleware loss was warned
        active = self.is_active
        self.spec = SpecInput(node, outputs, active, self.process_observation, self.reject)
        self.joint_states = JointStates(node, values, outputs, self.process_observation, self.reject)
        self.markers = NodeMarkers(node, self.stream, active, self.reject,
                                   lambda: self.spec.release_held(None, flush=True), self.end_probe)
        # the steady clock beside the node's wall clock: a step of the PC's clock is no pause or restart
        # for observations stamped at reception (None under use_sim_time: a sim's clock going back restarts)
        self.steady: Callable[[], int] | None = None

    def configure(self, assembled: AssembledInput | None, joints: JointInput | None) -> None:
        """The input of the next activation (``None``, ``None``: the single topic of ``obs_source``)."""
        self.spec.assembled, self.joint_states.joints = assembled, joints

    def is_active(self) -> bool:
        """Whether the inputs are subscribed (:attr:`active`), for the parts."""
        return self.active

    def source(self) -> str:
        """Where the observations come from, as an error line names it."""
        assembled = self.spec.assembled
        if assembled is not None:
            return f"observation_spec (step topic {assembled.spec.step_topic})"
        if self.values["obs_source"] == "joint_state":
            fields = list(self.values["joint_fields"])
            return f"'{layout.JOINT_STATES}' fields {fields} (obs_source=joint_state)"
        return f"'{layout.OBSERVATION}'"

    def counters(self) -> dict[str, int]:
        """The input's own counters (:meth:`NodePublishers.counters`)."""
        out: dict[str, int] = {}
        joints, assembled = self.joint_states.joints, self.spec.assembled
        if joints is not None and joints.merger is not None:
            out["joint_missing"] = joints.missing
        if assembled is not None:
            out.update(assembled.counters())
            out["obs_type_reports"] = assembled.type_reports
            out["obs_size_mismatch"] = int(self.stream.events["obs_size_mismatch"])
        return out

    @property
    def dropped_total(self) -> int:
        """Steps the assembler dropped (0 without ``observation_spec``)."""
        assembled = self.spec.assembled
        return assembled.dropped_total if assembled is not None else 0

    def subscribe(self, probe: IdleProbe | None = None) -> None:
        """The subscriptions of the configured input (on activation); active from then on, the
        observations held by ``probe`` until it measured the idle speed."""
        self.probe = probe
        inputs = input_qos(str(self.values["obs_qos"]), int(self.values["qos_depth"]))
        # KEEP_ALL: a full queue refuses new markers, and the reliable publisher resends them once the
        # node has read some, rather than the queue overwriting unread ones; what the middleware still
        # loses (a best-effort or shallow publisher) is counted (markers_lost)
        markers = QoSProfile(
            depth=MARKER_QUEUE, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL
        )
        # Markers first: when a marker and an observation are both ready, the executor serves the
        # subscriptions in creation order, so the 'start' reset precedes the episode's first step.
        self._subscribe(EpisodeMarker, layout.EPISODE_MARKER, self.markers.on_typed_marker, markers, None,
                        raw=True)
        self._subscribe(DiagnosticArray, layout.EPISODE, self.markers.on_episode, markers, None)  # deprecated
        self._subscribe(Int32MultiArray, layout.SKETCH, self.markers.on_sketch, markers, None)
        if self.spec.assembled is not None:
            self.spec.subscribe(self._subscribe_spec_topic, inputs)
        elif self.values["obs_source"] == "joint_state":
            joints = self.joint_states.on_joint_state
            self._subscribe(JointState, layout.JOINT_STATES, joints, inputs, "obs_qos")
        else:  # raw CDR: the float32 data is read in place, no message object is built
            info = self.uses_message_info
            callback = self._on_array_info if info else self.on_array
            self._subscribe(Float32MultiArray, layout.OBSERVATION, callback, inputs, "obs_qos", raw=True,
                            with_info=info)
        self.active = True

    def unsubscribe(self) -> None:
        """Destroy the subscriptions and timers (deactivate, cleanup, shutdown); held steps are decided
        (counted) but not stepped."""
        self.active = False
        self.probe = None  # what it held is not stepped (inactive); the next activation measures again
        for sub in self._subs:
            self.node.destroy_subscription(sub)
        self._subs = []
        self.spec.unsubscribe()

    def _subscribe_spec_topic(self, msg_type: Any, topic: str, callback: Any, qos: QoSProfile) -> None:
        self._subscribe(msg_type, topic, callback, qos, "obs_qos", raw=True)

    def _subscribe(
        self, msg_type: Any, topic: str, callback: Any, qos: QoSProfile, param: str | None, raw: bool = False,
        with_info: bool = False,
    ) -> None:
        """Subscribe ``callback`` (``with_info``: it takes the message info too).  The input topics (those
        of ``obs_qos``) count the samples they never received (:meth:`_counted`)."""
        lost = ("messages_lost", "markers_lost") if topic in MARKER_TOPICS else ("messages_lost",)
        gaps = SequenceGaps() if param == "obs_qos" else None
        events = SubscriptionEventCallbacks(
            incompatible_qos=lambda info: self.outputs.qos_mismatch(topic, param, info),
            message_lost=lambda info: self._count_lost(lost, topic, info),
            matched=None if gaps is None else _matched(gaps),
        )
        handler = callback if gaps is None else self._counted(topic, gaps, callback, with_info)
        sub = self.node.create_subscription(msg_type, topic, handler, qos, raw=raw, event_callbacks=events)
        if gaps is not None:
            # The message info of every sample, with either executor: rclpy's single-threaded one then
            # calls handler(message, info), the EventsExecutor handler((message, info)).
            sub._callback_type = Subscription.CallbackType.WithMessageInfo
        self._subs.append(sub)

    def _counted(self, topic: str, gaps: SequenceGaps, callback: Any, with_info: bool) -> Any:
        """``callback`` behind the gap count of ``topic`` (:mod:`ompn_ros.stream.delivery`)."""

        def on_message(message: Any, info: Any = None) -> None:
            if info is None:  # the EventsExecutor: one (message, info) argument
                message, info = message
            missed = gaps.seen(info.get("publication_sequence_number", 0))
            if missed:
                self._count_missed(topic, missed)
            if with_info:
                callback(message, info)
            else:
                callback(message)

        return on_message

    def _count_missed(self, topic: str, missed: int) -> None:
        """Samples of ``topic`` sent and never received: counted (``messages_missed``), warned the first
        time per topic."""
        self.stream.events["messages_missed"] += missed
        if topic not in self._missed_warned:
            self._missed_warned.add(topic)
            self.node.get_logger().warning(
                f"{missed} message(s) on '{topic}' were sent and never received (a gap in the publisher's "
                f"sequence numbers): the input queue (qos_depth={self.values['qos_depth']}) overflowed while "
                "the node was busy, or the transport lost them; counted as messages_missed on /diagnostics. "
                "Raise qos_depth, or publish more slowly")

    def _count_lost(self, counters: tuple[str, ...], topic: str, info: Any) -> None:
        """Messages the middleware reports lost (rmw's ``message_lost`` event): counted, warned once
        per topic."""
        self.stream.events.update(dict.fromkeys(counters, info.total_count_change))
        if topic not in self._lost_warned:
            self._lost_warned.add(topic)
            self.node.get_logger().warning(
                f"the middleware lost {info.total_count} message(s) on '{topic}' before the node received "
                "them; counted as messages_lost on /diagnostics")

    @property
    def uses_message_info(self) -> bool:
        """Array input takes its stamp from the DDS source timestamp (needs message info, wall time)."""
        return (
            self.values["obs_source"] == "array"
            and self.values["executor"] != "events"
            and not self.node.get_parameter("use_sim_time").value
        )

    # --- observations ----------------------------------------------------------------------------
    def _on_array_info(self, raw: bytes, info: dict[str, Any]) -> None:
        self.on_raw_array(raw, int(info["source_timestamp"]))

    def on_array(self, raw: bytes) -> None:
        # Without message info, stamp with the node's clock at reception (the stream rule's receive time),
        # judged against the steady clock (docs/specs.md, "Clocks")
        now = self.node.get_clock().now().nanoseconds
        steady = None if self.steady is None else self.steady()
        self.on_raw_array(raw, self.stream.receive_stamp(now), now, steady)

    def on_raw_array(self, raw: bytes, stamp_ns: int, now_ns: int | None = None,
                     steady_ns: int | None = None) -> None:
        if self.stream.repeats.seen(layout.OBSERVATION, layout.FLOAT32_ARRAY, stamp_ns, raw):
            return  # the same message sent twice: one step
        try:
            data = parse_float32_array(raw)
        except Exception as exc:  # rosbags raises several types on bad CDR: counted, never fatal
            self.reject(MalformedMessage(f"undecodable Float32MultiArray ({len(raw)} bytes): {exc}"))
            return
        self.process_observation(data, stamp_ns, now_ns, steady_ns)

    def process_observation(self, data: Any, stamp_ns: int | None, now_ns: int | None = None,
                            against_ns: int | None = None) -> None:
        """Step the segmenter on one observation and publish its outputs (or count a rejection).

        ``now_ns``: the node's clock at reception when the caller read it already; ``against_ns``: the
        clock its stamp's steps are judged against (:meth:`StreamRule.observe`)."""
        if self.stream.segmenter is not None and self.active:
            if self.probe is not None and stamp_ns is not None:
                if self.probe.hold(data, stamp_ns, now_ns):
                    self.end_probe()
                return
            self.stream.observe(data, stamp_ns, now_ns, against_ns)

    def release_all(self) -> None:
        """Before ``~/reset``: the steps the assembler and the idle probe hold are stepped, in order."""
        self.spec.release_all()
        self.end_probe()

    def end_probe(self) -> None:
        """``idle_speed: auto`` measured on the stream: derive it from the held observations (all there
        are: an episode marker or ``~/reset`` ends the probe early), then step them in order."""
        probe, self.probe = self.probe, None
        if probe is None:
            return
        self._idle_found(probe.derive(), len(probe.held))
        for data, stamp_ns, now_ns in probe.held:
            self.stream.observe(data, stamp_ns, now_ns)

    def reject(self, error: InvalidInput) -> None:
        """Count an input that cannot be used (while a segmenter is loaded and the inputs are active)."""
        if self.stream.segmenter is not None and self.active:
            self.stream.reject(error)


def _matched(gaps: SequenceGaps) -> Any:
    """The ``matched`` event callback that tells ``gaps`` how many publishers the topic has now."""

    def on_matched(info: Any) -> None:
        gaps.publishers(int(info.current_count))

    return on_matched
