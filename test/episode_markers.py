"""Episode markers as a sim sends them, for the node tests: one builder per form and one publisher.

A sim tells ``ompn_node`` where its episodes start and end with markers in two forms: the typed
``ompn_interfaces/EpisodeMarker`` on ``episode_marker``, and the deprecated ``DiagnosticArray`` (one
status named ``layout.EPISODE_STATUS_NAME``) on ``episode``.  :func:`marker` builds the deprecated form as
a message object (what an in-process test hands to the node's callback), :class:`MarkerPublisher`
publishes either form, or both of each marker, into a node's namespace.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ompn_ros import layout
from ompn_ros.data import messages as m

FORMS = ("typed", "legacy")


def marker(kind: str, **values: str) -> DiagnosticArray:
    """The deprecated form of a marker: ``kind`` 'start' or 'end', ``values`` its keys (``layout.KEY_*``)."""
    status = DiagnosticStatus(name=layout.EPISODE_STATUS_NAME, message=kind,
                              values=[KeyValue(key=k, value=v) for k, v in values.items()])  # fmt: skip
    return DiagnosticArray(status=[status])


class MarkerPublisher:
    """Publishes markers into namespace ``ns`` (``"/robot"``, or ``""`` for the root) from ``node``, in
    ``forms``: ``("legacy",)`` (DiagnosticArray on ``episode``, the default), ``("typed",)``
    (EpisodeMarker on ``episode_marker``) or both (each marker twice, as the sims send them for one
    release)."""

    def __init__(self, node: Any, ns: str, qos: Any, forms: tuple[str, ...] = ("legacy",)) -> None:
        unknown = set(forms) - set(FORMS)
        assert forms and not unknown, f"marker forms are {FORMS}, not {sorted(unknown)}"
        self.pubs: dict[str, Any] = {}
        if "typed" in forms:
            from ompn_interfaces.msg import EpisodeMarker

            self.pubs["typed"] = node.create_publisher(EpisodeMarker, f"{ns}/{layout.EPISODE_MARKER}", qos)
        if "legacy" in forms:
            self.pubs["legacy"] = node.create_publisher(DiagnosticArray, f"{ns}/{layout.EPISODE}", qos)

    def publish(self, kind: str, values: Mapping[str, object]) -> None:
        """One marker in every form, the typed one first (the codec's bytes, header stamp 0)."""
        if "typed" in self.pubs:
            self.pubs["typed"].publish(m.encode_typed_marker(kind, 0, values))
        if "legacy" in self.pubs:
            self.pubs["legacy"].publish(m.encode_episode_marker(kind, 0, values))

    def matched(self) -> bool:
        """Whether every form's publisher has a subscriber."""
        return all(pub.get_subscription_count() > 0 for pub in self.pubs.values())
