"""Subtask vocabulary and sketch ids for the weakly supervised ("sketch") setting (docs/craft.md §1.9).

Deviation from the authors: their ids come from ``list(set(names))``, i.e. Python's per-process string
hash order, so they change between runs.  Ours are the **sorted** names, ids 1..8, 0 = padding, fixed.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from sim_nodes.craft.world import TASKS, Task, get_task

SUBTASK_NAMES: Final = tuple(sorted({s.split()[-1] for t in TASKS.values() for s in t.sketch}))
"""('factory', 'gem', 'gold', 'grass', 'iron', 'toolshed', 'wood', 'workbench')."""
PAD_ID: Final = 0
SUBTASK_ID: Final = {name: i + 1 for i, name in enumerate(SUBTASK_NAMES)}
N_SUBTASK_IDS: Final = len(SUBTASK_NAMES) + 1  # embedding table size including the pad id
MAX_SKETCH_LEN: Final = max(len(t.sketch) for t in TASKS.values())  # 5


def subtask_id(subtask: str) -> int:
    """Id of a subtask string ('get wood' → id of 'wood')."""
    return SUBTASK_ID[subtask.split()[-1]]


def sketch_ids(task: str | Task, *, pad_to: int | None = None) -> np.ndarray:
    """int64 subtask ids of ``task``'s sketch in order, optionally right-padded with 0 to ``pad_to``."""
    spec = task if isinstance(task, Task) else get_task(task)
    ids = [subtask_id(s) for s in spec.sketch]
    if pad_to is not None:
        if pad_to < len(ids):
            raise ValueError(f"pad_to={pad_to} is shorter than the sketch of '{spec.name}' ({len(ids)})")
        ids += [PAD_ID] * (pad_to - len(ids))
    return np.asarray(ids, dtype=np.int64)


def sketch_names(ids: np.ndarray) -> list[str]:
    """Inverse of :func:`sketch_ids` (pads dropped)."""
    return [SUBTASK_NAMES[int(i) - 1] for i in np.asarray(ids) if int(i) != PAD_ID]
