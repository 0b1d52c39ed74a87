"""``final_observation: auto``: one training run per guess of the missing final observation, and the
run validation prefers kept.

Bags recorded without the observation after the last command leave row T of every episode to a guess
(:attr:`~ompn_ros.data.reader.ReaderSpec.final_observation`).  Which guess trains best depends on the
data: ``extrapolate`` (``2 s_T - s_{T-1}``) was the best option on our scripted Dial demonstrations and
among the worst on human-like ones (docs/design.md#final-observation-auto).  With ``auto``,
:func:`train_auto` reads the bags once per option of ``final_options``, trains each on the same split
(``OUT/final_observation/<option>/``, a whole ``ompn_train`` run each, ``candidates`` included), scores
each run's bundled online detector on its own validation episodes and keeps the option
:func:`~ompn_ros.detect.tune.pick_within_error` prefers: the best validation objective (the domain's
headline metric) within one standard error, then the other metric, the rule that tunes the detector
itself.  The winner's checkpoints, log and reports are copied into ``OUT``;
``OUT/final_observation.json`` records the choice with every option's validation figures, and each
run's ``best/`` and ``last/`` the option they were trained with, in the one record of the choice
(:mod:`ompn_ros.app.final_record`), which later readers of the ``auto`` spec apply.

The first option trains alone when no episode lacks its final observation (nothing to choose) or
without validation labels (the label-free agreement does not rank runs, docs/design.md#best-of-two).

Cost: one training run per option, and one teacher-forced pass over the validation episodes each.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from ompn_ros.app.errors import TrainSetupError
from ompn_ros.app.final_record import record_final
from ompn_ros.app.read_report import write_read_report
from ompn_ros.app.training import TrainingData, bag_data, build_configs, labelled, run_training
from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.episode import Episode
from ompn_ros.data.reader import ReaderSpec, final_row_guessed
from ompn_ros.detect.defaults import objective_for
from ompn_ros.detect.grid import scores_from_p_hats
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.detect.tune import Metrics, Objective, pick_within_error, score_online, standard_error
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.train.candidates import copy_outputs
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.evaluation import teacher_forced_outputs
from ompn_ros.train.trainer import train_val_episodes

LOG = logging.getLogger("ompn_ros.train")

FINAL_DIR = "final_observation"
PUBLISHED = ("best", "last", "log.jsonl", "candidates", "candidates.json", "read_report.json",
             "read_report.txt")
"""What the chosen option's run contributes to ``OUT`` (``summary.json`` is written anew)."""


@dataclass(frozen=True)
class _Scored:
    """One validation episode's online scores and expansion distribution (a replay, teacher-forced)."""

    scores: np.ndarray
    p_hat: np.ndarray
    outputs: np.ndarray


@dataclass(frozen=True)
class Validated:
    """The bundled online detector of one run on its validation episodes: pooled, per episode, and
    the objective the domain tunes (``f1`` or ``align``)."""

    metrics: Metrics
    per_episode: list[Metrics]
    lengths: list[int]
    objective: Objective


def validate_online(run_dir: Path, val_eps: Sequence[Episode], cfg: TrainConfig) -> Validated:
    """Score ``run_dir/best``'s online detector (``detector.json``) on ``val_eps``.  O(Σ T)."""
    policy, _ = load_checkpoint(run_dir / "best")
    settings = load_detector_settings(run_dir / "best")
    outputs = teacher_forced_outputs(cast(OMPNPolicy, policy), val_eps, bptt=cfg.bptt,
                                     batch_size=cfg.eval_batch_size)
    p_hats = [x[:, :policy.config.n_slots + 1] for x in outputs]
    replays = [_Scored(s, p, x) for s, p, x in zip(scores_from_p_hats(p_hats), p_hats, outputs, strict=True)]

    def score(index: Sequence[int]) -> Metrics:
        return score_online([replays[i] for i in index], [val_eps[i] for i in index], settings.online,
                            settings.duration_model, settings.head)

    every = range(len(val_eps))
    return Validated(score(every), [score([i]) for i in every], [ep.length for ep in val_eps],
                     objective_for(policy.config.action_type))


@dataclass(frozen=True)
class OptionRun:
    """One option's finished run: its directory, ``summary.json`` and validation figures."""

    option: str
    out_dir: Path
    summary: dict[str, Any]
    validated: Validated


def choose(runs: Sequence[OptionRun]) -> int:
    """Index of the run :func:`~ompn_ros.detect.tune.pick_within_error` keeps (the first on ties)."""
    lengths = runs[0].validated.lengths
    if any(r.validated.lengths != lengths for r in runs):
        raise TrainSetupError("final_observation: auto: the options' validation episodes differ in length; "
                              "they must be the same episodes read with another row T")
    objective = runs[0].validated.objective
    return pick_within_error([r.validated.metrics for r in runs], objective,
                             lambda g: runs[g].validated.per_episode, lengths)


def _why_alone(data: TrainingData, cfg: TrainConfig) -> str | None:
    """Why the first option trains alone, or None when the options are to be compared."""
    if not final_row_guessed(data.facts):
        return "every episode has its final observation"
    if not labelled(cfg, data):
        return "without validation labels the runs cannot be ranked (docs/design.md#best-of-two)"
    return None


Shown = Callable[[str, TrainingData], None]


def train_auto(bags: list[str], config: dict[str, dict[str, Any]], spec: ReaderSpec, out: Path,
               resume: bool = False, quiet: bool = False,
               shown: Shown | None = None) -> tuple[dict[str, Any] | None, str]:
    """Train with ``final_observation: auto`` (module docstring); ``(summary, chosen option)``.
    ``shown(option, data)`` is called after each read (the CLI prints the reader's summary)."""
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        raise TrainSetupError("final_observation: auto trains one run per option in one process; under "
                              "torchrun set final_observation to one of final_options")
    options = spec.final_options
    first = bag_data(bags, config["data"], spec.with_final(options[0]))
    if shown is not None:
        shown(options[0], first)
    model_config, train_config = build_configs(config, first, out, resume, quiet)
    reason = _why_alone(first, train_config)
    if reason is not None or len(options) == 1:
        LOG.info("final_observation: auto keeps %s (%s)", options[0], reason or "one option")
        write_read_report(out, first.report)
        summary = run_training(first, model_config, train_config, out)
        _record(out, options[0])
        return summary, options[0]
    runs = []
    for option in options:
        data = first if option == options[0] else bag_data(bags, config["data"], spec.with_final(option))
        if shown is not None and data is not first:
            shown(option, data)
        runs.append(_train_option(option, data, config, out / FINAL_DIR / option, resume, quiet))
    winner = choose(runs)
    _publish(out, runs, winner)
    return json.loads((out / "summary.json").read_text(encoding="utf-8")), runs[winner].option


def _train_option(option: str, data: TrainingData, config: dict[str, dict[str, Any]], out: Path,
                  resume: bool, quiet: bool) -> OptionRun:
    """Train ``data`` (the bags read with ``option``) into ``out`` and score it on validation."""
    LOG.info("final_observation: auto: training with row T read as '%s' in %s", option, out)
    out.mkdir(parents=True, exist_ok=True)
    model_config, train_config = build_configs(config, data, out, resume and (out / "train_state").exists(),
                                               quiet)
    write_read_report(out, data.report)
    summary = run_training(data, model_config, train_config, out)
    assert summary is not None  # one process (train_auto refuses torchrun)
    _record(out, option)
    _, val_eps, _ = train_val_episodes(data.episodes, train_config)
    return OptionRun(option, out, summary, validate_online(out, val_eps, train_config))


def _record(run_dir: Path, option: str) -> None:
    """Name ``option`` beside the run's checkpoints, for later readers of an ``auto`` spec."""
    for name in ("best", "last"):
        if (run_dir / name).is_dir():
            record_final(run_dir / name, option)


def _publish(out: Path, runs: Sequence[OptionRun], winner: int) -> None:
    """Copy the winner's outputs into ``out``; write ``summary.json`` and the record of the choice with
    the comparison (:func:`~ompn_ros.app.final_record.record_final`)."""
    chosen = runs[winner]
    copy_outputs(chosen.out_dir, out, PUBLISHED)
    summary = {**chosen.summary, "final_observation": chosen.option,
               "train_seconds": sum(float(r.summary["train_seconds"]) for r in runs),
               "frames": sum(int(r.summary["frames"]) for r in runs)}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, sort_keys=True))
    objective = chosen.validated.objective
    rows = [{"option": r.option, "dir": f"{FINAL_DIR}/{r.option}",
             "best_iteration": int(r.summary["best_iteration"]),
             "val_f1_1": r.validated.metrics["f1_tol1"], "val_align": r.validated.metrics["align_strict"],
             "standard_error": standard_error(r.validated.per_episode, r.validated.lengths,
                                              objective)}
            for r in runs]
    record_final(out, chosen.option, {
        "objective": objective, "validation_episodes": len(chosen.validated.lengths),
        "rule": "the bundled online detector on validation, best objective within one standard error, then "
                "the other metric (docs/design.md#final-observation-auto)",
        "options": rows})
    LOG.info("final_observation: auto: %s; kept '%s'",
             ", ".join(f"{r['option']}: F1@1 {r['val_f1_1']:.3f} align {r['val_align']:.3f}" for r in rows),
             chosen.option)


__all__ = ["FINAL_DIR", "OptionRun", "Validated", "choose", "train_auto", "validate_online"]
