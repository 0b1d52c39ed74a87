"""Text and image renderings of a Craft world (y is drawn upward, as in the authors' renderer)."""

from __future__ import annotations

from typing import Final

import numpy as np

from sim_nodes.craft.world import DIRECTION_DELTA, KIND_NAMES, N_KINDS, CraftWorld

_CHARS: Final = ".#~oTWFigw$*PSARBHCDL"  # one character per kind id (see KIND_NAMES)
_AGENT_CHARS: Final = "v^<>"  # down, up, left, right
_COLORS: Final = np.array(
    [
        (235, 235, 225),
        (60, 60, 60),
        (70, 130, 220),
        (140, 140, 150),  # empty boundary water stone
        (200, 120, 40),
        (150, 90, 50),
        (120, 60, 140),  # toolshed workbench factory
        (170, 170, 185),
        (110, 200, 80),
        (120, 80, 30),
        (240, 200, 30),
        (60, 220, 220),  # iron..gem
        (220, 180, 120),
        (180, 140, 90),
        (200, 60, 60),
        (200, 200, 120),
        (220, 100, 160),
        (160, 160, 220),
        (240, 160, 200),
        (110, 90, 70),
        (210, 170, 60),
    ],
    dtype=np.uint8,
)
assert len(_CHARS) == N_KINDS and len(_COLORS) == N_KINDS


def render_ansi(world: CraftWorld) -> str:
    """Rows from top (largest y) to bottom; the agent is drawn as an arrow; then inventory and progress."""
    rows = []
    for y in range(world.grid.shape[1] - 1, -1, -1):
        row = [_CHARS[int(world.grid[x, y])] for x in range(world.grid.shape[0])]
        if y == world.pos[1]:
            row[world.pos[0]] = _AGENT_CHARS[world.direction]
        rows.append(" ".join(row))
    held = [f"{KIND_NAMES[k]}={int(n)}" for k, n in enumerate(world.inventory) if n > 0]
    sketch = world.task.sketch
    done = min(world.sketch_index, len(sketch))
    current = sketch[done] if done < len(sketch) else "(all done)"
    rows.append(f"task={world.task.name} step={world.steps} subtask {done}/{len(sketch)}: {current}")
    rows.append("inventory: " + (", ".join(held) if held else "(empty)"))
    return "\n".join(rows) + "\n"


def render_rgb(world: CraftWorld, cell: int = 24) -> np.ndarray:
    """uint8 ``[H*cell, W*cell, 3]`` picture: coloured cells, the agent as a dark square + facing notch."""
    h = world.grid.shape[1]
    kinds = world.grid.T[::-1]  # image rows = y descending, columns = x
    img = np.repeat(np.repeat(_COLORS[kinds], cell, axis=0), cell, axis=1)
    img[::cell, :] = img[:, ::cell] = 200  # faint grid lines
    x, y = world.pos
    r0, c0 = (h - 1 - y) * cell, x * cell
    m = cell // 5
    img[r0 + m : r0 + cell - m, c0 + m : c0 + cell - m] = (30, 30, 30)
    dx, dy = DIRECTION_DELTA[world.direction]
    cr, cc = r0 + cell // 2 - dy * (cell // 2 - m), c0 + cell // 2 + dx * (cell // 2 - m)
    n = max(cell // 8, 1)
    img[max(cr - n, 0) : cr + n, max(cc - n, 0) : cc + n] = (240, 60, 60)
    return img


def save_png(world: CraftWorld, path: str, cell: int = 32) -> None:
    """Write :func:`render_rgb` to a PNG file (matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, render_rgb(world, cell))


if __name__ == "__main__":  # python -m sim_nodes.craft.render docs/craft_map.png [seed] [task]
    import sys

    world = CraftWorld(sys.argv[3] if len(sys.argv) > 3 else "makebed")
    world.reset(np.random.default_rng(int(sys.argv[2]) if len(sys.argv) > 2 else 1))
    save_png(world, sys.argv[1] if len(sys.argv) > 1 else "craft_map.png")
    print(render_ansi(world))
