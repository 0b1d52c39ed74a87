"""``ompn_node``'s inputs: the subscriptions and their callbacks, each surviving any message.

:class:`NodeInputs` turns ROS messages into the stream rule's plain inputs (:mod:`ompn_ros.stream.rule`:
an observation and its stamp, a marker's text, a sketch) and reports what cannot be used.  Every
input topic (those of ``obs_qos``) also counts the messages its publisher sent that never reached a
callback (an input queue overwritten while the node was busy), from the gaps in the publication
sequence numbers of the message info (``messages_missed``, :mod:`ompn_ros.stream.delivery`).  Topics,
stamps and QoS: the module docstring of :mod:`ompn_ros.nodes.ompn_node`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
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
from ompn_ros.data.messages import StampRangeError, join_stamp, parse_float32_array, parse_typed_marker
from ompn_ros.data.obs import Decided, Drop
from ompn_ros.nodes.ompn_node_idle import IdleProbe
from ompn_ros.nodes.ompn_node_obs import AssembledInput, JointInput, drop_line
from ompn_ros.nodes.ompn_node_outputs import NodePublishers
from ompn_ros.nodes.ompn_node_params import input_qos
from ompn_ros.stream.delivery import SequenceGaps
from ompn_ros.stream.rule import classify_stamp
from ompn_ros.validate import BadStamp, FutureStamp, InvalidInput, MalformedMessage

MARKER_QUEUE = 5_000  # depth of the marker (and sketch) topics, KEEP_ALL: a full queue holds publishers back
MARKER_TOPICS = (layout.EPISODE_MARKER, layout.EPISODE)



class MarkerTwins:
    """Keeps one of the two forms of one marker: the sims publish each marker typed (``episode_marker``)
    and, for one release, as the deprecated ``DiagnosticArray`` (``episode``); DDS may deliver either
    first.  A marker equal to the one just handled but of the other form is its twin and is dropped."""

    def __init__(self) -> None:
        self._last: tuple[bool, tuple[str, tuple[tuple[str, str], ...]]] | None = None
        self.typed_seen = False
        self.deprecated_handled = 0

    def keep(self, typed: bool, kind: str, values: dict[str, str]) -> bool:
        """Whether to handle this marker (``typed``: from ``episode_marker``)."""
        identity = (kind, tuple(sorted(values.items())))
        self.typed_seen = self.typed_seen or typed
        if self._last is not None and self._last[1] == identity and self._last[0] != typed:
            self._last = None
            return False
        self._last = (typed, identity)
        self.deprecated_handled += not typed
        return True


class NodeInputs:
    """The node's subscriptions and their callbacks; they feed :attr:`stream` while :attr:`active`.

    Args:
        node: the lifecycle node that owns the subscriptions and timers (and logs).
        values: the node's parameter values (the same dict, kept current by the node).
        outputs: the node's publishers: their stream rule is fed, their warnings are used.
    """

    def __init__(self, node: LifecycleNode, values: dict[str, Any], outputs: NodePublishers,
                 idle_found: Callable[[IdleSpeed, int], None]) -> None:
        self.node, self.values, self.outputs = node, values, outputs
        self.stream = outputs.stream
        self.probe: IdleProbe | None = None  # idle_speed auto measured on the stream: observations held
        self._idle_found = idle_found  # the node's: the probe derived the idle speed (and from how many)
        self.active = False  # subscribed (between subscribe() and unsubscribe())
        self.assembled: AssembledInput | None = None  # observation_spec input (None: single topic)
        self.joints: JointInput | None = None  # obs_source 'joint_state'
        self._subs: list[Any] = []
        self._graph_timer: Any = None
        self._hold_timer: Any = None
        self._missed_warned: set[str] = set()  # input topics whose first unreceived messages were warned
        self._lost_warned: set[str] = set()  # topics whose first middleware loss was warned
        self._twins = MarkerTwins()  # a marker's typed and deprecated forms: one is handled
        # the steady clock beside the node's wall clock: a step of the PC's clock is no pause or restart
        # for observations stamped at reception (None under use_sim_time: a sim's clock going back restarts)
        self.steady: Callable[[], int] | None = None

    def configure(self, assembled: AssembledInput | None, joints: JointInput | None) -> None:
        """The input of the next activation (``None``, ``None``: the single topic of ``obs_source``)."""
        self.assembled, self.joints = assembled, joints

    def source(self) -> str:
        """Where the observations come from, as an error line names it."""
        if self.assembled is not None:
            return f"observation_spec (step topic {self.assembled.spec.step_topic})"
        if self.values["obs_source"] == "joint_state":
            fields = list(self.values["joint_fields"])
            return f"'{layout.JOINT_STATES}' fields {fields} (obs_source=joint_state)"
        return f"'{layout.OBSERVATION}'"

    def counters(self) -> dict[str, int]:
        """The input's own counters (:meth:`NodePublishers.counters`)."""
        out: dict[str, int] = {}
        if self.joints is not None and self.joints.merger is not None:
            out["joint_missing"] = self.joints.missing
        if self.assembled is not None:
            out.update(self.assembled.counters())
            out["obs_type_reports"] = self.assembled.type_reports
            out["obs_size_mismatch"] = int(self.stream.events["obs_size_mismatch"])
        return out

    @property
    def dropped_total(self) -> int:
        """Steps the assembler dropped (0 without ``observation_spec``)."""
        return self.assembled.dropped_total if self.assembled is not None else 0

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
        self._subscribe(EpisodeMarker, layout.EPISODE_MARKER, self._on_typed_marker, markers, None, raw=True)
        self._subscribe(DiagnosticArray, layout.EPISODE, self.on_episode, markers, None)  # deprecated
        self._subscribe(Int32MultiArray, layout.SKETCH, self.on_sketch, markers, None)
        if self.assembled is not None:
            self._subscribe_spec(self.assembled, inputs)
        elif self.values["obs_source"] == "joint_state":
            self._subscribe(JointState, layout.JOINT_STATES, self.on_joint_state, inputs, "obs_qos")
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
        for timer in (self._graph_timer, self._hold_timer):
            if timer is not None:
                self.node.destroy_timer(timer)
        self._graph_timer = self._hold_timer = None
        if self.assembled is not None:
            self.assembled.asm.reset()

    def _subscribe_spec(self, assembled: AssembledInput, qos: QoSProfile) -> None:
        """One raw subscription per spec topic, the publishers' types checked ~1/s.  Partners first: when
        a partner and a step message are both ready, a wait-set executor serves them in creation order,
        and the partner message, published first, is then fed first (as it arrived)."""
        spec = assembled.spec
        for topic in (*spec.partner_topics, spec.step_topic):
            callback = self.on_spec_step if topic == spec.step_topic else self.partner_callback(topic)
            msg_class = assembled.classes[topic]
            self._subscribe(msg_class, topic, callback, qos, "obs_qos", raw=True)
        self._graph_timer = self.node.create_timer(1.0, self.check_topic_types)
        self.check_topic_types()
        if assembled.asm.waited_topics:  # held steps are released on every message, and by this timer
            period = max(0.005, spec.wait_s / 2)
            self._hold_timer = self.node.create_timer(period, lambda: self.release_held(None))

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
            self._reject(MalformedMessage(f"undecodable Float32MultiArray ({len(raw)} bytes): {exc}"))
            return
        self.process_observation(data, stamp_ns, now_ns, steady_ns)

    def on_spec_step(self, raw: bytes) -> None:
        """A step-topic message: held by the assembler (receive time = the node's clock, strictly
        increasing) until its partners caught up or ``wait_s`` passed, then stepped like any
        observation; a dropped step is counted by reason and warned (throttled)."""
        assembled = self.assembled
        if assembled is None or self.stream.segmenter is None or not self.active:
            return
        now = self.node.get_clock().now().nanoseconds
        receive = self.stream.receive_stamp(now)
        step_topic = assembled.spec.step_topic
        if self.stream.repeats.seen(step_topic, assembled.spec.type_of(step_topic), receive, raw):
            return
        try:
            assembled.asm.hold(receive, raw)
        except Exception as exc:  # the assembler counts what it knows; anything else is malformed input
            self._reject(MalformedMessage(f"step message not assembled: {type(exc).__name__}: {exc}"))
            return
        self.release_held(now)

    def release_held(self, now_ns: int | None, flush: bool = False) -> None:
        """Step the held steps the assembler can decide now (all of them with ``flush``), in order."""
        assembled = self.assembled
        if assembled is None or not assembled.asm.held:
            return
        now = self.node.get_clock().now().nanoseconds if now_ns is None else now_ns
        try:
            decided = assembled.asm.release(now, flush)
        except Exception as exc:  # never fatal: counted as malformed input, warned
            self._reject(MalformedMessage(f"held steps not assembled: {type(exc).__name__}: {exc}"))
            return
        self.step_decided(assembled, decided)

    def step_decided(self, assembled: AssembledInput, decided: list[Decided]) -> None:
        for d in decided:
            if isinstance(d.result, Drop):
                self.outputs.warn_throttled(drop_line(d.result, assembled.dropped_total), with_total=False)
                continue
            problem = assembled.first_size_problem(d.result)
            if problem is not None:
                self.stream.events["obs_size_mismatch"] += 1
                self.node.get_logger().error(problem)
            # judged at the step's arrival, not at its release: a step the assembler held for a lagging
            # partner is no clock step (docs/specs.md, "Clocks")
            self.process_observation(d.result, d.stamp_ns, d.receive_ns)

    def partner_callback(self, topic: str) -> Any:
        def on_partner(raw: bytes) -> None:
            assembled = self.assembled
            if assembled is None or not self.active:
                return
            now = self.node.get_clock().now().nanoseconds
            if self.stream.repeats.seen(topic, assembled.spec.type_of(topic), now, raw):
                return
            try:
                rejected = assembled.asm.offer(topic, now, raw)
            except Exception as exc:  # never fatal: counted as a node event, warned
                self.stream.events["obs_partner_errors"] += 1
                self.outputs.warn_throttled(f"message on '{topic}' not used: {type(exc).__name__}: {exc}")
                return
            if rejected is not None:
                self.outputs.warn_throttled(f"message rejected: {rejected}", with_total=False)
            self.release_held(now)

        return on_partner

    def check_topic_types(self) -> None:
        """Compare the spec topics' advertised types with the spec (timer, ~1 s): one line per change."""
        if self.assembled is None:
            return
        try:
            graph = {t: [p.topic_type for p in self.node.get_publishers_info_by_topic(t)]
                     for t in self.assembled.spec.topics}
        except Exception as exc:  # the graph may be unavailable while the context shuts down
            if "context" not in str(exc):
                self.outputs.warn_throttled(f"ROS graph not readable: {exc}")
            return
        for line in self.assembled.check_graph(graph):
            if "expects" in line:
                self.node.get_logger().error(line)
            else:
                self.node.get_logger().info(line)

    def on_joint_state(self, msg: JointState) -> None:
        try:
            stamp = join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec)
        except StampRangeError as exc:
            self._reject(BadStamp(str(exc)))
            return
        fields = {f: np.asarray(getattr(msg, f)) for f in layout.JOINT_FIELDS}
        payload = "\0".join(msg.name).encode() + b"".join(v.tobytes() + b"|" for v in fields.values())
        if self.stream.repeats.seen_sample(layout.JOINT_STATES, stamp, payload):
            return  # the same sample sent twice (same header stamp and data): one step
        joints = self.joints or JointInput(self.values["joint_fields"], None, None)
        if joints.merger is not None and self._merge_refuses(stamp):
            return
        got = joints.observation(stamp, msg.name, fields)
        if got is None:  # joint_merge: another publisher's message, or a step lacking a joint (counted)
            silent = joints.silence_line()
            if silent is not None:
                self.node.get_logger().warning(silent)
            return
        if isinstance(got, str):
            self._reject(MalformedMessage(got))
            return
        self.outputs.frame_id = msg.header.frame_id
        with np.errstate(over="ignore"):  # beyond float32 -> inf, which the segmenter rejects
            self.process_observation(got.astype(np.float32), stamp)

    def _merge_refuses(self, stamp_ns: int) -> bool:
        """``joint_merge``: a message of any publisher stamped more than ``max_stamp_lead`` ahead of the
        node's clock is rejected before it is merged (``future_stamp``), as a step would be: its values
        would otherwise look fresh to every step until the clock caught up."""
        limits = self.stream.limits
        if limits.max_lead_ns <= 0:
            return False
        now = self.node.get_clock().now().nanoseconds
        if classify_stamp(stamp_ns, None, now, jump_back_ns=0, max_lead_ns=limits.max_lead_ns) != "future":
            return False
        self._reject(FutureStamp(f"JointState stamped {stamp_ns} ns is more than max_stamp_lead="
                                 f"{limits.max_stamp_lead} s ahead of the node's clock: not merged"))
        return True

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
        assembled = self.assembled
        if assembled is not None:
            self.step_decided(assembled, assembled.asm.reset())
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

    def _reject(self, error: InvalidInput) -> None:
        if self.stream.segmenter is not None and self.active:
            self.stream.reject(error)

    # --- markers and sketches --------------------------------------------------------------------
    def _on_typed_marker(self, raw: bytes) -> None:
        try:
            kind, values = parse_typed_marker(raw)
        except Exception as exc:  # rosbags raises several types on bad CDR: counted, never fatal
            self._reject(MalformedMessage(f"undecodable EpisodeMarker ({len(raw)} bytes): {exc}"))
            return
        self._on_marker(True, kind, values)

    def on_episode(self, msg: DiagnosticArray) -> None:
        """The deprecated string-keyed marker (read for one release)."""
        for status in msg.status:
            if status.name == layout.EPISODE_STATUS_NAME:
                self._on_marker(False, status.message, {kv.key: kv.value for kv in status.values})

    def _on_marker(self, typed: bool, kind: str, values: dict[str, str]) -> None:
        if self.stream.segmenter is None or not self.active or not self._twins.keep(typed, kind, values):
            return
        self.release_held(None, flush=True)  # held steps belong to the episode before the marker
        self.end_probe()
        if not self._twins.typed_seen and self._twins.deprecated_handled == 2:
            self.node.get_logger().warning(
                f"episode markers on '{layout.EPISODE}' (diagnostic_msgs/DiagnosticArray) are deprecated, "
                f"read for one release: publish ompn_interfaces/msg/EpisodeMarker on "
                f"'{layout.EPISODE_MARKER}'")
        self.stream.marker(kind, values)

    def on_sketch(self, msg: Int32MultiArray) -> None:
        if self.stream.segmenter is not None and self.active and len(msg.data) > 0:
            self.end_probe()
            self.stream.sketch_message(msg.data)


def _matched(gaps: SequenceGaps) -> Any:
    """The ``matched`` event callback that tells ``gaps`` how many publishers the topic has now."""

    def on_matched(info: Any) -> None:
        gaps.publishers(int(info.current_count))

    return on_matched
