"""Live equals replay on a human-like stream: ``ompn_node`` (in process, the shipped Craft or Dial
checkpoint and its own detector) fed what ``craft_sim`` / ``dial_sim demonstrator:=human`` publishes
(pauses, detours, variable speed, sensor noise, a dropped observation never arrives, a duplicated one
arrives twice) publishes exactly the boundaries and ``~/pi`` of an offline replay of the same received
stream."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.episode import Episode, observation_copies  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402
from sim_nodes import derive_seed  # noqa: E402
from sim_nodes.craft.human import generate_human_episode  # noqa: E402
from sim_nodes.dial import human as dial_human  # noqa: E402
from sim_nodes.human import parse_human  # noqa: E402

torch.set_num_threads(1)
STEP_NS = 40_000_000
HUMAN = ("drop_rate=0.05", "duplicate_rate=0.05", "pause_rate=0.1", "overshoot_rate=0.15")


class Recorder:
    """Stands in for a publisher: keeps the CDR bytes the node publishes."""

    def __init__(self) -> None:
        self.raws: list[bytes] = []

    def publish(self, raw: bytes) -> None:
        self.raws.append(raw)


def marker(kind: str, **values: str) -> DiagnosticArray:
    status = DiagnosticStatus(name=layout.EPISODE_STATUS_NAME, message=kind,
                              values=[KeyValue(key=k, value=v) for k, v in values.items()])  # fmt: skip
    return DiagnosticArray(status=[status])


def received(ep: Episode) -> Episode:
    """What a subscriber receives: each observation as often as it was published."""
    rows = np.repeat(ep.observations, observation_copies(ep), axis=0)
    return Episode(observations=rows, actions=np.zeros(len(rows) - 1, dtype=np.int64), sketch=ep.sketch)


def live(node: OMPNNode, stream: Episode, t0_ns: int) -> tuple[list[tuple[Any, ...]], np.ndarray]:
    b0, p0 = len(node._pubs["boundary"].raws), len(node._pubs["pi"].raws)
    node._on_episode(marker(layout.EPISODE_START, sketch=",".join(map(str, stream.sketch))))
    for t, row in enumerate(stream.observations):
        node._on_raw_array(m.encode_float32_array(row), t0_ns + t * STEP_NS)
    node._on_episode(marker(layout.EPISODE_END, steps=str(stream.length)))
    events = []
    for raw in node._pubs["boundary"].raws[b0:]:
        b = decode_subtask_boundary(raw)
        events.append((b.step, b.subtask, b.decided_step, f"{b.score:.6f}"))
    return events, np.array([m.parse_float32_array(r) for r in node._pubs["pi"].raws[p0:]])


def _episodes(domain: str) -> list[Episode]:
    """Human-like demonstrations with dropped and duplicated observation messages."""
    human = parse_human(domain, HUMAN)
    if domain == "craft":
        return [generate_human_episode(derive_seed(8, i), human, task=task)
                for i, task in enumerate(("makebed", "makeaxe", "makeshears"))]
    return [dial_human.generate_human_episode(derive_seed(8, i), human) for i in range(2)]


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_live_output_on_a_human_like_stream_equals_its_replay(ctx, domain: str) -> None:
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("domain", value=domain)])
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node._pubs = {k: Recorder() for k in node._pubs}
    seg = node.segmenter
    assert seg is not None
    offline = StreamingSegmenter(seg.policy, seg.detector_config, seg.duration_model, seg.head)
    t0 = (int(time.time()) - 10_000) * 1_000_000_000
    n_events = copies_seen = 0
    for i, ep in enumerate(_episodes(domain)):
        copies_seen += int((observation_copies(ep) != 1).sum())
        stream = received(ep)
        got, pis = live(node, stream, t0 + i * 10 * 1_000_000_000)
        replay = replay_episode(offline, stream, include_done_step=True)
        want = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.published]
        assert got == want, (i, got, want)
        inner = [(b.step, b.subtask, b.detected_at, f"{b.score:.6f}") for b in replay.boundaries]
        assert want[:len(inner) - 1] == inner[:-1]  # the published boundaries of the T real steps
        # one event per subtask, then the episode end when no subtask ended with the episode
        assert [b.subtask for b in replay.published] == list(range(len(replay.published)))
        assert [b.final for b in replay.published] == [False] * (len(replay.published) - 1) + [True]
        assert len(pis) == len(stream.observations)
        np.testing.assert_allclose(pis[:-1, -1], replay.pi_end, atol=1e-6)
        np.testing.assert_allclose(pis[:-1, -2], replay.expected_position, atol=1e-5)
        n_events += len(got)
    assert copies_seen > 0 and n_events > 6  # drops/duplicates happened; inner boundaries were found
    node.destroy_node()
