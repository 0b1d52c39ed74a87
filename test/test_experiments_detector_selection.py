"""The detector-selection study (lab.detector_selection): its families name real arms, and its two
rules are the product's."""

from __future__ import annotations

import numpy as np

from lab import detector_selection as study
from lab.own_data import ARMS


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
    means = study.means([{k: {"f1_1": 0.5, "align": 0.25} for k in (*study.RULES, "test_oracle")}] * 2)
    assert np.isclose(means["one_se"]["f1_1"], 0.5) and np.isclose(means["previous"]["align"], 0.25)
