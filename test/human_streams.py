"""Human-like streams fed to ompn_node in process, and what the node received of them."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
from episode_markers import marker  # noqa: E402

from ompn_ros import layout  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.episode import Episode, observation_copies  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402
from sim_nodes import derive_seed  # noqa: E402
from sim_nodes.craft.human import generate_human_episode  # noqa: E402
from sim_nodes.dial import human as dial_human  # noqa: E402
from sim_nodes.human import parse_human  # noqa: E402

STEP_NS = 40_000_000


HUMAN = ("drop_rate=0.05", "duplicate_rate=0.05", "pause_rate=0.1", "overshoot_rate=0.15")


class Recorder:
    """Stands in for a publisher: keeps the CDR bytes the node publishes."""

    def __init__(self) -> None:
        self.raws: list[bytes] = []

    def publish(self, raw: bytes) -> None:
        self.raws.append(raw)


def received(ep: Episode) -> Episode:
    """What a subscriber receives: each observation as often as it was published."""
    rows = np.repeat(ep.observations, observation_copies(ep), axis=0)
    return Episode(observations=rows, actions=np.zeros(len(rows) - 1, dtype=np.int64), sketch=ep.sketch)


def live(node: OMPNNode, stream: Episode, t0_ns: int) -> tuple[list[tuple[Any, ...]], np.ndarray]:
    b0, p0 = len(node.outputs.pubs["boundary"].raws), len(node.outputs.pubs["pi"].raws)
    node.inputs.markers.on_episode(marker(layout.EPISODE_START, sketch=",".join(map(str, stream.sketch))))
    for t, row in enumerate(stream.observations):
        node.inputs.on_raw_array(m.encode_float32_array(row), t0_ns + t * STEP_NS)
    node.inputs.markers.on_episode(marker(layout.EPISODE_END, steps=str(stream.length)))
    events = []
    for raw in node.outputs.pubs["boundary"].raws[b0:]:
        b = decode_subtask_boundary(raw)
        events.append((b.step, b.subtask, b.decided_step, f"{b.score:.6f}"))
    return events, np.array([m.parse_float32_array(r) for r in node.outputs.pubs["pi"].raws[p0:]])


def _episodes(domain: str) -> list[Episode]:
    """Human-like demonstrations with dropped and duplicated observation messages."""
    human = parse_human(domain, HUMAN)
    if domain == "craft":
        return [generate_human_episode(derive_seed(8, i), human, task=task)
                for i, task in enumerate(("makebed", "makeaxe", "makeshears"))]
    return [dial_human.generate_human_episode(derive_seed(8, i), human) for i in range(2)]
