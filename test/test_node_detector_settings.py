"""ompn_node runs the detector that travels with the checkpoint unless a parameter says otherwise."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import DetectorSettings, save_detector_settings
from ompn_ros.nodes.ompn_node import OMPNNode


@pytest.fixture
def checkpoint(tmp_path: Path) -> Path:
    """A copy of the shipped Dial checkpoint with its own, unusual detector settings."""
    path = tmp_path / "dial"
    shutil.copytree(shipped_checkpoint("dial"), path)
    online = DetectorConfig(high=0.37, low=0.3, min_segment_length=4, mode="peak")
    save_detector_settings(path, DetectorSettings(online=online, done_threshold=0.8,
                                                  source="tuned_on_validation", provenance="a test"))
    return path


def _configured(overrides: list[Parameter]) -> tuple[OMPNNode, Context]:
    ctx = Context()
    rclpy.init(context=ctx)
    node = OMPNNode(context=ctx, parameter_overrides=[Parameter("auto_start", value=False), *overrides])
    node.trigger_configure()
    assert node.segmenter is not None, node.last_error
    return node, ctx


def _close(node: OMPNNode, ctx: Context) -> None:
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_the_checkpoints_detector_is_used_by_default(checkpoint: Path) -> None:
    node, ctx = _configured([Parameter("checkpoint", value=str(checkpoint))])
    try:
        config = node.segmenter.detector_config
        assert (config.high, config.low_threshold, config.min_segment_length, config.mode) == (
            0.37, 0.3, 4, "peak")
        assert node.get_parameter("detector_high").value == 0.37  # the parameters show what runs
        assert node.get_parameter("done_threshold").value == 0.8
    finally:
        _close(node, ctx)


def test_an_explicit_parameter_wins_per_parameter(checkpoint: Path) -> None:
    node, ctx = _configured([Parameter("checkpoint", value=str(checkpoint)),
                             Parameter("detector_high", value=0.6)])
    try:
        config = node.segmenter.detector_config
        assert config.high == 0.6 and config.mode == "peak"  # the rest still from detector.json
    finally:
        _close(node, ctx)


def test_the_shipped_checkpoint_started_the_short_way_has_its_tuned_detector() -> None:
    node, ctx = _configured([Parameter("domain", value="dial")])
    try:
        assert node.segmenter.detector_config.high != 0.5  # not the generic default
    finally:
        _close(node, ctx)
