"""ompn_node runs the detector that travels with the checkpoint unless a parameter says otherwise."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.duration import DurationDetector, fit_duration_model
from ompn_ros.detect.online import DetectorConfig, OnlineDetector
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


def test_the_node_declares_one_parameter_per_detector_field_with_its_default() -> None:
    from ompn_ros.detect.settings import NODE_PARAMETERS, node_parameters
    from ompn_ros.nodes.ompn_node_params import SPECS

    declared = {spec.name: spec.default for spec in SPECS}
    defaults = node_parameters(DetectorSettings())  # DetectorConfig's fields under the node's names
    assert [(name, declared[name], type(declared[name])) for name in NODE_PARAMETERS] == [
        (name, value, type(value)) for name, value in defaults.items()
    ]


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


def test_a_checkpoint_with_a_duration_model_runs_the_hsmm_decoder_and_takes_live_changes(
    tmp_path: Path,
) -> None:
    path = tmp_path / "dial_hsmm"
    shutil.copytree(shipped_checkpoint("dial"), path)
    rng = np.random.default_rng(0)
    lengths = rng.integers(5, 8, size=(50, 4))
    bounds = [np.cumsum(ls) - 1 for ls in lengths]
    scores = [np.where(np.isin(np.arange(b[-1] + 1), b), 0.7, 0.1) for b in bounds]
    model = fit_duration_model(scores, bounds)
    save_detector_settings(path, DetectorSettings(online=DetectorConfig(mode="hsmm", high=0.6, lag=2),
                                                  duration_model=model, provenance="a test"))
    node, ctx = _configured([Parameter("checkpoint", value=str(path))])
    try:
        detector = node.segmenter.detector
        assert isinstance(detector, DurationDetector) and (detector.lag, detector.threshold) == (2, 0.6)
        assert node.get_parameter("detector_lag").value == 2
        assert node.set_parameters([Parameter("detector_lag", value=3)])[0].successful
        assert node.segmenter.detector.lag == 3  # no step yet: applies at once
        assert node.set_parameters([Parameter("detector_mode", value="peak")])[0].successful
        assert isinstance(node.segmenter.detector, OnlineDetector)
    finally:
        _close(node, ctx)


def test_the_hsmm_mode_is_refused_for_a_checkpoint_without_a_duration_model(checkpoint: Path) -> None:
    node, ctx = _configured([Parameter("checkpoint", value=str(checkpoint))])
    try:
        result = node.set_parameters([Parameter("detector_mode", value="hsmm")])[0]
        assert not result.successful and "needs a duration model" in result.reason
        assert node.segmenter.detector_config.mode == "peak"
    finally:
        _close(node, ctx)
