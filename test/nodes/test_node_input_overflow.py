"""Every observation is stepped or counted: a burst that overflows the node's input queue.

A publisher sends 2 000 observations as fast as it can to an ``ompn_node`` whose input queue holds 5
(``qos_depth``): most are overwritten in the middleware before any callback runs, which the middleware
reports nowhere.  The node counts them from the gaps in the publisher's sequence numbers
(``messages_missed``, :mod:`ompn_ros.stream.delivery`) and warns once: stepped + missed = sent, with
either executor.  Every message differs from the others: equal bytes 100 µs apart are a driver's repeat
(:mod:`ompn_ros.data.cuts.repeats`), stepped once and counted apart, and a burst is faster than that.
Loopback only; bounded: 2 000 messages, 90 s at most per executor.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from node_process import NodeProcess, Peer  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.stream.delivery import SequenceGaps  # noqa: E402

TRAILERS = 10  # messages sent one at a time after the burst (see the test)
BURST = 2_000
OBS_DIM = 8


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("overflow") / "ckpt"
    save_checkpoint(path, OMPNPolicy(OMPNConfig(obs_dim=OBS_DIM, action_type="discrete", action_dim=4,
                                                n_slots=3, slot_size=64)))
    return path


@pytest.mark.parametrize("executor", ["events", "single"])
def test_a_burst_is_stepped_or_counted(ckpt: Path, ros_env: dict[str, str], executor: str) -> None:
    ns = f"/overflow_{os.getpid()}_{executor}"
    proc = NodeProcess(ros_env, f"checkpoint:={ckpt}", "qos_depth:=5", "diagnostics_period:=0.1",
                       f"executor:={executor}", "max_stamp_lead:=0.0", ns=ns)
    peer = Peer(proc, name="burst_sim")
    try:
        pub = peer.node.create_publisher(Float32MultiArray, proc.topic(layout.OBSERVATION),
                                         QoSProfile(depth=BURST, reliability=ReliabilityPolicy.RELIABLE))
        diags = peer.statuses(proc.status_name)
        pump = peer.pump

        def counter(name: str) -> int:
            return int(diags[-1].get(name, 0)) if diags else 0

        msg = Float32MultiArray(data=[0.5] * OBS_DIM)
        numbered = iter(range(1_000_000))

        def publish() -> None:  # every message its own bytes: none is a repeat of the one before
            msg.data[0] = float(next(numbered))
            pub.publish(msg)

        sent = 0
        # one observation at a time until the node has stepped one: its sequence numbers are known
        while not pump(lambda: counter("accepted") > 0, 0.5):
            assert proc.running() and sent < 120, "ompn_node never stepped an observation"
            publish()
            sent += 1
        sent = counter("accepted")  # the ones before the first received are not the node's to count
        for _ in range(BURST):
            publish()
        sent += BURST
        # A gap at the very end of a stream shows only when a later message arrives (its sequence number
        # is the evidence): trailing messages, one at a time, until the count is whole.
        for _ in range(TRAILERS):
            if pump(lambda n=sent: counter("accepted") + counter("messages_missed") >= n, 5):
                break
            publish()
            sent += 1
        assert pump(lambda: counter("accepted") + counter("messages_missed") >= sent, 60), str(diags[-1:])
        pump(lambda: False, 0.5)  # nothing more arrives
        assert counter("accepted") + counter("messages_missed") == sent, diags[-1]
        assert counter("messages_missed") > 0 and counter("rejected") == 0 == counter("repeated_messages")
    finally:
        peer.close()
        out = proc.stop()
    warned = [x for x in out.splitlines() if "never received" in x]
    assert len(warned) == 1 and "messages_missed" in warned[0] and "qos_depth=5" in warned[0], out[-3000:]


def test_the_gap_rule() -> None:
    gaps = SequenceGaps()
    assert [gaps.seen(s) for s in (7, 8, 12, 13)] == [0, 0, 3, 0]  # before 7: not known to be missed
    assert gaps.seen(2) == 0 and gaps.seen(5) == 2  # a restarted publisher: counting starts again
    gaps.publishers(2)
    assert gaps.seen(100) == 0 and gaps.seen(3) == 0 and gaps.seen(101) == 0  # interleaved: not counted
    gaps.publishers(1)
    assert gaps.seen(110) == 0 and gaps.seen(112) == 1 and gaps.seen(2**64 - 1) == 0
    assert gaps.seen(0) == 0 and gaps.seen(113) == 0  # no number given: the count goes on unharmed
    assert gaps.missed == 3 + 2 + 1
