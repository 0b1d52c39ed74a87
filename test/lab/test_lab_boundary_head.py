"""The causal boundary head study (lab.boundary_head): inputs, targets, the causal decoding of its
lag outputs, a head that learns a delayed cue, and the README section."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lab import boundary_head as bh
from lab.own_data import ARMS
from lab.report import render_readme


def test_every_family_names_arms_of_the_own_data_study() -> None:
    for _, role, arms in bh.FAMILIES:
        assert role in ("design", "held-out seeds", "held-out family")
        assert arms and all(arm in ARMS for arm in arms)
    design = {a for _, role, arms in bh.FAMILIES if role == "design" for a in arms}
    held = {a for _, role, arms in bh.FAMILIES if role != "design" for a in arms}
    assert design and held and not design & held


def test_windowed_rows_are_the_last_steps_with_the_first_repeated() -> None:
    x = np.arange(10, dtype=np.float32).reshape(5, 2)
    w = bh.windowed(x)
    assert w.shape == (5, bh.WINDOW * 2)
    np.testing.assert_array_equal(w[0], np.tile(x[0], bh.WINDOW))
    np.testing.assert_array_equal(w[4, -4:], x[3:5].ravel())  # the newest step last


def test_targets_mark_inner_boundaries_at_every_lag() -> None:
    y = bh.targets(np.array([2, 9]), 10)  # 9 is the episode's last step: no target
    assert y.shape == (10, bh.MAX_LAG + 1)
    for j in range(bh.MAX_LAG + 1):
        assert y[2 + j, j] == 1.0
    assert y.sum() == bh.MAX_LAG + 1


def _spikes(length: int, steps: dict[int, float], lag: int) -> np.ndarray:
    q = np.zeros((length, bh.MAX_LAG + 1))
    for s, value in steps.items():
        for j in range(bh.MAX_LAG + 1):
            if s + j < length:
                q[s + j, j] = value
    return q


def test_decode_publishes_each_boundary_lag_steps_later_and_closes_at_the_end() -> None:
    q = _spikes(20, {5: 0.9, 6: 0.6, 12: 0.2, 18: 0.8}, 0)
    steps, when = bh.decode(q, bh.Rule(lag=3, theta=0.5, gap=1, peak=False))
    assert steps == [5, 6, 18, 19] and when == [8, 9, 19, 19]  # 18 only at the end; 19 closes
    steps, _ = bh.decode(q, bh.Rule(lag=3, theta=0.5, gap=2, peak=False))
    assert steps == [5, 18, 19]  # 6 is too close to 5
    steps, _ = bh.decode(q, bh.Rule(lag=3, theta=0.1, gap=1, peak=True))
    assert steps == [5, 6, 12, 18, 19]


def test_peak_waits_for_the_likelier_later_step() -> None:
    q = _spikes(20, {5: 0.6, 6: 0.9}, 0)
    steps, _ = bh.decode(q, bh.Rule(lag=2, theta=0.5, gap=2, peak=True))
    assert steps == [6, 19]
    steps, _ = bh.decode(q, bh.Rule(lag=2, theta=0.5, gap=2, peak=False))
    assert steps == [5, 19]


def _toy(rng: np.random.Generator, n: int, cue: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Episodes of 3 subtasks whose outputs show a bump two steps after each boundary (or noise only)."""
    xs, labels = [], []
    for _ in range(n):
        lengths = rng.integers(6, 14, size=3)
        lab = np.repeat(np.arange(3), lengths)
        x = rng.normal(0, 0.3, size=(len(lab), 4)).astype(np.float32)
        if cue:
            for b in np.cumsum(lengths)[:-1] - 1:
                x[b + 2, 0] += 3.0
        xs.append(x)
        labels.append(lab.astype(np.int64))
    return xs, labels


@pytest.mark.parametrize("cue", [True, False])
def test_a_trained_head_finds_a_delayed_cue_and_nothing_without_one(cue: bool) -> None:
    rng = np.random.default_rng(0)
    train_x, train_l = _toy(rng, 60, cue)
    val_x, val_l = _toy(rng, 20, cue)
    test_x, test_l = _toy(rng, 20, cue)
    head = bh.train_head(train_x, bh._bounds(train_l), seed=0, recurrent=False)
    rule, val = bh.pick([head(x) for x in val_x], val_l)
    got = bh.score([head(x) for x in test_x], test_l, rule)
    assert val == bh.score([head(x) for x in val_x], val_l, rule)
    if cue:
        assert got["online_f1_1"] > 0.95 and rule.lag >= 2  # the cue comes two steps late
        assert got["delay_mean"] <= bh.MAX_LAG
    else:
        assert got["online_f1_1"] < 0.8


def test_the_readme_section_shows_each_family(tmp_path: Path) -> None:
    figures = {"online_f1_1": 0.9, "online_align": 0.8, "delay_mean": 2.0, "at_end_share": 0.1}
    head = {**figures, "val": {"online_align": 0.7}}
    rows = [{"arm": a, "offline": {"f1_1": 0.5, "align": 0.6}, "head_labels": head, "head_topk": figures,
             "bundled": {"f1_1": 0.7, "align": 0.75, "delay": 1.0, "val": {"online_align": val}}}
            for a, val in (("a", 0.6), ("b", 0.8))]  # the head wins validation on a only
    family = bh.family_row("toy family", "held-out family", rows)
    assert family["means"]["decoder_budget"] is None
    assert family["means"]["head_labels"] == {k: head[k] for k in bh.FIGURES}
    assert family["means"]["chosen"] == {"f1_1": pytest.approx(0.8), "align": pytest.approx(0.775),
                                         "head_runs": 1}
    (tmp_path / bh.RESULTS).write_text(json.dumps({"meta": {"command": ["x"], "date": "d", "held_out": "h",
                                                            **{k: v for k, v in bh.META.items()
                                                               if k != "held_out"}},
                                                   "families": [family]}))
    text = render_readme(tmp_path)
    assert ("| toy family | held-out family | 2 | 50.0 / 60.0 | 70.0 / 75.0 | – | 90.0 / 80.0, 2.0 steps, "
            "10.0 % at end |") in text
    assert text.rstrip().endswith("| 80.0 / 77.5 (head in 1) |")
