"""Cached teacher-forced scores of lab arms, made up: what lab.detector_selection.cached_scores reads
from ``<work>/selection/<arm>.npz``, for tests of the lab studies built on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

RNG = np.random.default_rng(3)


def episode(sharp: bool, length: int = 40, subtasks: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A p_hat [T, 3] whose expansion peaks at the labelled boundaries (``sharp``) or anywhere."""
    labels = np.repeat(np.arange(subtasks), length // subtasks + 1)[:length]
    ends = set(np.flatnonzero(np.diff(labels) != 0).tolist()) | {length - 1}
    p = np.zeros((length, 3))
    for t in range(length):
        high = (t in ends) if sharp else RNG.random() < 0.15
        p[t] = [0.05, 0.05, 0.9] if high else [0.9, 0.05, 0.05]
    return p, labels


def write_cache(work: Path, arm: str, sharp: bool) -> None:
    doc = {}
    for prefix, n in (("val", 12), ("test", 10)):
        for i in range(n):
            p, lab = episode(sharp)
            doc[f"{prefix}_p{i}"], doc[f"{prefix}_l{i}"] = p.astype(np.float32), lab
    (work / "selection").mkdir(parents=True, exist_ok=True)
    np.savez_compressed(work / "selection" / f"{arm}.npz", **doc)  # type: ignore[arg-type]
