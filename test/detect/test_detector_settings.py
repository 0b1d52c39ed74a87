"""detector.json: the detector settings stored with a checkpoint (ompn_ros.detect.settings)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.errors import DetectorSettingsError
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import (
    DETECTOR_FILE,
    DetectorSettings,
    detector_config,
    load_detector_settings,
    node_parameters,
    resolve_detector,
    save_detector_settings,
)
from ompn_ros.paths import config_file


def _settings() -> DetectorSettings:
    return DetectorSettings(
        online=DetectorConfig(high=0.15, low=0.05, min_segment_length=3, mode="peak", offset=2),
        done_threshold=0.7,
        offline_detector="constrained_top_k",
        min_length=4,
        source="calibrated_label_free",
        provenance="calibrated on 12 validation episodes",
        metrics={"f1_tol1": 0.9, "delay_mean": float("nan")},
    )


def test_round_trip_through_the_file(tmp_path: Path) -> None:
    saved = _settings()
    path = save_detector_settings(tmp_path, saved)
    assert path == tmp_path / DETECTOR_FILE
    loaded = load_detector_settings(tmp_path)
    assert loaded.online == saved.online
    assert (loaded.done_threshold, loaded.offline_detector, loaded.min_length) == (
        0.7,
        "constrained_top_k",
        4,
    )
    assert loaded.source == "calibrated_label_free" and loaded.provenance == saved.provenance
    assert loaded.metrics["f1_tol1"] == 0.9
    assert json.loads(path.read_text())["metrics"]["delay_mean"] is None  # strict JSON
    assert [p.name for p in tmp_path.iterdir()] == [DETECTOR_FILE]  # no temporary left behind


def test_missing_file_gives_defaults_and_a_warning(tmp_path: Path) -> None:
    loaded = load_detector_settings(tmp_path)
    assert loaded.source == "default" and loaded.online == DetectorConfig()
    assert "not found" in loaded.provenance and DETECTOR_FILE in loaded.provenance


@pytest.mark.parametrize(
    ("patch", "key"),
    [
        ({"online": {"high": 2.0}}, "online"),
        ({"online": {"hgh": 0.2}}, "online"),
        ({"done_threshold": -1}, "done_threshold"),
        ({"offline": {"detector": "magic", "min_length": 2}}, "offline.detector"),
        ({"offline": {"detector": "top_k", "min_length": 0}}, "offline.min_length"),
        ({"source": "guessed"}, "source"),
        ({"format_version": 99}, "format_version"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_invalid_file_names_file_and_key(tmp_path: Path, patch: dict, key: str) -> None:
    doc = {**_settings().to_dict(), **patch}
    (tmp_path / DETECTOR_FILE).write_text(json.dumps(doc))
    with pytest.raises(DetectorSettingsError) as info:
        load_detector_settings(tmp_path)
    assert str(tmp_path / DETECTOR_FILE) in str(info.value) and f"'{key}'" in str(info.value)


def test_unreadable_json_names_the_file(tmp_path: Path) -> None:
    (tmp_path / DETECTOR_FILE).write_text("{not json")
    with pytest.raises(DetectorSettingsError, match=r"detector\.json"):
        load_detector_settings(tmp_path)


def test_precedence_explicit_over_checkpoint_over_default(tmp_path: Path) -> None:
    settings, line = resolve_detector(tmp_path)
    assert settings.source == "default" and "not found" in line
    save_detector_settings(tmp_path, _settings())
    settings, line = resolve_detector(tmp_path)
    assert settings.online.high == 0.15 and "calibrated_label_free" in line and str(tmp_path) in line
    explicit = DetectorConfig(high=0.4)
    settings, line = resolve_detector(tmp_path, explicit, "--detector-config x.yaml")
    assert settings.online == explicit and settings.min_length == 4  # stored offline choice kept
    assert "--detector-config x.yaml" in line and "high=0.4" in line


def test_save_needs_an_existing_directory(tmp_path: Path) -> None:
    with pytest.raises(DetectorSettingsError, match="not a directory"):
        save_detector_settings(tmp_path / "missing", _settings())


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_shipped_checkpoints_carry_the_shipped_node_settings(domain: str) -> None:
    """The node runs the detector the shipped checkpoint carries: its per-domain config overrides no
    detector key, and what the detector's mode needs (a duration model, a boundary head) is there."""
    import yaml

    stored = load_detector_settings(shipped_checkpoint(domain))
    params = yaml.safe_load(config_file(f"ompn_node_{domain}.yaml").read_text())["/**/ompn_node"][
        "ros__parameters"
    ]
    assert stored.source == "shipped"
    assert not [key for key in params if key.startswith("detector_")], (
        f"config/ompn_node_{domain}.yaml overrides the shipped checkpoint's detector")
    if stored.online.mode in ("hsmm", "head_hsmm"):
        assert stored.duration_model is not None, f"{domain}: mode {stored.online.mode} without its model"
    if stored.online.mode in ("head", "head_hsmm"):
        assert stored.head is not None, f"{domain}: mode {stored.online.mode} without its boundary head"


def test_node_parameters_round_trip_through_the_node_yaml_reader() -> None:
    settings = _settings()
    params = node_parameters(settings)
    assert params["detector_mode"] == "peak" and params["done_threshold"] == 0.7
    high, hysteresis = params["detector_high"], params["detector_hysteresis"]
    rebuilt = DetectorConfig(
        high=high,
        low=round(high - hysteresis, 6) if hysteresis > 0 else None,
        min_segment_length=params["detector_min_segment_length"],
        mode=params["detector_mode"],
        force_first_step_low=params["detector_force_first_step_low"],
        offset=params["detector_offset"],
    )
    assert rebuilt == settings.online
    back = detector_config(params)  # the node's own way back (low = high - hysteresis, in floats)
    assert back.low_threshold == pytest.approx(settings.online.low_threshold)
    assert dataclasses.replace(back, low=settings.online.low) == settings.online


def test_a_detector_file_written_before_the_offset_reads_as_offset_0(tmp_path: Path) -> None:
    path = save_detector_settings(tmp_path, _settings())
    doc = json.loads(path.read_text())
    del doc["online"]["offset"]
    path.write_text(json.dumps(doc))
    assert load_detector_settings(tmp_path).online.offset == 0
    assert "offset" not in load_detector_settings(tmp_path).describe()  # the log line names a non-zero one
    assert "offset=2" in _settings().describe()


@pytest.mark.parametrize(
    ("before", "after"), [("shipped", "shipped"), ("calibrated_label_free", "tuned_on_validation")]
)
def test_retuning_keeps_a_shipped_checkpoint_shipped(tmp_path: Path, before: str, after: str) -> None:
    import dataclasses

    from ompn_ros.app.replay import store_tuned

    save_detector_settings(tmp_path, dataclasses.replace(_settings(), source=before))  # type: ignore[arg-type]
    tuned = DetectorConfig(high=0.3, mode="falling_edge")
    store_tuned(tmp_path, tuned, {"f1_tol1": 0.95}, "ompn_segment --tune on 3 bags, objective f1")
    stored = load_detector_settings(tmp_path)
    assert stored.source == after and stored.online == tuned and stored.min_length == 4  # offline kept
    assert stored.provenance == "ompn_segment --tune on 3 bags, objective f1"
