"""Collation with the appended done step, observation statistics, split and batch order."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ompn_ros.data.episode import Episode
from ompn_ros.train.batching import collate, epoch_batches, obs_normalization, split_train_val
from ompn_ros.train.errors import BatchError


def _discrete(length: int, dim: int = 3, sketch: list[int] | None = None) -> Episode:
    obs = np.arange((length + 1) * dim, dtype=np.float32).reshape(length + 1, dim)
    return Episode(
        obs,
        np.arange(length, dtype=np.int64) % 2,
        np.zeros(length, np.int64),
        None if sketch is None else np.asarray(sketch),
        task="t",
        seed=length,
    )


def test_discrete_collate_appends_done_class_and_pads() -> None:
    batch = collate([_discrete(2), _discrete(4)], "discrete", action_dim=5)
    assert batch.obs.shape == (2, 5, 3) and batch.actions.shape == (2, 5)
    assert batch.actions[0].tolist() == [0, 1, 5, 0, 0]  # done = action_dim at row T, then padding
    assert batch.actions[1].tolist() == [0, 1, 0, 1, 5]
    assert batch.mask[0].tolist() == [True, True, True, False, False]
    assert batch.done_mask[0].tolist() == [False, False, True, False, False]
    assert batch.done_mask[1].tolist() == [False, False, False, False, True]
    assert torch.equal(batch.obs[0, :3], torch.from_numpy(_discrete(2).observations))  # final obs at row T
    assert torch.all(batch.obs[0, 3:] == 0)
    assert batch.lengths.tolist() == [2, 4] and batch.valid_steps == 3 + 5
    assert batch.sketch is None


def test_continuous_collate_zero_action_at_done_step() -> None:
    eps = [
        Episode(np.ones((3, 2), np.float32), np.full((2, 4), 0.5, np.float32)),
        Episode(np.ones((2, 2), np.float32), np.full((1, 4), -1.0, np.float32)),
    ]
    batch = collate(eps, "continuous", action_dim=4)
    assert batch.actions.shape == (2, 3, 4) and batch.actions.dtype == torch.float32
    assert torch.all(batch.actions[0, 2] == 0) and torch.all(batch.actions[0, :2] == 0.5)
    assert batch.done_mask.tolist() == [[False, False, True], [False, True, False]]


def test_sketch_ids_are_kept_and_padded_with_minus_one() -> None:
    batch = collate(
        [_discrete(2, sketch=[0, 3]), _discrete(2, sketch=[2, 1, 4])], "discrete", 5, use_sketch=True
    )
    assert batch.sketch is not None
    assert batch.sketch.tolist() == [[0, 3, -1], [2, 1, 4]]


def test_collate_errors_name_the_episode() -> None:
    with pytest.raises(BatchError, match="seed 2"):
        collate([_discrete(3), _discrete(2, dim=4)], "discrete", 5)
    bad = _discrete(2)
    bad.actions[0] = 7
    with pytest.raises(BatchError, match="action ids outside"):
        collate([bad], "discrete", 5)
    with pytest.raises(BatchError, match="shape"):
        collate([Episode(np.ones((3, 2), np.float32), np.ones((2, 3), np.float32))], "continuous", 4)
    with pytest.raises(BatchError, match="no sketch"):
        collate([_discrete(2)], "discrete", 5, use_sketch=True)
    with pytest.raises(BatchError, match="empty"):
        collate([], "discrete", 5)


def test_obs_normalization_modes() -> None:
    eps = [
        Episode(np.array([[1.0, 0.0], [-3.0, 0.0]], np.float32), np.zeros(1, np.int64)),
        Episode(np.array([[2.0, 0.0], [4.0, 0.0]], np.float32), np.zeros(1, np.int64)),
    ]
    norm = obs_normalization(eps, "maxabs")
    np.testing.assert_allclose(norm.mean, [1.0, 0.0])
    np.testing.assert_allclose(norm.scale, [4.0, 1.0])  # max |s| of the raw values; all-zero feature -> 1
    np.testing.assert_allclose(norm.apply(np.array([5.0, 2.0])), [1.0, 2.0])
    none = obs_normalization(eps, "none")
    assert np.all(none.mean == 0) and np.all(none.scale == 1)
    with pytest.raises(BatchError, match="obs_norm"):
        obs_normalization(eps, "std")  # type: ignore[arg-type]


def test_obs_statistics_stream_over_episodes() -> None:
    rng = np.random.default_rng(4)
    eps = [Episode((rng.standard_normal((int(n) + 1, 40)) * 10 ** rng.uniform(-3, 3, 40)).astype(np.float32),
                   np.zeros(int(n), np.int64)) for n in rng.integers(1, 300, 60)]
    stacked = np.concatenate([e.observations for e in eps]).astype(np.float64)  # the reference
    norm = obs_normalization(eps, "maxabs")
    np.testing.assert_allclose(norm.mean, stacked.mean(axis=0).astype(np.float32), rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(norm.scale, np.abs(stacked).max(axis=0).astype(np.float32))
    with pytest.raises(BatchError, match=r"episode #1 .*\(2, 3\).* 40 features"):
        obs_normalization([eps[0], Episode(np.zeros((2, 3), np.float32), np.zeros(1, np.int64))], "maxabs")


def test_obs_statistics_do_not_copy_the_dataset() -> None:
    import tracemalloc

    big = np.random.default_rng(1).standard_normal((40_000, 50)).astype(np.float32)  # 8 MB
    eps = [Episode(big[a: a + 100], np.zeros(99, np.int64)) for a in range(0, len(big), 100)]
    tracemalloc.start()
    try:
        obs_normalization(eps, "maxabs")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < big.nbytes // 8, f"{peak} bytes traced while reading {big.nbytes} bytes of observations"


def test_split_and_epoch_batches_are_seeded() -> None:
    train_a, val_a = split_train_val(10, 0.2, seed=3)
    _, val_b = split_train_val(10, 0.2, seed=3)
    assert len(val_a) == 2 and len(train_a) == 8
    assert np.array_equal(val_a, val_b) and not set(val_a) & set(train_a)
    batches = epoch_batches(10, 4, seed=1, epoch=0)
    assert [len(b) for b in batches] == [4, 4, 2]
    assert sorted(np.concatenate(batches).tolist()) == list(range(10))
    assert all(np.array_equal(x, y) for x, y in zip(batches, epoch_batches(10, 4, seed=1, epoch=0)))
    assert not np.array_equal(np.concatenate(batches), np.concatenate(epoch_batches(10, 4, seed=1, epoch=1)))
    with pytest.raises(BatchError, match="val_ratio"):
        split_train_val(10, 1.5, seed=0)
