"""ompn_node on typed episode markers, and on a sim's two forms of each marker (counted once).

A fake sim publishes Dial-sized observations with every marker twice: as
``ompn_interfaces/EpisodeMarker`` on ``episode_marker`` and as the deprecated ``DiagnosticArray`` on
``episode`` (what the sims publish for one release), or typed only.  The node must start and end each
episode once: its ``markers`` counter counts each marker once and each episode ends with one final
boundary.  The node runs as a process; it needs an ``ompn_interfaces`` built with EpisodeMarker.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
if "EpisodeMarker" not in pytest.importorskip("ompn_interfaces.msg").__dict__:
    pytest.skip("ompn_interfaces was built before EpisodeMarker: rebuild it (build_venv.py)",
                allow_module_level=True)

from episode_markers import MarkerPublisher  # noqa: E402
from node_process import NodeProcess, Peer  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_interfaces.msg import SubtaskBoundary  # noqa: E402
from ompn_ros import layout  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
FORMS = {"both": ("typed", "legacy"), "typed": ("typed",)}


@pytest.mark.parametrize("forms", ["both", "typed"])
def test_node_starts_and_ends_each_episode_once(ros_env: dict[str, str], forms: str) -> None:
    proc = NodeProcess(ros_env, "domain:=dial", "diagnostics_period:=0.1", ns=f"/mk_{os.getpid()}_{forms}")
    with proc, Peer(proc, name="fake_sim") as peer:
        obs_pub = peer.node.create_publisher(Float32MultiArray, proc.topic(layout.OBSERVATION), RELIABLE)
        markers = MarkerPublisher(peer.node, proc.ns or "", RELIABLE, FORMS[forms])
        events: list[SubtaskBoundary] = []
        boundary = proc.topic("ompn_node/boundary")
        peer.node.create_subscription(SubtaskBoundary, boundary, events.append, EVENTS)
        diags = peer.statuses(proc.status_name)
        assert peer.pump(lambda: bool(diags) and obs_pub.get_subscription_count() > 0 and markers.matched(),
                         60), "ompn_node did not come up"
        rng = np.random.default_rng(0)
        for episode in range(2):
            markers.publish(layout.EPISODE_START, m.start_marker_values(episode, "dial", episode, None))
            assert peer.pump(lambda e=episode: int(diags[-1]["episode_starts"]) >= e + 1, 10)
            for _ in range(12):
                obs_pub.publish(Float32MultiArray(data=rng.normal(size=39).astype(np.float32).tolist()))
                peer.pump(lambda: False, 0.02)
            markers.publish(layout.EPISODE_END, m.end_marker_values(episode, "dial", episode, 11, True))
            assert peer.pump(lambda e=episode: sum(ev.final for ev in events) == e + 1, 10), events
        peer.pump(lambda: False, 1.0)  # late twins would arrive now
        last = diags[-1]
        counts = [int(last["markers"]), int(last["episode_starts"]), int(last["episodes_ended"]),
                  sum(ev.final for ev in events)]
    assert counts == [4, 2, 2, 2], counts  # markers, episode starts, episodes ended, final boundaries
