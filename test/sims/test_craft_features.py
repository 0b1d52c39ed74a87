"""Craft feature layout (hand-checked indices), partial masking, compact encoding, sketch ids."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.craft.expert import generate_episode
from sim_nodes.craft.features import (
    COMPACT_SIZE,
    N_FEATURES,
    CompactEncodingError,
    decode_compact,
    encode_compact,
    global_index,
    local_index,
    world_features,
)
from sim_nodes.craft.sketch import SUBTASK_NAMES, sketch_ids, sketch_names
from sim_nodes.craft.world import BOUNDARY, IRON, N_KINDS, TOOLSHED, WOOD, Action, CraftWorld


def fixed_world(pos=(3, 3)) -> CraftWorld:
    w = CraftWorld("makebed")
    w.grid = np.zeros((10, 10), dtype=np.int8)
    w.grid[0, :] = w.grid[-1, :] = w.grid[:, 0] = w.grid[:, -1] = BOUNDARY
    w.grid[3, 4] = WOOD
    w.grid[8, 8] = TOOLSHED
    w.pos, w.direction = pos, int(Action.UP)
    w.inventory = np.zeros(N_KINDS, dtype=np.int64)
    w.inventory[IRON] = 1
    return w


def test_feature_indices_hand_checked():
    f = world_features(fixed_world())
    assert f.shape == (N_FEATURES,) == (1075,) and f.dtype == np.float32
    # helpers agree with the hand-computed formula ((dx+2)*5 + (dy+2))*21 + k
    assert local_index(0, 1, WOOD) == 282 and local_index(0, 0, 0) == 252
    assert f[282] == 1.0  # wood right above the agent
    assert f[252] == 1.0  # the agent's own cell is 'empty'
    assert f[:525].sum() == 25  # window fully inside the map: one kind per cell
    # global block: window x-12..x+12 = -9..15; block 2 covers 1..5, block 1 covers -4..0
    assert global_index(2, 2, WOOD) == 786 and f[786] == 1.0
    assert global_index(1, 1, BOUNDARY) == 652 and f[652] == 1.0
    assert f[525 + (1 * 5 + 1) * 21 + 0] == 0.0  # block (1,1) holds only the corner boundary cell
    assert f[global_index(3, 3, TOOLSHED)] == 1.0  # (8, 8) lies in block 3 (6..10)
    assert f[525 : 525 + 5 * 21].sum() == 0  # block row bi=0 (x -9..-5) is outside the map
    assert f[1050 + IRON] == 1.0 and f[1050:1071].sum() == 1
    assert f[1071:].tolist() == [0.0, 1.0, 0.0, 0.0]  # facing up


def test_out_of_map_cells_are_zero_and_boundary_is_channel_one():
    f = world_features(fixed_world(pos=(1, 1)))
    assert f[local_index(-1, 0, BOUNDARY)] == 1.0
    assert f[local_index(-2, 0, 0) : local_index(-2, 0, 0) + N_KINDS].sum() == 0  # x = -1: padding
    assert f[:525].sum() == 16  # 4x4 of the 5x5 window lies inside the map


def test_global_block_equals_global_view_of_all_cells():
    w = fixed_world(pos=(6, 2))
    f = world_features(w)
    glob = f[525:1050].reshape(5, 5, N_KINDS)
    for bi in range(5):
        for bj in range(5):
            xs = [x for x in range(6 - 12 + 5 * bi, 6 - 7 + 5 * bi) if 0 <= x < 10]
            ys = [y for y in range(2 - 12 + 5 * bj, 2 - 7 + 5 * bj) if 0 <= y < 10]
            kinds = {int(w.grid[x, y]) for x in xs for y in ys}
            assert set(np.flatnonzero(glob[bi, bj]).tolist()) == kinds


def test_partial_observation_zeroes_only_the_global_block():
    w = fixed_world()
    full, part = world_features(w, full_obs=True), world_features(w, full_obs=False)
    assert part[525:1050].sum() == 0 and full[525:1050].sum() > 0
    assert np.array_equal(np.delete(full, np.s_[525:1050]), np.delete(part, np.s_[525:1050]))


def test_compact_round_trip_exact_on_episodes():
    for full_obs in (True, False):
        ep = generate_episode(11, task="makeshears", full_obs=full_obs)
        packed = encode_compact(ep.observations)
        assert packed.dtype == np.uint8 and packed.shape == (ep.length + 1, COMPACT_SIZE)
        assert np.array_equal(decode_compact(packed), ep.observations)
        assert np.array_equal(decode_compact(encode_compact(ep.observations[3])), ep.observations[3])


def test_compact_rejects_what_it_cannot_represent():
    f = world_features(fixed_world())
    bad = f.copy()
    bad[10] = 0.5
    with pytest.raises(CompactEncodingError, match="0/1"):
        encode_compact(bad)
    bad = f.copy()
    bad[1050] = 300
    with pytest.raises(CompactEncodingError, match="inventory"):
        encode_compact(bad)
    with pytest.raises(CompactEncodingError, match="shape"):
        encode_compact(f[:100])
    with pytest.raises(CompactEncodingError, match="uint8"):
        decode_compact(np.zeros(COMPACT_SIZE, dtype=np.int64))


def test_sketch_vocabulary_sorted_and_fixed():
    assert SUBTASK_NAMES == ("factory", "gem", "gold", "grass", "iron", "toolshed", "wood", "workbench")
    assert sketch_ids("makebed").tolist() == [7, 6, 4, 8]
    assert sketch_ids("makeaxe").tolist() == [7, 8, 5, 6]
    assert sketch_ids("makeshears").tolist() == [7, 8, 5, 8]
    assert sketch_ids("makebed", pad_to=5).tolist() == [7, 6, 4, 8, 0]
    assert sketch_ids("makebed").dtype == np.int64
    assert sketch_names(sketch_ids("getgem", pad_to=5)) == ["wood", "workbench", "iron", "toolshed", "gem"]
    with pytest.raises(ValueError, match="pad_to"):
        sketch_ids("getgem", pad_to=3)


def reference_features(w: CraftWorld) -> np.ndarray:
    """Straightforward spec formula: one-hot windows, zero padding, 5×5 max-pooling."""
    one_hot = np.zeros((34, 34, N_KINDS), dtype=np.float32)  # map cell (x, y) at [x + 12, y + 12]
    for x in range(10):
        for y in range(10):
            one_hot[x + 12, y + 12, w.grid[x, y]] = 1.0
    x, y = w.pos
    local = one_hot[x + 10 : x + 15, y + 10 : y + 15]
    window = one_hot[x : x + 25, y : y + 25]
    pooled = window.reshape(5, 5, 5, 5, N_KINDS).max(axis=(1, 3))
    direction = np.eye(4, dtype=np.float32)[w.direction]
    return np.concatenate([local.ravel(), pooled.ravel(), w.inventory.astype(np.float32), direction])


def test_vectorised_features_match_reference_formula():
    rng = np.random.default_rng(0)
    for seed in range(30):
        w = CraftWorld("getgold" if seed % 3 == 0 else "makebed")
        w.reset(np.random.default_rng(seed))
        w.inventory[rng.integers(0, N_KINDS)] = 1
        assert np.array_equal(world_features(w), reference_features(w))
