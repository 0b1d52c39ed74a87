"""The detector-selection study (lab.detector_selection): its families name real arms, its two
rules are the product's, and the bundled detector is the run's own detector.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lab_cache import write_cache

from lab import detector_selection as study
from lab.own_data import ARMS
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import DetectorSettings, save_detector_settings


def test_every_family_names_arms_of_the_own_data_study() -> None:
    names = [arm for family in study.FAMILIES for arm in family.arms]
    assert names and all(name in ARMS for name in names)
    assert len(names) == len(set(names))  # no arm in two families


def test_the_rules_differ_only_where_validation_cannot_tell_settings_apart() -> None:
    rows = [{"f1_tol1": 0.40, "align_strict": 0.960, "delay_mean": 1.0},
            {"f1_tol1": 0.85, "align_strict": 0.955, "delay_mean": 1.0}]
    spread = [{"f1_tol1": 0.4, "align_strict": a, "delay_mean": 1.0} for a in (0.99, 0.93)]
    val = study.Validation(rows, lambda g: spread, [100, 100])
    assert study.previous(val, "align") == 0
    assert study.one_standard_error(val, "align") == 1
    means = study.means([{k: {"f1_1": 0.5, "align": 0.25} for k in (*study.RULES, "test_oracle", "bundled")}]
                        * 2)
    assert np.isclose(means["one_se"]["f1_1"], 0.5) and np.isclose(means["previous"]["align"], 0.25)


def test_the_bundled_detector_is_the_runs_detector_json_on_test(tmp_path: Path) -> None:
    write_cache(tmp_path, "toy_seed1", sharp=True)
    best = tmp_path / "runs" / "toy_seed1" / "best"
    best.mkdir(parents=True)
    data = study.cached_scores("toy_seed1", tmp_path)
    for high in (0.5, 0.95):  # 0.95: no score is above it, so only the episodes' ends are boundaries
        config = DetectorConfig(high=high, mode="falling_edge")
        save_detector_settings(best, DetectorSettings(online=config, source="tuned_on_validation"))
        got = study.bundled("toy_seed1", tmp_path, data)
        want = study.decoded(config, None, data["test_p"], data["test_l"])
        assert (got["f1_1"], got["align"]) == (want["online_f1_1"], want["online_align"])
        assert got["config"] == "falling_edge" and got["source"] == "tuned_on_validation"
        assert got["f1_1"] == pytest.approx(1.0) if high == 0.5 else got["f1_1"] < 0.6
