"""The restart rule of :func:`ompn_ros.train.trainer.train`: a second initialisation for a weak start.

Some initialisations never find the subtask structure. With a sketch, one Craft training seed of
five expands its top slot at the wrong steps and its validation alignment stays well below the other
runs' (docs/design.md#restart-rule).  The run is decided early: its best validation alignment comes
early in the run.

The rule: at its first evaluation at or after iteration ``restart_at``, a run whose best validation
criterion so far is below ``restart_below`` has a *weak start*.  It trains to the end all the same,
then a new initialisation (seed ``seed + RESTART_SEED_STRIDE · k`` for attempt ``k``) trains on the
*same* train/validation split in ``OUT/attempts/<k>/``, at most ``restarts`` times while the newest
attempt starts weak.  The attempt with the best validation criterion is kept (the first on ties): its
``best/``, ``last/`` and ``log.jsonl`` are copied into ``OUT`` (attempt 0's log is kept as
``log_attempt0.jsonl``), and ``OUT/attempt.json`` records every attempt and which one was kept.

The bound is absolute and was set on expert Craft; keeping the better attempt rather than the newest
one makes a bound that fires on a good run cost time, not accuracy (human-like partial-observation
runs all start below it, docs/design.md#restart-rule).  Cost: one more whole run per weak start.

It needs labels: the label-free ``agreement`` does not flag the collapse (0.95 at iteration 100 on
the collapsed Craft run, as high as on good runs), so under label-free selection the rule is off and
the trainer says so once.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ompn_ros.atomic import atomic_write_text
from ompn_ros.train.candidates import copy_outputs
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainStateError

RESTART_SEED_STRIDE = 100_003
"""Attempt ``k`` of seed ``s`` initialises with seed ``s + RESTART_SEED_STRIDE · k`` (a prime above
the ensemble members' ``s + 1000 · j``, so the two never share an initialisation)."""
ATTEMPT_FILE = "attempt.json"
ATTEMPTS_DIR = "attempts"
FIRST_LOG = "log_attempt0.jsonl"
KEPT = ("best", "last", "log.jsonl")
"""What the kept attempt contributes to the run directory."""


def attempt_config(cfg: TrainConfig, attempt: int) -> TrainConfig:
    """The config of attempt ``attempt``: a new initialisation and batch order, the same split, its own
    directory ``OUT/attempts/<attempt>/`` (attempt 0 is the run itself)."""
    if attempt == 0:
        return cfg
    split = cfg.seed if cfg.split_seed is None else cfg.split_seed
    out = None if cfg.out_dir is None else str(Path(cfg.out_dir) / ATTEMPTS_DIR / str(attempt))
    return replace(  # type: ignore[type-var]
        cfg, seed=cfg.seed + RESTART_SEED_STRIDE * attempt, split_seed=split, out_dir=out,
    )


def rule_applies(cfg: TrainConfig, labelled: bool, attempt: int) -> bool:
    """Whether this attempt checks the rule at ``restart_at``: on, a ``labelled`` selection (the
    label-free agreement does not flag a collapse), restarts left."""
    return bool(cfg.restart_at) and labelled and attempt < cfg.restarts


def start_score(cfg: TrainConfig, scores: Sequence[tuple[int, float]]) -> float | None:
    """The best criterion of validation ``scores`` (``(iteration, criterion)`` of a run's selectable
    evaluations, in order) up to the first evaluation at or after ``restart_at``; None when the run
    never got there or the rule is off.  O(len(scores))."""
    checked = [it for it, _ in scores if it >= cfg.restart_at]
    if not cfg.restart_at or not checked:
        return None
    return max((s for it, s in scores if it <= checked[0]), default=-math.inf)


def weak_start(cfg: TrainConfig, scores: Sequence[tuple[int, float]]) -> bool:
    """Whether a run with validation ``scores`` starts weak: its :func:`start_score` is below
    ``restart_below`` (False for a run that never reached ``restart_at``)."""
    score = start_score(cfg, scores)
    return score is not None and not score >= cfg.restart_below


def attempt_row(attempt: int, seed: int, best: float, best_iteration: int, seconds: float,
                frames: int) -> dict[str, Any]:
    """The record of one finished attempt (``OUT/attempt.json``)."""
    return {"attempt": attempt, "seed": seed, "best": best, "best_iteration": best_iteration,
            "train_seconds": seconds, "frames": frames,
            "dir": "." if attempt == 0 else f"{ATTEMPTS_DIR}/{attempt}"}


def kept_attempt(rows: Sequence[dict[str, Any]]) -> int:
    """The attempt with the best validation criterion, the first of equals."""
    return int(max(rows, key=lambda r: float(r["best"]))["attempt"])


def read_record(out_dir: Path | None) -> dict[str, Any]:
    """``out_dir``'s restart record, checked (empty without one); :class:`TrainStateError` names a
    malformed one."""
    path = None if out_dir is None else out_dir / ATTEMPT_FILE
    if path is None or not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
        attempt, rows = doc["attempt"], doc.get("attempts", [])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TrainStateError(
            f"{path} is not a restart record ({exc!r}); remove it to resume attempt 0"
        ) from exc
    if not isinstance(attempt, int) or isinstance(attempt, bool) or attempt < 0:
        raise TrainStateError(f"{path}: 'attempt' must be an int >= 0, got {attempt!r}")
    if not isinstance(rows, list) or not all(isinstance(r, dict) and {"attempt", "best"} <= set(r)
                                             for r in rows):
        raise TrainStateError(f"{path}: 'attempts' must be a list of attempt records")
    return dict(doc)


def read_attempt(out_dir: Path | None) -> int:
    """The attempt a resumable run directory holds (0 without a record): the one in progress, or
    the last one trained."""
    return int(read_record(out_dir).get("attempt", 0))


def read_kept(out_dir: Path | None) -> int:
    """The attempt whose checkpoints ``out_dir`` holds: the kept one (a record written before the
    rule kept the better attempt names none: its last attempt trained in ``out_dir``)."""
    doc = read_record(out_dir)
    kept = doc.get("kept", doc.get("attempt", 0))
    if not isinstance(kept, int) or isinstance(kept, bool) or kept < 0:
        raise TrainStateError(f"{out_dir}/{ATTEMPT_FILE}: 'kept' must be an int >= 0, got {kept!r}")
    return kept


def finished_attempts(out_dir: Path | None) -> list[dict[str, Any]]:
    """The rows of the attempts ``out_dir`` records as finished before the one in progress."""
    doc = read_record(out_dir)
    return [r for r in doc.get("attempts", []) if r["attempt"] < doc.get("attempt", 0)]


def clear_attempts(out_dir: Path | None) -> None:
    """A fresh (not resumed) run: drop an earlier run's restart record, attempts and first log."""
    if out_dir is None:
        return
    (out_dir / ATTEMPT_FILE).unlink(missing_ok=True)
    (out_dir / FIRST_LOG).unlink(missing_ok=True)
    shutil.rmtree(out_dir / ATTEMPTS_DIR, ignore_errors=True)


def start_attempt(out_dir: Path | None, attempt: int, seed: int, reason: str,
                  rows: Sequence[dict[str, Any]]) -> None:
    """Record that attempt ``attempt`` starts after the finished ``rows``."""
    if out_dir is None:
        return
    doc = {"attempt": attempt, "seed": seed, "reason": reason, "attempts": list(rows)}
    atomic_write_text(out_dir / ATTEMPT_FILE, json.dumps(doc, indent=1) + "\n")


def keep_attempt(out_dir: Path | None, kept: int, rows: Sequence[dict[str, Any]]) -> None:
    """Publish attempt ``kept`` in ``out_dir`` (its checkpoints and log; attempt 0's log stays as
    ``log_attempt0.jsonl``) and record every attempt and the kept one."""
    if out_dir is None:
        return
    if kept:
        if not (out_dir / FIRST_LOG).exists() and (out_dir / "log.jsonl").is_file():
            (out_dir / "log.jsonl").rename(out_dir / FIRST_LOG)
        copy_outputs(out_dir / ATTEMPTS_DIR / str(kept), out_dir, KEPT)
    doc = json.loads((out_dir / ATTEMPT_FILE).read_text())
    doc.update(attempts=list(rows), kept=kept)
    atomic_write_text(out_dir / ATTEMPT_FILE, json.dumps(doc, indent=1) + "\n")


def restart_reason(cfg: TrainConfig, selection: str, scores: Sequence[tuple[int, float]]) -> str:
    """The one log line of a weak start."""
    score = start_score(cfg, scores)
    shown = "none" if score is None or math.isinf(score) else f"{score:.3f}"
    return (f"restart rule: best validation {selection} by iteration {cfg.restart_at} was {shown}, "
            f"below restart_below={cfg.restart_below}: training a new initialisation on the same split "
            "and keeping the better of the two by validation")


__all__ = [
    "ATTEMPTS_DIR",
    "ATTEMPT_FILE",
    "FIRST_LOG",
    "RESTART_SEED_STRIDE",
    "attempt_config",
    "attempt_row",
    "clear_attempts",
    "finished_attempts",
    "keep_attempt",
    "kept_attempt",
    "read_attempt",
    "read_kept",
    "read_record",
    "restart_reason",
    "rule_applies",
    "start_attempt",
    "start_score",
    "weak_start",
]
