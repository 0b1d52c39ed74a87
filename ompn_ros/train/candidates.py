"""Best of N initialisations: train several on one split and keep the one validation prefers.

Some initialisations find a worse segmentation than others, and which ones cannot be known before
training.  Bags without the observation after the last action (the reader guesses row T) make this
more likely: on Craft with the ``blank`` row T, more seeds ended weak than with complete bags, and
the weak runs had the lowest best validation alignment (docs/design.md#best-of-two).  Keeping the
better of two runs by that validation criterion avoids most of them.

Layout: candidate ``k`` trains in ``OUT/candidates/<k>/`` with seed ``seed + CANDIDATE_SEED_STRIDE ·
k`` on the split of ``seed`` (candidate 0 is exactly the single run of ``seed``).  The winner's
``best/`` and ``last/`` (with their ``detector.json``) and ``log.jsonl`` are copied into ``OUT``, and
``OUT/candidates.json`` records every candidate's seed, best iteration and score and which one won.
A resumed run resumes each candidate in its own directory.

Cost: N full training runs (the restart rule of :mod:`ompn_ros.train.restart` still applies to each).
The comparison uses the run's selection criterion; with the label-free ``agreement`` it is a weak
guide (it did not flag a collapsed run, docs/design.md#best-of-two), and the trainer says so.
"""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, TypeVar

from ompn_ros.atomic import atomic_write_text
from ompn_ros.train.config import TrainConfig

LOG = logging.getLogger(__name__)

CANDIDATE_SEED_STRIDE = 10_007
"""Candidate ``k`` of seed ``s`` initialises with seed ``s + CANDIDATE_SEED_STRIDE · k`` (a prime, so it
never meets an ensemble member's ``s + 1000 · j``; a restart adds ``100 003`` on top)."""
CANDIDATES_DIR = "candidates"
CANDIDATES_FILE = "candidates.json"
COPIED = ("best", "last", "log.jsonl")
"""What the winner contributes to the run directory."""




class CandidateResult(Protocol):
    """The fields of :class:`~ompn_ros.train.trainer.TrainResult` the comparison reads."""

    best_iteration: int
    best_metrics: dict[str, float]
    selection: str
    restarts: int


R = TypeVar("R", bound=CandidateResult)


@dataclass(frozen=True)
class Candidate:
    """One finished candidate: its number, seed, directory and result."""

    index: int
    seed: int
    out_dir: Path | None
    score: float
    result: Any


def candidate_config(cfg: TrainConfig, index: int) -> TrainConfig:
    """The config of candidate ``index``: a new initialisation and batch order, the split of ``cfg.seed``,
    its own directory under ``OUT/candidates/``, and ``candidates = 1`` (it trains once)."""
    split = cfg.seed if cfg.split_seed is None else cfg.split_seed
    out = None if cfg.out_dir is None else str(Path(cfg.out_dir) / CANDIDATES_DIR / str(index))
    return replace(  # type: ignore[type-var]
        cfg, seed=cfg.seed + CANDIDATE_SEED_STRIDE * index, split_seed=split, out_dir=out, candidates=1,
    )


def resolve_candidates(cfg: TrainConfig, final_guessed: bool, labelled: bool) -> TrainConfig:
    """``cfg`` with ``candidates`` raised to ``candidates_no_final`` when the reader guessed the final
    observation (row T) of training episodes and validation labels select the checkpoint.

    O(1).  Labels are required because the label-free ``agreement`` does not rank weak runs below good
    ones (docs/design.md#best-of-two); without them the extra runs would cost time for nothing shown."""
    if not (final_guessed and labelled) or cfg.candidates_no_final <= cfg.candidates:
        return cfg
    LOG.info("the reader guessed the final observation of training episodes: training %d initialisations "
             "and keeping the best by validation (train.candidates_no_final; docs/design.md#best-of-two)",
             cfg.candidates_no_final)
    return replace(cfg, candidates=cfg.candidates_no_final)  # type: ignore[type-var]


def _score(result: CandidateResult) -> float:
    return float(result.best_metrics.get(result.selection, float("-inf")))


def candidate_rows(everyone: Sequence[Candidate]) -> list[dict[str, Any]]:
    """One JSON-ready row per candidate: number, seed, best iteration and score, restarts, directory."""
    return [
        {"candidate": c.index, "seed": c.seed, "best_iteration": int(c.result.best_iteration),
         "best": c.score, "restarts": int(c.result.restarts), "dir": f"{CANDIDATES_DIR}/{c.index}"}
        for c in everyone
    ]


def copy_outputs(source_dir: Path, out_dir: Path, names: Sequence[str]) -> None:
    """Replace ``out_dir/<name>`` by ``source_dir/<name>`` for each of ``names`` (files or directories;
    a name ``source_dir`` lacks is removed from ``out_dir``)."""
    for name in names:
        source, target = source_dir / name, out_dir / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
        if source.is_dir():
            shutil.copytree(source, target)
        elif source.is_file():
            shutil.copy2(source, target)


def _publish(out_dir: Path, winner: Candidate, everyone: Sequence[Candidate], selection: str) -> None:
    """Copy the winner's checkpoints and log into ``out_dir`` and write ``candidates.json``."""
    assert winner.out_dir is not None
    copy_outputs(winner.out_dir, out_dir, COPIED)
    doc = {
        "selection": selection,
        "winner": winner.index,
        "candidates": candidate_rows(everyone),
    }
    atomic_write_text(out_dir / CANDIDATES_FILE, json.dumps(doc, indent=1) + "\n")


def best_of(cfg: TrainConfig, train_one: Callable[[TrainConfig], R],
            is_main: bool = True) -> tuple[R, list[Candidate]]:
    """Train ``cfg.candidates`` initialisations with ``train_one`` and return the winner's result and
    every candidate, in order.  The winner has the highest best validation criterion (the first on
    ties, so candidate 0 unless another one is strictly better).

    Cost: ``cfg.candidates`` calls of ``train_one``, plus copying the winner's checkpoints."""
    done: list[Candidate] = []
    for index in range(cfg.candidates):
        sub = candidate_config(cfg, index)
        if is_main:
            LOG.info("candidate %d of %d (seed %d)", index + 1, cfg.candidates, sub.seed)
        result = train_one(sub)
        out = None if sub.out_dir is None else Path(sub.out_dir)
        done.append(Candidate(index, sub.seed, out, _score(result), result))
    winner = max(done, key=lambda c: c.score)  # max keeps the first of equal scores
    if is_main:
        LOG.info("candidates: %s; kept candidate %d",
                 ", ".join(f"{c.index}: {c.score:.3f}" for c in done), winner.index)
        if cfg.out_dir is not None:
            _publish(Path(cfg.out_dir), winner, done, winner.result.selection)
    return winner.result, done


__all__ = [
    "CANDIDATES_DIR",
    "CANDIDATES_FILE",
    "CANDIDATE_SEED_STRIDE",
    "Candidate",
    "best_of",
    "candidate_config",
    "candidate_rows",
    "copy_outputs",
    "resolve_candidates",
]
