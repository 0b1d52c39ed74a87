"""The 1075-float Craft feature vector (docs/craft.md §1.7-1.8) and its compact uint8 storage form.

Layout (index order of the authors' ``_obs``):

* ``[0, 525)`` local 5×5×21 one-hot around the agent, index ``((dx+2)*5 + (dy+2))*21 + k``; out-of-map
  cells are all-zero, empty cells (and the agent's own cell) set channel 0;
* ``[525, 1050)`` the 25×25×21 one-hot window centred on the agent, max-pooled in 5×5 blocks, raveled
  the same way; all zeros with partial observation;
* ``[1050, 1071)`` inventory counts; ``[1071, 1075)`` direction one-hot [down, up, left, right].
"""

from __future__ import annotations

from typing import Final

import numpy as np

from sim_nodes.craft.world import HEIGHT, N_KINDS, WIDTH, CraftWorld

WINDOW: Final = 5
GLOBAL_WINDOW: Final = 25
LOCAL_SIZE: Final = WINDOW * WINDOW * N_KINDS  # 525
N_FEATURES: Final = 2 * LOCAL_SIZE + N_KINDS + 4  # 1075
LOCAL: Final = slice(0, LOCAL_SIZE)
GLOBAL: Final = slice(LOCAL_SIZE, 2 * LOCAL_SIZE)
INVENTORY: Final = slice(2 * LOCAL_SIZE, 2 * LOCAL_SIZE + N_KINDS)
DIRECTION: Final = slice(2 * LOCAL_SIZE + N_KINDS, N_FEATURES)

_PAD_KIND: Final = N_KINDS  # a 22nd pseudo-kind whose one-hot row is all zeros
_PAD: Final = GLOBAL_WINDOW // 2  # 12
_CELL_OFFSETS: Final = np.arange(WINDOW * WINDOW) * N_KINDS
_XS: Final = np.arange(WIDTH)
_YS: Final = np.arange(HEIGHT)


def local_index(dx: int, dy: int, kind: int) -> int:
    """Index of (dx, dy, kind) in the local block (dx, dy ∈ −2..2)."""
    return ((dx + 2) * WINDOW + (dy + 2)) * N_KINDS + kind


def global_index(bi: int, bj: int, kind: int) -> int:
    """Index of pooled block (bi, bj) and ``kind`` in the global block."""
    return LOCAL_SIZE + (bi * WINDOW + bj) * N_KINDS + kind


def compute_features(
    grid: np.ndarray,
    pos: tuple[int, int],
    direction: int,
    inventory: np.ndarray,
    *,
    full_obs: bool = True,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """The float32 feature vector of one state (vectorised scatters, no per-cell Python loop)."""
    feats = np.zeros(N_FEATURES, dtype=np.float32) if out is None else out
    if out is not None:
        feats[:] = 0.0
    x, y = pos
    # Local block: a padded copy of the grid (pad = a kind with no channel), then one scatter.
    padded = np.full((WIDTH + 4, HEIGHT + 4), _PAD_KIND, dtype=np.intp)
    padded[2:-2, 2:-2] = grid
    local = padded[x : x + WINDOW, y : y + WINDOW].ravel()
    inside = local != _PAD_KIND
    feats[(_CELL_OFFSETS + local)[inside]] = 1.0
    if full_obs:
        # Global block: the 25×25 window always covers the 10×10 map, so max-pooling one-hots in 5×5
        # blocks = marking, for every map cell, its kind in the block it falls into.
        bi = (_XS - x + _PAD) // WINDOW
        bj = (_YS - y + _PAD) // WINDOW
        blocks = (bi[:, None] * WINDOW + bj[None, :]) * N_KINDS
        feats[LOCAL_SIZE + (blocks + grid).ravel()] = 1.0
    feats[INVENTORY] = inventory
    feats[DIRECTION.start + int(direction)] = 1.0
    return feats


def world_features(world: CraftWorld, *, full_obs: bool = True, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`compute_features` of a :class:`CraftWorld`."""
    return compute_features(
        world.grid, world.pos, world.direction, world.inventory, full_obs=full_obs, out=out
    )


# --- compact storage ---------------------------------------------------------------------------------
_BINARY_BITS: Final = 2 * LOCAL_SIZE  # 1050 one-hot / max-pooled bits
_BINARY_BYTES: Final = (_BINARY_BITS + 7) // 8  # 132
COMPACT_SIZE: Final = _BINARY_BYTES + N_KINDS + 1  # 132 packed bits + 21 counts + 1 direction byte = 154


class CompactEncodingError(ValueError):
    """Features that the compact uint8 form cannot represent exactly, or a malformed compact array."""


def encode_compact(features: np.ndarray) -> np.ndarray:
    """Pack ``[..., 1075]`` features into ``[..., 154]`` uint8 (bits, inventory counts, direction bits).

    Exact for every vector the env produces: the blocks other than the inventory must be 0/1 and the
    inventory must hold integers in 0..255; anything else raises :class:`CompactEncodingError`.
    """
    feats = np.asarray(features)
    if feats.shape[-1:] != (N_FEATURES,):
        raise CompactEncodingError(f"expected features of shape [..., {N_FEATURES}], got {feats.shape}")
    binary = np.concatenate([feats[..., :_BINARY_BITS], feats[..., DIRECTION]], axis=-1)
    if not np.all((binary == 0) | (binary == 1)):
        raise CompactEncodingError("feature blocks other than the inventory must be 0/1 to encode compactly")
    inv = feats[..., INVENTORY]
    if not np.all((inv >= 0) & (inv <= 255) & (inv == np.round(inv))):
        raise CompactEncodingError("inventory features must be integers in 0..255 to encode compactly")
    bits = np.packbits(binary[..., :_BINARY_BITS].astype(np.uint8), axis=-1)
    direction = np.packbits(binary[..., _BINARY_BITS:].astype(np.uint8), axis=-1)
    return np.concatenate([bits, inv.astype(np.uint8), direction], axis=-1)


def decode_compact(compact: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode_compact`: ``[..., 154]`` uint8 → float32 ``[..., 1075]``."""
    data = np.asarray(compact)
    if data.dtype != np.uint8 or data.shape[-1:] != (COMPACT_SIZE,):
        raise CompactEncodingError(
            f"expected a uint8 array of shape [..., {COMPACT_SIZE}], got {data.dtype} {data.shape}"
        )
    out = np.empty((*data.shape[:-1], N_FEATURES), dtype=np.float32)
    out[..., :_BINARY_BITS] = np.unpackbits(data[..., :_BINARY_BYTES], axis=-1, count=_BINARY_BITS)
    out[..., INVENTORY] = data[..., _BINARY_BYTES : _BINARY_BYTES + N_KINDS]
    out[..., DIRECTION] = np.unpackbits(data[..., -1:], axis=-1, count=4)
    return out
