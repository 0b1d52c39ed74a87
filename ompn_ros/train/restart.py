"""The restart rule of :func:`ompn_ros.train.trainer.train`: re-initialise a run that collapsed.

Some initialisations never find the subtask structure. With a sketch, Craft training seed 2 of five
expands its top slot at the wrong steps (for 36 % of the true boundaries the nearest one Top-K takes
is 2 or more steps away, against 6 % for a good run) and its validation alignment never rises above
0.62 (full) / 0.59 (partial), where the other runs stand at 0.75–0.93 by iteration 120
(docs/design.md#restart-rule).  The run is decided early: its best validation alignment of the run comes
at iteration 60 (full) / 80 (partial).

The rule: at its first evaluation at or after iteration ``restart_at``, a run whose best validation
criterion so far is below ``restart_below`` starts again from a new initialisation (seed
``seed + RESTART_SEED_STRIDE · k`` for attempt ``k``) on the *same* train/validation split, at most
``restarts`` times.  The abandoned attempt's ``log.jsonl`` is kept as ``log_attempt<k>.jsonl``.
Cost: about ``restart_at`` iterations and their evaluations per restart, paid only by the runs that
restart.

It needs labels: the label-free ``agreement`` does not flag the collapse (0.95 at iteration 100 on
the collapsed Craft run, as high as on good runs), so under label-free selection the rule is off and
the trainer says so once.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

from ompn_ros.atomic import atomic_write_text
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainStateError

RESTART_SEED_STRIDE = 100_003
"""Attempt ``k`` of seed ``s`` initialises with seed ``s + RESTART_SEED_STRIDE · k`` (a prime above
the ensemble members' ``s + 1000 · j``, so the two never share an initialisation)."""
ATTEMPT_FILE = "attempt.json"


def attempt_config(cfg: TrainConfig, attempt: int) -> TrainConfig:
    """The config of attempt ``attempt``: a new initialisation and batch order, the same split."""
    if attempt == 0:
        return cfg
    split = cfg.seed if cfg.split_seed is None else cfg.split_seed
    return replace(cfg, seed=cfg.seed + RESTART_SEED_STRIDE * attempt, split_seed=split)  # type: ignore[type-var]


def rule_applies(cfg: TrainConfig, labelled: bool, attempt: int) -> bool:
    """Whether this attempt checks the rule at ``restart_at``: on, a ``labelled`` selection (the
    label-free agreement does not flag a collapse), restarts left."""
    return bool(cfg.restart_at) and labelled and attempt < cfg.restarts


def collapsed(cfg: TrainConfig, iteration: int, best_score: float) -> bool:
    """Whether the run is to restart at this evaluation: the first one at or after ``restart_at``,
    with the best score so far below the bound."""
    first = iteration >= cfg.restart_at > iteration - cfg.eval_every
    return first and not best_score >= cfg.restart_below


def read_attempt(out_dir: Path | None) -> int:
    """The attempt a resumable run directory holds (0 without a record)."""
    path = None if out_dir is None else out_dir / ATTEMPT_FILE
    if path is None or not path.is_file():
        return 0
    try:
        attempt = json.loads(path.read_text())["attempt"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TrainStateError(
            f"{path} is not a restart record ({exc!r}); remove it to resume attempt 0"
        ) from exc
    if not isinstance(attempt, int) or isinstance(attempt, bool) or attempt < 0:
        raise TrainStateError(f"{path}: 'attempt' must be an int >= 0, got {attempt!r}")
    return attempt


def start_attempt(out_dir: Path | None, attempt: int, seed: int, reason: str) -> None:
    """Record attempt ``attempt`` in ``out_dir``, drop the abandoned attempt's resumable state and keep
    its log beside the new one."""
    if out_dir is None:
        return
    shutil.rmtree(out_dir / "train_state", ignore_errors=True)  # a resume must not find the old attempt
    log = out_dir / "log.jsonl"
    if log.is_file():
        log.rename(out_dir / f"log_attempt{attempt - 1}.jsonl")
    doc = {"attempt": attempt, "seed": seed, "reason": reason}
    atomic_write_text(out_dir / ATTEMPT_FILE, json.dumps(doc, indent=1) + "\n")


def restart_reason(cfg: TrainConfig, selection: str, best_score: float, best_iteration: int) -> str:
    """The one log line of a restart."""
    score = "none" if math.isinf(best_score) else f"{best_score:.3f} (iteration {best_iteration})"
    return (f"restart rule: best validation {selection} by iteration {cfg.restart_at} is {score}, "
            f"below restart_below={cfg.restart_below}: the initialisation collapsed, training again "
            "from a new one on the same split")


__all__ = [
    "ATTEMPT_FILE",
    "RESTART_SEED_STRIDE",
    "attempt_config",
    "collapsed",
    "read_attempt",
    "restart_reason",
    "rule_applies",
    "start_attempt",
]
