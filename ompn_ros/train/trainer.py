"""Behaviour cloning of an OMPN with the done step (paper §3.2, Alg. 1; docs/craft.md §4, docs/dial.md §4).

One iteration = one Adam update on a batch of whole, zero-padded episodes (teacher forcing from the
initial memory, memory detached every ``bptt`` steps, loss = mean ``−log p'`` per valid step
including the appended done step, gradient L2 norm clipped to ``clip_norm``).  Each epoch reshuffles
the training split (seeded by ``(seed, epoch)``) and cuts it into consecutive batches.

Every ``eval_every`` iterations (and after the last one) the validation split is evaluated by
:func:`ompn_ros.train.evaluation.evaluate`: teacher-forced loss plus task-decomposition
metrics and the label-free ``agreement``.  With ``patience`` > 0 training stops once the selection
criterion has not improved for that many evaluations (``iterations`` is the cap).  Checkpoints
under ``out_dir``:

* ``best/``: the policy with the best validation score.  **Selection** (``selection``):
  ``'align'`` (default) = highest validation alignment accuracy of the domain's detector (Top-K for
  discrete actions, automatic threshold for continuous ones), ties broken by the lower validation
  loss; ``'f1_tol1'`` likewise with F1(tol=1); ``'val_loss'`` = lowest validation loss (what
  ompn_dial does); ``'agreement'`` = the label-free criterion of
  :func:`ompn_ros.detect.calibrate.agreement` (how well a causal detector reproduces the model's
  own whole-episode segmentation), used instead of ``'align'``/``'f1_tol1'`` when the validation
  episodes have no labels or ``labels='none'`` hides them.  The authors' Craft code selected by
  free-run return, which needs an environment and is not available offline.
* ``last/``: the policy after the latest evaluation.
* ``best/detector.json`` and ``last/detector.json``: the detector settings that travel with the
  checkpoint, written when training ends (:mod:`ompn_ros.train.detector`): tuned on the validation
  labels, or calibrated without labels.
* ``train_state/``: a resumable state (weights + Adam state, safetensors + JSON); ``resume=True``
  continues from it and, with the same seed and data, reaches bitwise the same weights as an
  uninterrupted run.
* ``log.jsonl``: one JSON line per evaluation; TensorBoard scalars under ``tb/`` if enabled.
* ``attempt.json`` and ``attempts/<k>/``: with the restart rule, the further initialisations after a
  weak start and which attempt the files above hold (:mod:`ompn_ros.train.restart`).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NoReturn, cast

import numpy as np
import torch

from ompn_ros.atomic import write_failure
from ompn_ros.data.cuts import drop_still
from ompn_ros.data.episode import Episode
from ompn_ros.detect.reference import agreement
from ompn_ros.detect.settings import DetectorSettings
from ompn_ros.model.build import PolicyModule, build_policy
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint
from ompn_ros.model.config import ActionNorm, OMPNConfig
from ompn_ros.model.errors import ConfigError
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.train.averaging import WeightAverage
from ompn_ros.train.batching import (
    Batch,
    ObsNormalization,
    action_normalization,
    collate,
    epoch_batches,
    obs_normalization,
    split_train_val,
)
from ompn_ros.train.candidates import best_of, candidate_rows
from ompn_ros.train.config import LABELLED_SELECTIONS, TrainConfig
from ompn_ros.train.detector import HeadData
from ompn_ros.train.detector import bundle as bundle_detector
from ompn_ros.train.device import batch_to, device_of, resolve_device
from ompn_ros.train.distill import distill_loss, teacher_p_hats, with_teacher_targets
from ompn_ros.train.distributed import (
    DistContext,
    all_reduce_gradients,
    all_reduce_sum,
    broadcast_module,
)
from ompn_ros.train.errors import TrainConfigError, TrainDataError, TrainStateError
from ompn_ros.train.evaluation import evaluate, teacher_forced_outputs
from ompn_ros.train.interrupt import StopRequest, TrainingInterrupted
from ompn_ros.train.precision import resolve_bf16
from ompn_ros.train.restart import (
    attempt_config,
    attempt_row,
    clear_attempts,
    finished_attempts,
    keep_attempt,
    kept_attempt,
    read_attempt,
    restart_reason,
    rule_applies,
    start_attempt,
    weak_start,
)
from ompn_ros.train.state import (
    clean_state_root,
    latest_state_dir,
    optimizer_from_files,
    read_state,
    save_state,
)
from ompn_ros.train.threads import resolve_threads

LOG = logging.getLogger("ompn_ros.train")

@dataclass
class TrainResult:
    """What :func:`train` returns (rank 0 holds the evaluation history)."""

    policy: PolicyModule
    iterations: int
    best_iteration: int
    best_metrics: dict[str, float]
    last_metrics: dict[str, float]
    history: list[dict[str, float]] = field(default_factory=list)
    out_dir: str | None = None
    train_seconds: float = 0.0
    frames: int = 0
    stopped_early: bool = False
    selection: str = ""
    detectors: dict[str, DetectorSettings] = field(default_factory=dict)
    restarts: int = 0
    """How many more initialisations the restart rule trained (:mod:`ompn_ros.train.restart`)."""
    weak_start: bool = False
    """The restart rule flagged this attempt (internal to :func:`train`)."""
    candidates: list[dict[str, Any]] = field(default_factory=list)
    """With ``candidates`` > 1: every candidate's seed, best iteration and score (the one returned won)."""


def learning_rate(cfg: TrainConfig, iteration: int) -> float:
    """The learning rate of update number ``iteration`` (1-based) under ``cfg.lr_schedule``."""
    if cfg.lr_schedule == "cosine":
        return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * (iteration - 1) / cfg.iterations))
    return cfg.lr


def dropout_inputs(obs: torch.Tensor, p: float, key: tuple[int, int, int]) -> torch.Tensor:
    """Inverted dropout of ``obs`` with probability ``p`` from a generator seeded by ``key``."""
    generator = torch.Generator().manual_seed(int(np.random.SeedSequence(key).generate_state(1)[0]))
    keep = torch.rand(obs.shape, generator=generator) >= p
    return torch.where(keep, obs / (1.0 - p), 0.0)


def effective_selection(cfg: TrainConfig, labelled: bool) -> str:
    """The criterion a run selects by: ``cfg.selection``, or ``'agreement'`` when it needs labels
    that the validation split does not have (or that ``cfg.labels = 'none'`` hides)."""
    if cfg.selection in LABELLED_SELECTIONS and not (labelled and cfg.labels == "auto"):
        return "agreement"
    return cfg.selection


def evaluations_since_best(history: Sequence[dict[str, float]], best_iteration: int) -> int:
    """Evaluations after the best one (what ``patience`` is compared with)."""
    return sum(1 for record in history if record["iteration"] > best_iteration)


def selection_start(cfg: TrainConfig, selection: str) -> int:
    """The last iteration whose evaluation cannot be selected: ``cfg.agreement_warmup`` under the
    label-free ``'agreement'``, else 0 (every evaluation can)."""
    return cfg.agreement_warmup if selection == "agreement" else 0


def eligible(cfg: TrainConfig, selection: str, iteration: int) -> bool:
    """Whether the evaluation at ``iteration`` may become ``best/`` (the run's last one always may)."""
    return iteration > selection_start(cfg, selection) or iteration >= cfg.iterations


def early_agreement_warning(
    selection: str, history: Sequence[dict[str, float]], best_iteration: int
) -> str | None:
    """One line when the label-free ``agreement`` chose a checkpoint from the first fifth of a run
    (at least 5 evaluations) whose validation loss was still falling afterwards: early models can
    agree with themselves trivially (on Dial it chose iteration 20 of 220, validation alignment 0.27
    against 0.91 for the last checkpoint; docs/design.md#agreement-warm-up).  ``None`` otherwise."""
    if selection != "agreement" or len(history) < 5:
        return None
    rank = next((i for i, record in enumerate(history) if record["iteration"] == best_iteration), None)
    if rank is None or rank >= len(history) // 5:
        return None
    best_loss, last_loss = history[rank].get("loss", math.nan), history[-1].get("loss", math.nan)
    if not last_loss < best_loss:
        return None
    return (f"best/ was chosen by the label-free agreement at iteration {best_iteration} of "
            f"{int(history[-1]['iteration'])}, while the validation loss still fell ({best_loss:.4g} -> "
            f"{last_loss:.4g}): early models can agree trivially; compare last/ before using best/ "
            "(docs/design.md#agreement-warm-up)")


def selection_key(metrics: dict[str, float], selection: str) -> tuple[float, float]:
    """Larger is better: ``(score, −val_loss)``; for ``'val_loss'`` the score is ``−loss``."""
    loss = float(metrics.get("loss", math.inf))
    if selection == "val_loss":
        return (-loss, 0.0)
    return (float(metrics.get(selection, -math.inf)), -loss)


# --- training ------------------------------------------------------------------------------------


def train_val_episodes(
    episodes: Sequence[Episode], cfg: TrainConfig
) -> tuple[list[Episode], list[Episode], int]:
    """``(train, validation, n_val)`` as :func:`train` splits ``episodes`` (``val_ratio``, and
    ``split_seed``, or ``seed`` when it is None).

    The validation list is capped at ``eval_episodes``; with ``val_ratio = 0`` it is the training
    split itself and ``n_val`` is 0.
    """
    split_seed = cfg.seed if cfg.split_seed is None else cfg.split_seed
    train_idx, val_idx = split_train_val(len(episodes), cfg.val_ratio, split_seed)
    train_eps = [episodes[i] for i in train_idx]
    val_eps = [episodes[i] for i in val_idx] if len(val_idx) else list(train_eps)
    if cfg.eval_episodes:
        val_eps = val_eps[: cfg.eval_episodes]
    return train_eps, val_eps, len(val_idx)


def _check_dropout_range(cfg: TrainConfig, model_config: OMPNConfig) -> None:
    if cfg.obs_dropout_range and cfg.obs_dropout_range[1] > model_config.obs_dim:
        raise TrainConfigError(
            f"TrainConfig.obs_dropout_range {cfg.obs_dropout_range} reaches past the model's "
            f"obs_dim={model_config.obs_dim}"
        )


def _check_episodes(episodes: Sequence[Episode], model_config: OMPNConfig) -> None:
    if len(episodes) < 1:
        raise TrainDataError("train() needs at least one episode")
    for i, ep in enumerate(episodes):
        if ep.observations.shape[1] != model_config.obs_dim:
            raise TrainDataError(
                f"episode #{i} (task '{ep.task}', seed {ep.seed}) has {ep.observations.shape[1]} observation "
                f"features but the model expects obs_dim={model_config.obs_dim}"
            )
        if ep.length < 1:
            raise TrainDataError(f"episode #{i} (task '{ep.task}', seed {ep.seed}) has no steps")


def _scalars(metrics: dict[str, Any]) -> dict[str, float]:
    return {k: float(v) for k, v in metrics.items() if isinstance(v, int | float) and not isinstance(v, bool)}


class _Sinks:
    """Log file and optional TensorBoard writer (rank 0 only)."""

    def __init__(self, out_dir: Path | None, tensorboard: bool) -> None:
        self.log_path = out_dir / "log.jsonl" if out_dir is not None else None
        self.writer = None
        if tensorboard and out_dir is not None:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:  # pragma: no cover - tensorboard is optional
                LOG.warning("tensorboard is not installed; TensorBoard scalars are disabled")
            else:
                self.writer = SummaryWriter(log_dir=str(out_dir / "tb"))

    def write(self, iteration: int, frames: int, record: dict[str, float]) -> None:
        if self.log_path is not None:
            try:
                with self.log_path.open("a", encoding="utf-8") as handle:
                    handle.write(json.dumps({"iteration": iteration, "frames": frames, **record}) + "\n")
            except OSError as exc:  # a full disk: one line naming the log
                raise write_failure(self.log_path, exc) from exc
        if self.writer is not None:
            for key, value in record.items():
                self.writer.add_scalar(key, value, global_step=iteration)
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _patience_exhausted(
    cfg: TrainConfig, selection: str, history: Sequence[dict[str, float]], best_iteration: int
) -> bool:
    if not cfg.patience or not history:
        return False
    since = max(best_iteration, selection_start(cfg, selection))
    return evaluations_since_best(history, since) >= cfg.patience


def validation_metrics(
    policy: PolicyModule, val_eps: Sequence[Episode], cfg: TrainConfig
) -> dict[str, float]:
    """The scalars of :func:`evaluate` on the validation split plus the label-free ``agreement``
    (:func:`ompn_ros.detect.calibrate.agreement`), logged at every evaluation whatever selects."""
    result = evaluate(
        cast(OMPNPolicy, policy),  # evaluate() only uses forward_sequence and config
        val_eps,
        bptt=cfg.bptt,
        batch_size=cfg.eval_batch_size,
        no_done_loss=cfg.no_done_loss,
        keep_p_hat=True,
    )
    metrics = _scalars(result)
    metrics["agreement"] = agreement(result["p_hat"])
    return metrics


HEAD_TRAIN_EPISODES = 500
"""The most training episodes the boundary head is fitted on (its cost grows with their steps); from
more, every k-th is taken, so that bags recorded task by task are all represented."""


def head_fit_episodes(train_eps: Sequence[Episode]) -> list[Episode]:
    """The training episodes the boundary head is fitted on: all, or every k-th of more than
    :data:`HEAD_TRAIN_EPISODES`."""
    return list(train_eps[::math.ceil(len(train_eps) / HEAD_TRAIN_EPISODES) or 1])


def _head_data(policy: OMPNPolicy, train_eps: Sequence[Episode], val_eps: Sequence[Episode],
               val_outputs: list[np.ndarray], cfg: TrainConfig) -> HeadData | None:
    """The boundary head's inputs when ``train.boundary_head`` is on and every episode is labelled."""
    fit = head_fit_episodes(train_eps)
    labelled = all(ep.subtask is not None for ep in (*fit, *val_eps))
    if not (cfg.boundary_head and cfg.labels == "auto" and fit and labelled):
        return None
    train_outputs = teacher_forced_outputs(policy, fit, bptt=cfg.bptt, batch_size=cfg.eval_batch_size)
    return HeadData(train_outputs, fit, val_outputs, seed=cfg.seed)


def bundle_detectors(
    out_dir: Path, val_eps: Sequence[Episode], cfg: TrainConfig, train_eps: Sequence[Episode] = ()
) -> dict[str, DetectorSettings]:
    """Write ``detector.json`` into ``best/`` and ``last/`` (see :mod:`ompn_ros.train.detector`); with
    ``train_eps``, the boundary head is fitted on them (``train.boundary_head``)."""
    written: dict[str, DetectorSettings] = {}
    for name in ("best", "last"):
        directory = out_dir / name
        if not (directory / "config.json").is_file():
            continue
        policy = cast(OMPNPolicy, load_checkpoint(directory)[0])
        # p_hat is the first n + 1 columns of the outputs the head reads: one pass for both
        val_outputs = teacher_forced_outputs(policy, val_eps, bptt=cfg.bptt, batch_size=cfg.eval_batch_size)
        p_hats = [x[:, :policy.config.n_slots + 1] for x in val_outputs]
        written[name] = bundle_detector(
            directory, p_hats, val_eps, action_type=policy.config.action_type,
            use_labels=cfg.labels == "auto", lag=cfg.detector_lag, max_delay=cfg.detector_delay,
            head=_head_data(policy, train_eps, val_eps, val_outputs, cfg),
        )
    return written


def _with_action_norm(model_config: OMPNConfig, action_norm: ActionNorm) -> OMPNConfig:
    """``model_config`` with ``train.action_norm`` applied (the option lives in the checkpoint's config)."""
    if action_norm == model_config.action_norm:
        return model_config
    try:
        return replace(model_config, action_norm=action_norm)
    except ConfigError as exc:
        raise TrainConfigError(f"TrainConfig.action_norm={action_norm!r}: {exc}") from exc


def train(
    episodes: Sequence[Episode],
    model_config: OMPNConfig,
    train_config: TrainConfig,
    *,
    dist_ctx: DistContext | None = None,
    callback: Callable[[int, dict[str, float]], None] | None = None,
) -> TrainResult:
    """Train an :class:`~ompn_ros.model.policy.OMPNPolicy` by behaviour cloning (see module docstring).

    With ``restart_at`` set, a run that starts weak is followed by a new initialisation on the same
    split and the better of the two by validation is kept (:mod:`ompn_ros.train.restart`); ``resume``
    continues the attempt ``out_dir`` records.
    With ``candidates`` > 1, that many initialisations train on the split and the best by validation is
    kept (:mod:`ompn_ros.train.candidates`); the result's ``train_seconds`` and ``frames`` sum them.

    Args:
        episodes: all demonstrations; split into train/validation by ``val_ratio`` and ``seed``.
        model_config: an :class:`~ompn_ros.model.config.OMPNConfig` matching the episodes.
        train_config: a :class:`TrainConfig`.
        dist_ctx: the torchrun context (default: single process).
        callback: called after every update as ``callback(iteration, stats)``; raising from it stops
            training (used to simulate a kill in tests).
    """
    ctx = dist_ctx or DistContext()
    episodes = _without_still(episodes, model_config.still_tolerance, ctx)
    if train_config.candidates > 1:
        return _train_candidates(episodes, model_config, train_config, ctx, callback)
    out_dir = Path(train_config.out_dir) if train_config.out_dir is not None else None
    attempt = read_attempt(out_dir) if train_config.resume else 0
    rows = finished_attempts(out_dir) if train_config.resume else []
    if not train_config.resume and ctx.is_main:
        clear_attempts(out_dir)
    results: dict[int, TrainResult] = {}
    while True:
        sub = attempt_config(train_config, attempt)
        result = results[attempt] = _Attempt(episodes, model_config, sub, attempt, ctx, callback).run()
        rows.append(attempt_row(attempt, sub.seed, _best_score(result), result.best_iteration,
                                result.train_seconds, result.frames))
        if not result.weak_start:
            break
        attempt += 1
        reason = restart_reason(train_config, result.selection, _scores(train_config, result))
        if ctx.is_main:
            LOG.warning("%s (attempt %d of at most %d)", reason, attempt + 1, train_config.restarts + 1)
            start_attempt(out_dir, attempt, attempt_config(train_config, attempt).seed, reason, rows)
        train_config = replace(train_config, resume=False)
    return _kept(episodes, model_config, train_config, ctx, results, rows)


def _without_still(episodes: Sequence[Episode], tolerance: float, ctx: DistContext) -> Sequence[Episode]:
    """The episodes as the model is stepped on them: with ``still_tolerance`` > 0 without their still
    observations (:func:`~ompn_ros.data.cuts.drop_still`; idempotent, so nested calls cost only time)."""
    if tolerance <= 0:
        return episodes
    reduced = [drop_still(ep, tolerance)[0] for ep in episodes]
    before, after = sum(ep.length for ep in episodes), sum(ep.length for ep in reduced)
    if ctx.is_main and after < before:
        LOG.info("still_tolerance %g: %d of %d steps are still and not stepped", tolerance, before - after,
                 before)
    return reduced


def _best_score(result: TrainResult) -> float:
    return float(result.best_metrics.get(result.selection, -math.inf))


def _scores(cfg: TrainConfig, result: TrainResult) -> list[tuple[int, float]]:
    """``(iteration, criterion)`` of the selectable evaluations of ``result``'s history."""
    its = [int(h["iteration"]) for h in result.history]
    return [(it, selection_key(h, result.selection)[0]) for it, h in zip(its, result.history, strict=True)
            if eligible(cfg, result.selection, it)]


def _kept(episodes: Sequence[Episode], model_config: OMPNConfig, cfg: TrainConfig, ctx: DistContext,
          results: dict[int, TrainResult], rows: list[dict[str, Any]]) -> TrainResult:
    """The result of the attempt with the best validation criterion, published in ``OUT`` when
    there was more than one (:func:`~ompn_ros.train.restart.keep_attempt`); the cost sums them all."""
    last = max(results)
    if last == 0:
        return results[0]
    kept = int(all_reduce_sum(float(kept_attempt(rows) if ctx.is_main else 0), ctx))
    if kept not in results:  # a resumed run kept an attempt finished before the kill: reload it
        again = attempt_config(replace(cfg, resume=True), kept)
        results[kept] = _Attempt(episodes, model_config, again, kept, ctx, None).run()
    if ctx.is_main:
        keep_attempt(Path(cfg.out_dir) if cfg.out_dir is not None else None, kept, rows)
        LOG.info("restart rule: attempts %s; kept attempt %d", ", ".join(
            f"{r['attempt']}: {float(r['best']):.3f}" for r in rows), kept)
    return replace(results[kept], restarts=last, out_dir=cfg.out_dir, weak_start=False,
                   train_seconds=sum(float(r["train_seconds"]) for r in rows),
                   frames=sum(int(r["frames"]) for r in rows))


def _train_candidates(
    episodes: Sequence[Episode], model_config: OMPNConfig, cfg: TrainConfig, ctx: DistContext,
    callback: Callable[[int, dict[str, float]], None] | None,
) -> TrainResult:
    """:func:`train` with ``cfg.candidates`` > 1: the winner's result, with the cost of all of them."""
    def one(sub: TrainConfig) -> TrainResult:
        return train(episodes, model_config, sub, dist_ctx=ctx, callback=callback)

    winner, everyone = best_of(cfg, one, is_main=ctx.is_main)
    if ctx.is_main and winner.selection not in LABELLED_SELECTIONS:
        LOG.warning("candidates compared by %s, which does not rank weak runs below good ones "
                    "(docs/design.md#best-of-two)", winner.selection)
    return replace(winner, out_dir=cfg.out_dir, candidates=candidate_rows(everyone),
                   train_seconds=sum(c.result.train_seconds for c in everyone),
                   frames=sum(c.result.frames for c in everyone))


@dataclass
class _Selected:
    """What an attempt has trained and selected so far; a resume restores it (:func:`_resume`)."""

    iteration: int = 0
    frames: int = 0
    best_key: tuple[float, float] = (-math.inf, -math.inf)
    best_iteration: int = 0
    best_metrics: dict[str, float] = field(default_factory=dict)
    last_metrics: dict[str, float] = field(default_factory=dict)
    history: list[dict[str, float]] = field(default_factory=list)


@dataclass
class _Models:
    """The trained policy, its weight average (``ema_decay``) and the optimizer."""

    policy: PolicyModule
    average: WeightAverage | None
    optimizer: torch.optim.Optimizer

    @property
    def evaluated(self) -> PolicyModule:
        """The weights that are evaluated, selected and exported (the average when ``ema_decay`` is on)."""
        return self.average.module if self.average is not None else self.policy  # type: ignore[return-value]


def _split(
    episodes: Sequence[Episode], model_config: OMPNConfig, cfg: TrainConfig, ctx: DistContext
) -> tuple[list[Episode], list[Episode], int, str]:
    """``(train, validation, n_val, selection)``: the split, the teachers' targets (``distill_from``) and
    the selection criterion the validation labels allow (warned when it differs from the asked one)."""
    train_eps, val_eps, n_val = train_val_episodes(episodes, cfg)
    if cfg.distill_from:
        targets = teacher_p_hats(cfg.distill_from, train_eps, model_config, cfg.eval_batch_size)
        train_eps = with_teacher_targets(train_eps, targets)
    if not n_val:
        LOG.warning("val_ratio=0: validation metrics are computed on the training split")
    selection = effective_selection(cfg, all(ep.subtask is not None for ep in val_eps))
    if selection != cfg.selection and ctx.is_main:
        LOG.warning("selection '%s' needs validation labels (%s): selecting by label-free '%s' instead",
                    cfg.selection, "hidden by labels=none" if cfg.labels == "none" else "the data has none",
                    selection)
    return train_eps, val_eps, n_val, selection


def _models(model_config: OMPNConfig, cfg: TrainConfig, train_eps: Sequence[Episode],
            ctx: DistContext, device: torch.device | None = None) -> _Models:
    """A new policy with the training split's normalisations on ``device`` (CPU: None), its average and
    its optimizer."""
    policy = build_policy(model_config)  # OMPNPolicy or, with arch='lstm', the LSTM baseline
    if ctx.is_main:  # the other ranks get rank 0's statistics (broadcast): they read only their shards
        norm: ObsNormalization = obs_normalization(train_eps, cfg.obs_norm)
        policy.set_obs_normalization(norm.mean, norm.scale)
        if model_config.action_norm == "standard":
            mean, std = action_normalization(train_eps)
            policy.set_action_normalization(mean, std)
    if device is not None:
        policy.to(device)
    broadcast_module(policy, ctx)
    policy.train()
    average = WeightAverage(policy, cfg.ema_decay) if cfg.ema_decay else None
    optimizer: torch.optim.Optimizer = (
        torch.optim.AdamW(policy.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        if cfg.weight_decay
        else torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    )
    return _Models(policy, average, optimizer)


def _resume(state_root: Path, models: _Models, model_config: OMPNConfig, cfg: TrainConfig,
            selection: str, log: bool) -> _Selected:
    """Load the newest saved state under ``state_root`` into ``models``; what it had selected (a fresh
    :class:`_Selected` when nothing was saved).  Raises :class:`TrainStateError` on a state that
    cannot continue this run."""
    state_dir = latest_state_dir(state_root)
    if state_dir is None:
        return _Selected()
    doc, opt_tensors = read_state(state_dir)
    loaded, _ = load_checkpoint(state_dir / "model")
    if loaded.config.to_dict() != model_config.to_dict():
        raise TrainStateError(
            f"cannot resume from {state_dir}: its model config differs from the requested one"
        )
    models.policy.load_state_dict(loaded.state_dict())
    if models.average is not None:
        if not (state_dir / "ema").is_dir():
            raise TrainStateError(
                f"cannot resume from {state_dir} with ema_decay={cfg.ema_decay}: the state has no "
                "averaged weights (it was saved with ema_decay=0)"
            )
        models.average.module.load_state_dict(load_checkpoint(state_dir / "ema")[0].state_dict())
    optimizer_from_files(models.optimizer, opt_tensors, doc["param_groups"])
    done = _Selected(
        iteration=int(doc["iteration"]), frames=int(doc.get("frames", 0)),
        best_iteration=int(doc.get("best_iteration", 0)), best_metrics=doc.get("best_metrics", {}),
        last_metrics=doc.get("last_metrics", {}), history=doc.get("history", []),
    )
    if done.best_metrics:
        done.best_key = selection_key(done.best_metrics, selection)
    if done.best_iteration and not eligible(cfg, selection, done.best_iteration):
        raise TrainStateError(
            f"cannot resume from {state_dir}: its best/ is from iteration {done.best_iteration}, "
            f"inside agreement_warmup={cfg.agreement_warmup}; continue it with --set "
            "train.agreement_warmup=0"
        )
    if log:
        LOG.info("resumed from %s at iteration %d", state_dir, done.iteration)
    return done


def _save_all(out_dir: Path, models: _Models, done: _Selected, extra: dict[str, Any], is_best: bool) -> None:
    """``best/`` (when ``is_best``), ``last/`` and the resumable state of ``done.iteration``."""
    evaluated = models.evaluated
    if is_best:
        save_checkpoint(out_dir / "best", evaluated, extra=extra)
    save_checkpoint(out_dir / "last", evaluated, extra=extra)
    _save_state(out_dir, models, done, extra)


def _save_state(out_dir: Path, models: _Models, done: _Selected, extra: dict[str, Any]) -> None:
    """The resumable state of ``done.iteration`` (weights, Adam state, selection record)."""
    payload = {
        "frames": done.frames,
        "best_iteration": done.best_iteration,
        "best_metrics": done.best_metrics,
        "last_metrics": extra["metrics"],
        "history": done.history,
    }

    def save_models(model_dir: Path) -> None:
        save_checkpoint(model_dir, models.policy, extra=extra)
        if models.average is not None:
            save_checkpoint(model_dir.parent / "ema", models.evaluated, extra=extra)

    save_state(out_dir / "train_state", done.iteration, save_models, models.optimizer, payload)


class _Attempt:
    """One attempt of :func:`train` with ``cfg`` already that attempt's
    (:func:`~ompn_ros.train.restart.attempt_config`): set up, then :meth:`run`."""

    def __init__(self, episodes: Sequence[Episode], model_config: OMPNConfig, cfg: TrainConfig, attempt: int,
                 ctx: DistContext, callback: Callable[[int, dict[str, float]], None] | None) -> None:
        device = resolve_device(cfg.device)
        if cfg.bf16 and device.type != "cpu" and ctx.is_main:
            LOG.warning("train.bf16 applies to the CPU forward only: training on %s runs in float32", device)
        if cfg.bf16 and (device.type != "cpu" or not resolve_bf16(cfg.bf16, cfg.force_bf16)):
            cfg = replace(cfg, bf16=False)  # what runs is what the checkpoints record
        model_config = _with_action_norm(model_config, cfg.action_norm)
        _check_episodes(episodes, model_config)
        _check_dropout_range(cfg, model_config)
        self.threads = resolve_threads(cfg.threads)
        if self.threads:
            torch.set_num_threads(self.threads)
        torch.manual_seed(cfg.seed)
        self.cfg, self.model_config, self.attempt = cfg, model_config, attempt
        self.ctx, self.callback = ctx, callback
        self.train_eps, self.val_eps, n_val, self.selection = _split(episodes, model_config, cfg, ctx)
        self.models = _models(model_config, cfg, self.train_eps, ctx, device)
        self.out_dir = Path(cfg.out_dir) if cfg.out_dir is not None else None
        if self.out_dir is not None and ctx.is_main:
            clean_state_root(self.out_dir / "train_state")  # temporaries of a killed earlier run
        self.extra_base = {"train_config": cfg.to_dict(), "obs_norm": cfg.obs_norm,
                           "n_train": len(self.train_eps), "n_val": n_val}
        self.done = _Selected()
        if cfg.resume and self.out_dir is not None:
            self.done = _resume(self.out_dir / "train_state", self.models, model_config, cfg, self.selection,
                                log=ctx.is_main)
        if self.out_dir is not None and ctx.is_main:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        self.sinks = _Sinks(self.out_dir, cfg.tensorboard) if ctx.is_main else None

    def _update(self, iteration: int, per_epoch: int) -> dict[str, float]:
        """One optimizer update (this rank's shard of the epoch's batch) and its statistics."""
        cfg, models = self.cfg, self.models
        epoch, index = divmod(iteration - 1, per_epoch)
        global_idx = epoch_batches(len(self.train_eps), cfg.batch_size, cfg.seed, epoch)[index]
        shard = global_idx[self.ctx.rank :: self.ctx.world_size]
        for group in models.optimizer.param_groups:
            group["lr"] = learning_rate(cfg, iteration)
        stats = train_step(models.policy, models.optimizer, [self.train_eps[i] for i in shard],
                           self.model_config, cfg, self.ctx, iteration=iteration)
        self.done.frames += int(stats["global_valid"])
        if models.average is not None:
            models.average.update(models.policy, iteration)
        return stats

    def _evaluate(self, iteration: int, stats: dict[str, float]) -> bool:
        """Rank 0: validate, keep the best, log and save.  Every rank: whether to stop early."""
        cfg, done = self.cfg, self.done
        stopped_early = False
        if self.ctx.is_main:
            metrics = validation_metrics(self.models.evaluated, self.val_eps, cfg)
            metrics["train_loss"] = stats["loss"]
            key = selection_key(metrics, self.selection)
            is_best = key > done.best_key and eligible(cfg, self.selection, iteration)
            if is_best:
                done.best_key, done.best_iteration, done.best_metrics = key, iteration, metrics
            done.last_metrics = metrics
            done.history.append({"iteration": float(iteration), **metrics})
            LOG.info("it %d  train_loss %.4f  val_loss %.4f  align %.3f  f1_tol1 %.3f  agreement %.3f%s",
                     iteration, stats["loss"], metrics["loss"], metrics.get("align", float("nan")),
                     metrics.get("f1_tol1", float("nan")), metrics["agreement"],
                     "  *best*" if is_best else "")
            assert self.sinks is not None
            self.sinks.write(iteration, done.frames, metrics)
            if self.out_dir is not None:
                extra = {**self.extra_base, "iteration": iteration, "metrics": metrics}
                _save_all(self.out_dir, self.models, done, extra, is_best)
            stopped_early = _patience_exhausted(cfg, self.selection, done.history, done.best_iteration)
        stopped_early = bool(all_reduce_sum(float(stopped_early), self.ctx))
        if stopped_early and self.ctx.is_main:
            LOG.info("early stop at iteration %d: %s has not improved for %d evaluations (best at iteration "
                     "%d)", iteration, self.selection, cfg.patience, done.best_iteration)
        return stopped_early

    def _loop(self) -> bool:
        """Update until the last iteration or an early stop: whether it stopped early."""
        cfg, done = self.cfg, self.done
        stopped_early = _patience_exhausted(cfg, self.selection, done.history, done.best_iteration)
        per_epoch = math.ceil(len(self.train_eps) / cfg.batch_size)
        progress = None
        if cfg.progress and self.ctx.is_main:
            from tqdm import tqdm

            progress = tqdm(total=cfg.iterations, initial=done.iteration, desc="train", unit="it",
                            leave=False)
        try:
            with StopRequest(enabled=self.ctx.world_size == 1) as stop:
                if self.ctx.is_main and self.attempt == 0:
                    LOG.info("training from iteration %d, torch threads: %d (train.threads=%s; Ctrl-C "
                             "stops after the update under way)", done.iteration, torch.get_num_threads(),
                             cfg.threads)
                while done.iteration < cfg.iterations and not stopped_early:
                    done.iteration += 1
                    stats = self._update(done.iteration, per_epoch)
                    if progress is not None:
                        progress.update(1)
                        progress.set_postfix(loss=f"{stats['loss']:.3f}")
                    if self.callback is not None:
                        self.callback(done.iteration, stats)
                    if done.iteration % cfg.eval_every == 0 or done.iteration == cfg.iterations:
                        stopped_early = self._evaluate(done.iteration, stats)
                    if stop.requested:
                        self._interrupted(saved=True)
        except TrainingInterrupted:
            raise
        except KeyboardInterrupt:
            self._interrupted(saved=False)
        finally:
            if progress is not None:
                progress.close()
            if self.sinks is not None:
                self.sinks.close()
        return stopped_early

    def _interrupted(self, saved: bool) -> NoReturn:
        """Ctrl-C (:mod:`ompn_ros.train.interrupt`): save the state of the update just finished
        (``saved``) and raise :class:`TrainingInterrupted` naming what a resume continues from."""
        iteration = self.done.iteration
        if self.out_dir is None or not self.ctx.is_main:
            raise TrainingInterrupted(f"interrupted at iteration {iteration} (nothing is kept without an "
                                      "output directory)")
        if saved:
            _save_state(self.out_dir, self.models, self.done, {**self.extra_base, "iteration": iteration,
                                                               "metrics": self.done.last_metrics})
        latest = latest_state_dir(self.out_dir / "train_state")
        if latest is None:
            raise TrainingInterrupted(f"interrupted at iteration {iteration}, before the first saved state: "
                                      "run the command again to start over")
        kept = int(json.loads((latest / "state.json").read_text(encoding="utf-8"))["iteration"])
        raise TrainingInterrupted(f"interrupted: the state of iteration {kept} is in "
                                  f"{self.out_dir / 'train_state'}; add --resume to the same command to "
                                  "go on")

    def run(self) -> TrainResult:
        """Train, bundle the detectors with ``best/`` and ``last/`` and say whether the restart rule
        flags the attempt."""
        cfg, done = self.cfg, self.done
        started = time.perf_counter()
        labelled = self.selection in LABELLED_SELECTIONS
        if cfg.restart_at and not labelled and self.attempt == 0 and self.ctx.is_main:
            LOG.warning("restart rule (restart_at=%d) off: it needs validation labels, and %s selects "
                        "without them", cfg.restart_at, self.selection)
        stopped_early = self._loop()
        warning = early_agreement_warning(self.selection, done.history, done.best_iteration) \
            if self.ctx.is_main else None
        if warning is not None:
            LOG.warning(warning)
        detectors: dict[str, DetectorSettings] = {}
        if self.out_dir is not None and self.ctx.is_main:
            detectors = bundle_detectors(self.out_dir, self.val_eps, cfg, self.train_eps)
        result = TrainResult(
            policy=self.models.evaluated, stopped_early=stopped_early, selection=self.selection,
            iterations=done.iteration, best_iteration=done.best_iteration, best_metrics=done.best_metrics,
            last_metrics=done.last_metrics, history=done.history, out_dir=cfg.out_dir,
            train_seconds=time.perf_counter() - started, frames=done.frames, detectors=detectors,
        )
        weak = self.ctx.is_main and rule_applies(cfg, labelled, self.attempt) \
            and weak_start(cfg, _scores(cfg, result))
        return replace(result, weak_start=bool(all_reduce_sum(float(weak), self.ctx)))


def train_step(
    policy: PolicyModule,
    optimizer: torch.optim.Optimizer,
    shard: Sequence[Episode],
    model_config: OMPNConfig,
    cfg: TrainConfig,
    ctx: DistContext | None = None,
    iteration: int = 0,
) -> dict[str, float]:
    """One Adam update on this rank's shard of whole episodes, including collation.

    ``iteration`` seeds the input-dropout masks (``cfg.obs_dropout``) together with ``cfg.seed``
    and the rank.

    Gradients are averaged over ranks (see :mod:`ompn_ros.train.distributed`), clipped to
    ``cfg.clip_norm`` and applied.  Returns the :func:`bc_loss` statistics plus ``loss`` (global
    per-token mean), ``grad_norm`` (before clipping) and ``global_valid`` (valid rows, all ranks).
    """
    ctx = ctx or DistContext()
    use_sketch = model_config.sketch_mode != "none"
    optimizer.zero_grad(set_to_none=True)
    local_valid = 0.0
    loss_value = 0.0
    batch: Batch | None = None
    if shard:
        batch = collate(shard, model_config.action_type, model_config.action_dim, use_sketch)
        local_valid = float(batch.valid_steps)
        if cfg.obs_dropout:
            start, stop = cfg.obs_dropout_range or (0, batch.obs.shape[-1])
            batch.obs[..., start:stop] = dropout_inputs(
                batch.obs[..., start:stop], cfg.obs_dropout, (cfg.seed, iteration, ctx.rank)
            )
        batch = batch_to(batch, device_of(policy))
    global_valid = all_reduce_sum(local_valid, ctx)
    stats: dict[str, float] = {}
    if batch is not None:
        out = policy.forward_sequence(batch.obs, batch.mask, batch.sketch, bptt=cfg.bptt, bf16=cfg.bf16)
        loss, stats = bc_loss(
            out, batch.actions, batch.mask, batch.done_mask, model_config, no_done_loss=cfg.no_done_loss,
            action_scale=policy.action_scale(),
        )
        if batch.teacher_p_hat is not None and cfg.distill_weight:
            kl = distill_loss(out.p_hat, batch.teacher_p_hat, batch.mask & ~batch.done_mask)
            loss = loss + cfg.distill_weight * kl
            stats["distill_kl"] = float(kl.detach())
        # scale so that the rank-average of gradients is the gradient of the global per-token mean
        (loss * (local_valid * ctx.world_size / global_valid)).backward()
        loss_value = float(loss.detach()) * local_valid
    all_reduce_gradients(policy, ctx)
    grad_norm = torch.nn.utils.clip_grad_norm_(policy.parameters(), cfg.clip_norm)
    optimizer.step()
    stats = dict(stats)
    stats["loss"] = all_reduce_sum(loss_value, ctx) / global_valid
    stats["grad_norm"] = float(grad_norm)
    stats["global_valid"] = global_valid
    return stats
