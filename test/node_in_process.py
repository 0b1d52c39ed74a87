"""ompn_node in process with publishers that record (the markers it reads: :mod:`episode_markers`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")
hypothesis = pytest.importorskip("hypothesis")
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402


class Recorder:
    """Stands in for a publisher: keeps the CDR bytes the node publishes."""

    def __init__(self) -> None:
        self.raws: list[bytes] = []

    def publish(self, raw: bytes) -> None:
        assert isinstance(raw, bytes)
        self.raws.append(raw)


def active_node(ctx, ckpt: Path, **params: Any) -> OMPNNode:
    overrides = [Parameter("checkpoint", value=str(ckpt)), Parameter("detector_high", value=0.3)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    node = OMPNNode(context=ctx, parameter_overrides=overrides)
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    node.outputs.pubs = {k: Recorder() for k in node.outputs.pubs}
    return node

