"""``ompn_node``'s multi-topic input (the ``observation_spec`` parameter), surviving any message.

:class:`SpecInput` is the part of the node's inputs (:mod:`ompn_ros.nodes.ompn_node_inputs`) that feeds
the spec's topics to the assembler (:class:`~ompn_ros.nodes.ompn_node_obs.AssembledInput`): a message of
the step topic is held until its partners caught up or ``wait_s`` passed, then stepped like any
observation; a dropped step is counted by reason and warned (throttled); the publishers' types are
checked against the spec about once a second.  The rule: :mod:`ompn_ros.nodes.ompn_node_obs`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.lifecycle import LifecycleNode
from rclpy.qos import QoSProfile

from ompn_ros.data.obs import Decided, Drop
from ompn_ros.nodes.ompn_node_obs import AssembledInput, drop_line
from ompn_ros.nodes.ompn_node_outputs import NodePublishers
from ompn_ros.validate import InvalidInput, MalformedMessage

__all__ = ["SpecInput"]

Subscribe = Callable[[Any, str, Any, QoSProfile], None]
"""The node's subscription of ``callback`` to raw messages of ``topic`` (message class, topic, callback,
QoS), counted as an input topic (:class:`~ompn_ros.nodes.ompn_node_inputs.NodeInputs`)."""


class SpecInput:
    """The callbacks and timers of the ``observation_spec`` topics; they feed ``step`` while ``active()``.

    Args:
        node: the lifecycle node (its clock, logger, timers and the ROS graph).
        outputs: the node's publishers: the stream rule they publish for, their throttled warnings.
        active: whether the node's inputs are subscribed.
        step: steps one observation with its stamp and arrival time (:meth:`NodeInputs.process_observation`).
        reject: counts an input that cannot be used (:meth:`NodeInputs.reject`).
    """

    def __init__(self, node: LifecycleNode, outputs: NodePublishers, active: Callable[[], bool],
                 step: Callable[[Any, int | None, int | None], None],
                 reject: Callable[[InvalidInput], None]) -> None:
        self.node, self.outputs, self.stream = node, outputs, outputs.stream
        self.active, self.step, self.reject = active, step, reject
        self.assembled: AssembledInput | None = None  # configured (None: a single-topic input)
        self._graph_timer: Any = None
        self._hold_timer: Any = None

    def subscribe(self, subscribe: Subscribe, qos: QoSProfile) -> None:
        """One raw subscription per spec topic, the publishers' types checked ~1/s.  Partners first: when
        a partner and a step message are both ready, a wait-set executor serves them in creation order,
        and the partner message, published first, is then fed first (as it arrived)."""
        assembled = self.assembled
        assert assembled is not None
        spec = assembled.spec
        for topic in (*spec.partner_topics, spec.step_topic):
            callback = self.on_step if topic == spec.step_topic else self.partner_callback(topic)
            subscribe(assembled.classes[topic], topic, callback, qos)
        self._graph_timer = self.node.create_timer(1.0, self.check_topic_types)
        self.check_topic_types()
        if assembled.asm.waited_topics:  # held steps are released on every message, and by this timer
            period = max(0.005, spec.wait_s / 2)
            self._hold_timer = self.node.create_timer(period, lambda: self.release_held(None))

    def unsubscribe(self) -> None:
        """Destroy the timers (the node destroys the subscriptions); held steps are decided (counted) but
        not stepped."""
        for timer in (self._graph_timer, self._hold_timer):
            if timer is not None:
                self.node.destroy_timer(timer)
        self._graph_timer = self._hold_timer = None
        if self.assembled is not None:
            self.assembled.asm.reset()

    def on_step(self, raw: bytes) -> None:
        """A step-topic message: held by the assembler (receive time = the node's clock, strictly
        increasing) until its partners caught up or ``wait_s`` passed, then stepped like any
        observation; a dropped step is counted by reason and warned (throttled)."""
        assembled = self.assembled
        if assembled is None or self.stream.segmenter is None or not self.active():
            return
        now = self.node.get_clock().now().nanoseconds
        receive = self.stream.receive_stamp(now)
        step_topic = assembled.spec.step_topic
        if self.stream.repeats.seen(step_topic, assembled.spec.type_of(step_topic), receive, raw):
            return
        try:
            assembled.asm.hold(receive, raw)
        except Exception as exc:  # the assembler counts what it knows; anything else is malformed input
            self.reject(MalformedMessage(f"step message not assembled: {type(exc).__name__}: {exc}"))
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
            self.reject(MalformedMessage(f"held steps not assembled: {type(exc).__name__}: {exc}"))
            return
        self.step_decided(assembled, decided)

    def release_all(self) -> None:
        """Before ``~/reset``: every held step is stepped, in order, and the partners are forgotten."""
        assembled = self.assembled
        if assembled is not None:
            self.step_decided(assembled, assembled.asm.reset())

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
            self.step(d.result, d.stamp_ns, d.receive_ns)

    def partner_callback(self, topic: str) -> Any:
        def on_partner(raw: bytes) -> None:
            assembled = self.assembled
            if assembled is None or not self.active():
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
