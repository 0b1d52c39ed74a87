"""One room chooses the detector (ompn_ros.detect.choose, its defaults in ompn_ros.detect.defaults),
and the settings keep one shape: detector.json, DetectorSettings and the node's parameters."""

from __future__ import annotations

import ast
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import Episode
from ompn_ros.detect import choose, defaults
from ompn_ros.detect.errors import DetectorSettingsError
from ompn_ros.detect.settings import (
    DETECTOR_FILE,
    DetectorSettings,
    detector_config,
    load_detector_settings,
    node_parameters,
)
from ompn_ros.train.config import TrainConfig

ROOT = Path(__file__).resolve().parents[2]
CHOOSER_FUNCTIONS = {"pick_online", "prefer", "duration_detector", "tune_head_duration", "pick_head",
                     "calibrate_without_labels", "objective_for", "settings_on_labels",
                     "settings_without_labels", "choose_on_replayed", "with_tuned", "pick_offline"}
"""What decides the detector: defined in ompn_ros/detect/choose.py (objective_for: defaults.py) only."""
DEFAULT_NAMES = {"DURATION_LAG", "DURATION_DELAY", "DURATION_GAIN", "DEFAULT_OBJECTIVE", "OBJECTIVES",
                 "LABEL_FREE_REFERENCE", "LABEL_FREE_REFERENCE_MIN_LENGTH", "LABEL_FREE_MIN_LENGTH",
                 "DEFAULT_DONE_THRESHOLD"}
"""The chooser's defaults: assigned in ompn_ros/detect/defaults.py only."""
OWNERS = {ROOT / "ompn_ros" / "detect" / "choose.py", ROOT / "ompn_ros" / "detect" / "defaults.py"}


def _sources() -> list[Path]:
    return sorted([*(ROOT / "ompn_ros").rglob("*.py"), *(ROOT / "lab").rglob("*.py")])


def _defined(tree: ast.Module) -> tuple[set[str], set[str]]:
    """Top-level function names and assigned names of a module."""
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assigned: set[str] = set()
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
            node, ast.AnnAssign) else []
        assigned |= {t.id for t in targets if isinstance(t, ast.Name)}
    return functions, assigned


def test_only_the_chooser_defines_the_choice_and_its_defaults() -> None:
    offenders = []
    for path in _sources():
        if path in OWNERS:
            continue
        functions, assigned = _defined(ast.parse(path.read_text(encoding="utf-8")))
        where = path.relative_to(ROOT)
        offenders += [f"{where}: def {name}" for name in sorted(functions & CHOOSER_FUNCTIONS)]
        offenders += [f"{where}: {name} =" for name in sorted(assigned & DEFAULT_NAMES)]
    assert not offenders, "the detector choice is written outside ompn_ros/detect/choose.py:\n" + "\n".join(
        offenders)


def test_the_check_sees_a_second_chooser() -> None:
    tree = ast.parse("DURATION_LAG = 2\n\ndef pick_online(a, b, c):\n    return a\n")
    functions, assigned = _defined(tree)
    assert functions & CHOOSER_FUNCTIONS == {"pick_online"} and assigned & DEFAULT_NAMES == {"DURATION_LAG"}


def test_training_and_tuning_run_with_the_choosers_defaults() -> None:
    from ompn_ros.app import segment_setup

    config = TrainConfig()
    assert (config.detector_lag, config.detector_delay) == (defaults.DURATION_LAG, defaults.DURATION_DELAY)
    assert (segment_setup.DURATION_LAG, segment_setup.DURATION_DELAY) == (1, 6.0)
    assert DetectorSettings().done_threshold == defaults.DEFAULT_DONE_THRESHOLD == 0.5


@pytest.mark.parametrize("domain", ["dial", "craft"])
def test_shipped_detector_files_read_back_to_the_same_document(domain: str) -> None:
    path = shipped_checkpoint(domain) / DETECTOR_FILE
    stored = json.loads(path.read_text(encoding="utf-8"))
    settings = load_detector_settings(path.parent)
    assert settings.to_dict() == stored  # no format change: the file is what the settings write
    view = detector_config(node_parameters(settings))  # the node's parameters, and back
    assert view.low_threshold == settings.online.low_threshold  # 'low' None reads back as low = high
    assert replace(view, low=None) == replace(settings.online, low=None)


@pytest.mark.parametrize(
    ("patch", "key"),
    [
        ({"offline": ["top_k"]}, "offline"),
        ({"duration_model": {"subtasks": "four"}}, "duration_model"),
        ({"boundary_head": {"window": 8}}, "boundary_head"),
        ({"online": {"mode": "hsmm"}}, "online.mode"),
        ({"format": "someone.else"}, "format"),
    ],
)
def test_every_part_of_from_dict_names_its_key_in_one_line(patch: dict, key: str) -> None:
    doc = {**DetectorSettings().to_dict(), **patch}
    with pytest.raises(DetectorSettingsError) as info:
        DetectorSettings.from_dict(doc, origin="their/detector.json")
    message = str(info.value)
    assert message.startswith("their/detector.json") and f"'{key}'" in message and "\n" not in message
    assert message.count("their/detector.json") == 1


def _episodes(n: int, rng: np.random.Generator) -> tuple[list[np.ndarray], list[Episode]]:
    """Episodes of three subtasks whose p_hat shows each boundary as an expansion from the top."""
    p_hats, episodes = [], []
    for i in range(n):
        lengths = rng.integers(5, 9, size=3)
        labels = np.repeat(np.arange(3), lengths)
        p = np.full((len(labels), 4), 0.05)
        p[:, 3] = 0.85
        ends = np.cumsum(lengths)[:-1] - 1
        p[ends] = [0.05, 0.85, 0.05, 0.05]
        p_hats.append(p / p.sum(1, keepdims=True))
        episodes.append(Episode(observations=np.zeros((len(labels) + 1, 2), np.float32),
                                actions=np.zeros(len(labels), np.int64), task="t", subtask=labels, seed=i))
    return p_hats, episodes


def test_the_choice_on_labels_finds_the_boundaries_and_calls_its_parts_once_in_order() -> None:
    p_hats, episodes = _episodes(12, np.random.default_rng(0))
    calls: list[str] = []

    def offline() -> tuple[str, int]:
        calls.append("offline")
        return "constrained_top_k", 3

    def fit_head() -> None:
        calls.append("head")

    settings = choose.choose_settings(choose.Validation(p_hats, episodes, "a test"), action_type="discrete",
                                      use_labels=True, fit_head=fit_head, offline=offline)  # type: ignore[arg-type]
    assert calls == ["head", "offline"]
    assert settings.source == "tuned_on_validation" and settings.min_length == 3
    assert settings.metrics["threshold_val_f1_tol1"] > 0.9  # the plain expansions are found
    unlabelled = choose.choose_settings(choose.Validation(p_hats, episodes, "a test"), action_type="discrete",
                                        use_labels=False, offline=offline)  # type: ignore[arg-type]
    assert unlabelled.source == "calibrated_label_free" and unlabelled.offline_detector == "auto_threshold"
    assert calls == ["head", "offline"]  # without labels neither is asked for


def test_the_params_file_holds_the_nodes_detector_parameters(tmp_path: Path) -> None:
    import yaml

    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.detect.params_file import load_detector_yaml, write_node_config
    from ompn_ros.detect.settings import DETECTOR_PARAMETERS

    config = DetectorConfig(high=0.3, low=0.2, min_segment_length=3, mode="peak", offset=2)
    path = write_node_config(tmp_path / "node.yaml", "", config, {}, "their bag")
    written = yaml.safe_load(path.read_text(encoding="utf-8"))["/**/ompn_node"]["ros__parameters"]
    assert set(written) == set(DETECTOR_PARAMETERS)  # one set of names: the file, the node, the reader
    assert load_detector_yaml(path) == config


def test_a_params_file_writes_each_value_in_the_nodes_type(tmp_path: Path) -> None:
    import yaml

    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.detect.params_file import write_node_config
    from ompn_ros.detect.settings import detector_parameters

    config = DetectorConfig(high=1, low=0, min_segment_length=2)  # a whole-number threshold, as JSON gives it
    path = write_node_config(tmp_path / "node.yaml", "", config, {}, "their bag")
    written = yaml.safe_load(path.read_text(encoding="utf-8"))["/**/ompn_node"]["ros__parameters"]
    assert written == detector_parameters(config)  # the node's parameters of this detector ...
    assert [type(value) for value in written.values()] == [float, float, int, str, bool, int, int]
    assert "detector_high: 1.0\n" in path.read_text(encoding="utf-8")  # ... a double, as the node declares it


def test_the_offline_choice_is_the_best_alignment_first_on_ties() -> None:
    assert choose.pick_offline({"topkc_align": 0.8, "topk_align": 0.9, "auto_align": 0.9}, 4) == ("top_k", 4)
    assert choose.pick_offline({"topkc_align": 0.9, "topk_align": 0.9, "auto_align": 0.1}, 2) == (
        "constrained_top_k", 2)
