"""lab.detours: the fold of a trip out and back, the persistence test and the DROID-style idle filter
on hand-made observation streams (docs/experiments.md §57)."""

from __future__ import annotations

import numpy as np

from lab.detours import DROID_RUN, droid_rows, fold_rows, undone
from ompn_ros.data.episode import Episode


def _line(cells: list[int], noise: float = 0.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.eye(10, dtype=np.float32)[cells] + rng.normal(0, noise, (len(cells), 10)).astype(np.float32)


def test_fold_drops_an_overshoot_and_a_wrong_move_undone() -> None:
    # rows: 0 at 2; 1 to 3; 2 overshoots to 4; 3 back at 3 (row 2 folded); 4 a pause at 3 (still);
    # 5 on to 4, 6 to 5; 7 a wrong move to 8?  no: to 6, 8 back at 5 (row 7 folded); 9 on to 6, 10 to 7
    cells = [2, 3, 4, 3, 3, 4, 5, 6, 5, 6, 7]
    kept = fold_rows(_line(cells, noise=0.02), tolerance=0.2, window=4)
    assert kept.tolist() == [0, 1, 5, 6, 9, 10]


def test_fold_with_a_window_of_one_is_the_still_rule() -> None:
    cells = [2, 3, 3, 3, 4, 5, 4]
    assert fold_rows(_line(cells, noise=0.02), tolerance=0.2, window=1).tolist() == [0, 1, 4, 5, 6]


def test_a_move_undone_bars_its_own_step_and_the_one_before() -> None:
    cells = [2, 3, 4, 3, 5, 6, 7, 8]  # the move of step 1 (3 -> 4) is undone at row 3
    barred = undone(_line(cells), tolerance=0.2, steps=3)
    assert barred.tolist() == [True, True, False, False, False, False, False]


def test_droid_filter_drops_only_long_constant_velocity_runs() -> None:
    T = 30
    rng = np.random.default_rng(1)
    moving = np.cumsum(rng.uniform(0.5, 1.5, (T + 1, 3)), axis=0).astype(np.float32)  # velocity changes
    held = moving.copy()
    held[10:] = held[10]  # held from row 10 on: 20 idle frames (velocity 0, unchanged)
    actions, labels = np.zeros(T, np.int64), np.zeros(T, np.int64)
    kept = droid_rows(Episode(held, actions, labels, None, "t", 0, True), "craft")
    assert len(kept) < T - 15 and kept[0] == 0 and np.all(np.diff(kept) > 0)
    noisy = held + rng.normal(0, 0.02, held.shape).astype(np.float32)  # sensor noise: nothing is idle
    assert len(droid_rows(Episode(noisy, actions, labels, None, "t", 0, True), "craft")) == T
    short = moving.copy()
    short[10 : 10 + DROID_RUN - 1] = short[10]  # held for fewer than 7 frames: kept
    short[10 + DROID_RUN - 1 :] += short[10] - short[10 + DROID_RUN - 1]
    assert len(droid_rows(Episode(short, actions, labels, None, "t", 0, True), "craft")) == T
