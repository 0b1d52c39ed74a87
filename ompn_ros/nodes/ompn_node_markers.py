"""``ompn_node``'s episode markers and sketch messages, each surviving any message.

:class:`NodeMarkers` is the part of the node's inputs (:mod:`ompn_ros.nodes.ompn_node_inputs`) that reads
the episode markers, typed (``ompn_interfaces/msg/EpisodeMarker`` on ``episode_marker``) and deprecated
(``diagnostic_msgs/DiagnosticArray`` on ``episode``, read for one release: one of a marker's two forms
is handled, :class:`MarkerTwins`), and the sketch messages, and gives them to the stream rule's markers
(:class:`~ompn_ros.stream.rule.EpisodeMarkers`).  Topics and QoS: the module docstring of
:mod:`ompn_ros.nodes.ompn_node`.
"""

from __future__ import annotations

from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import LifecycleNode
from std_msgs.msg import Int32MultiArray

from ompn_ros import layout
from ompn_ros.data.messages import parse_typed_marker
from ompn_ros.stream.rule import StreamRule
from ompn_ros.validate import InvalidInput, MalformedMessage

__all__ = ["MarkerTwins", "NodeMarkers"]


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


class NodeMarkers:
    """The callbacks of the marker and sketch topics; they feed ``stream`` while ``active()``.

    Args:
        node: the lifecycle node (its logger).
        stream: the stream rule the markers and sketches go to.
        active: whether the node's inputs are subscribed.
        reject: counts an input that cannot be used (:meth:`NodeInputs.reject`).
        flush: steps what the observation spec's assembler holds (it belongs to the episode before a
            marker).
        end_probe: ends the idle probe (``idle_speed: auto``): its observations are stepped.
    """

    def __init__(self, node: LifecycleNode, stream: StreamRule, active: Callable[[], bool],
                 reject: Callable[[InvalidInput], None], flush: Callable[[], None],
                 end_probe: Callable[[], None]) -> None:
        self.node, self.stream, self.active = node, stream, active
        self.reject, self.flush, self.end_probe = reject, flush, end_probe
        self.twins = MarkerTwins()  # a marker's typed and deprecated forms: one is handled

    def on_typed_marker(self, raw: bytes) -> None:
        try:
            kind, values = parse_typed_marker(raw)
        except Exception as exc:  # rosbags raises several types on bad CDR: counted, never fatal
            self.reject(MalformedMessage(f"undecodable EpisodeMarker ({len(raw)} bytes): {exc}"))
            return
        self._on_marker(True, kind, values)

    def on_episode(self, msg: DiagnosticArray) -> None:
        """The deprecated string-keyed marker (read for one release)."""
        for status in msg.status:
            if status.name == layout.EPISODE_STATUS_NAME:
                self._on_marker(False, status.message, {kv.key: kv.value for kv in status.values})

    def _on_marker(self, typed: bool, kind: str, values: dict[str, str]) -> None:
        if self.stream.segmenter is None or not self.active() or not self.twins.keep(typed, kind, values):
            return
        self.flush()  # held steps belong to the episode before the marker
        self.end_probe()
        if not self.twins.typed_seen and self.twins.deprecated_handled == 2:
            self.node.get_logger().warning(
                f"episode markers on '{layout.EPISODE}' (diagnostic_msgs/DiagnosticArray) are deprecated, "
                f"read for one release: publish ompn_interfaces/msg/EpisodeMarker on "
                f"'{layout.EPISODE_MARKER}'")
        self.stream.markers.marker(kind, values)

    def on_sketch(self, msg: Int32MultiArray) -> None:
        if self.stream.segmenter is not None and self.active() and len(msg.data) > 0:
            self.end_probe()
            self.stream.markers.sketch_message(msg.data)
