"""The training hyper-parameters: :class:`TrainConfig` (the ``train`` section of ``ompn_train``'s YAML).

The fields fall into two groups: the core loop of behaviour cloning (paper §3.2, Alg. 1; docs/craft.md
§4, docs/dial.md §4), checkpoint selection and what training writes; then the research options
(restarts, candidates, weight decay, weight averaging, the cosine schedule, input dropout, action
standardisation, distillation), each off by default.  Every field is validated when the config is
built; an invalid one raises :class:`~ompn_ros.train.errors.TrainConfigError` naming it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, get_args

from ompn_ros.detect.defaults import DURATION_DELAY, DURATION_LAG
from ompn_ros.detect.online import MAX_LAG
from ompn_ros.model.config import ACTION_NORMS, ActionNorm
from ompn_ros.train.device import DEVICES, Device
from ompn_ros.train.errors import TrainConfigError
from ompn_ros.train.threads import Threads, check_threads

Selection = Literal["align", "f1_tol1", "val_loss", "agreement"]
Labels = Literal["auto", "none"]
ObsNorm = Literal["none", "maxabs"]
LrSchedule = Literal["constant", "cosine"]
SELECTIONS: tuple[Selection, ...] = get_args(Selection)
LABEL_MODES: tuple[Labels, ...] = get_args(Labels)
LABELLED_SELECTIONS = ("align", "f1_tol1")
"""Selections that read validation labels; without labels the trainer selects by ``'agreement'``."""
OBS_NORMS: tuple[ObsNorm, ...] = get_args(ObsNorm)
LR_SCHEDULES: tuple[LrSchedule, ...] = get_args(LrSchedule)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


# TrainConfig's checks, by kind of field (__post_init__); the numbers are stored as floats
_POSITIVE_INTS = ("batch_size", "bptt", "iterations", "eval_every", "eval_batch_size")
_COUNTS = ("seed", "eval_episodes", "patience", "agreement_warmup", "restart_at", "restarts")
_AT_LEAST_ONE = ("candidates", "candidates_no_final")
_FLAGS = ("resume", "tensorboard", "no_done_loss", "progress", "bf16", "force_bf16", "boundary_head")
_NUMBERS: dict[str, tuple[Callable[[float], bool], str]] = {
    "lr": (lambda v: v > 0, "must be > 0"),
    "clip_norm": (lambda v: v > 0, "must be > 0"),
    "val_ratio": (lambda v: 0.0 <= v < 1.0, "must be in [0, 1)"),
    "weight_decay": (lambda v: v >= 0, "must be a number >= 0"),
    "ema_decay": (lambda v: 0.0 <= v < 1.0, "must be a number in [0, 1)"),
    "obs_dropout": (lambda v: 0.0 <= v < 1.0, "must be a number in [0, 1)"),
    "restart_below": (lambda v: 0.0 <= v <= 1.0, "must be a number in [0, 1]"),
    "detector_delay": (lambda v: v > 0, "must be > 0 (steps)"),
}
_CHOICES: dict[str, tuple[str, ...]] = {
    "lr_schedule": LR_SCHEDULES, "selection": SELECTIONS, "labels": LABEL_MODES, "obs_norm": OBS_NORMS,
    "action_norm": ACTION_NORMS, "device": DEVICES,
}

RECORDED_ORDER = (
    "lr", "batch_size", "clip_norm", "bptt", "iterations", "eval_every", "val_ratio", "seed", "split_seed",
    "out_dir", "resume", "tensorboard", "no_done_loss", "threads", "selection", "labels", "patience",
    "agreement_warmup", "restart_at", "restart_below", "restarts", "candidates", "candidates_no_final",
    "detector_lag", "detector_delay", "obs_norm", "eval_episodes", "eval_batch_size", "progress", "bf16",
    "weight_decay", "ema_decay", "lr_schedule", "obs_dropout", "obs_dropout_range", "force_bf16",
    "action_norm", "distill_from", "distill_weight", "device", "boundary_head",
)
"""The order of the keys of :meth:`TrainConfig.to_dict` (that of the fields before they were grouped)."""


@dataclass
class TrainConfig:
    """Training hyper-parameters (defaults: the Craft paper values, docs/craft.md §4).

    The core loop (paper Alg. 1, selection, early stopping, what training writes):

    Attributes:
        lr: Adam learning rate (Craft 1e-3, Dial 5e-4).
        batch_size: whole episodes per update (Craft 256, Dial 64); under DDP the global batch.
        clip_norm: gradient L2-norm clip (0.2).
        bptt: truncated-BPTT length in steps (64).
        iterations: number of updates.
        eval_every: evaluate, save ``last/`` + the resumable state every this many iterations.
        val_ratio: fraction of episodes held out for validation (seeded split).
        seed: seeds the model init, the split and the batch order.
        split_seed: seeds the train/validation split instead of ``seed`` (None = ``seed``).  The
            members of an ensemble share one split, so that its validation episodes are unseen by
            every member, and differ in ``seed``.
        out_dir: checkpoint/log directory (None = keep nothing on disk).
        resume: continue from ``out_dir/train_state`` if present.
        tensorboard: write TensorBoard scalars to ``out_dir/tb`` (if tensorboard is installed).
        no_done_loss: the "No Done" ablation (done steps leave the loss numerator).
        threads: torch threads: ``'auto'`` (the default: from the cores this process may use and the
            machine's load, 1 per process when several train; :mod:`ompn_ros.train.threads`), an int
            (``torch.set_num_threads``) or 0 (leave torch's default).
        selection: best-checkpoint criterion, one of ``SELECTIONS`` (see :mod:`ompn_ros.train.trainer`).
            ``'align'`` and ``'f1_tol1'`` need validation labels; without them (or with ``labels='none'``)
            ``'agreement'`` is used instead.
        labels: ``'auto'`` = use the validation episodes' subtask labels when every one has them;
            ``'none'`` = hide them from checkpoint selection, early stopping and the detector
            calibration (they are still scored and logged), to measure the label-free path.
        patience: stop when the selection criterion has not improved for this many evaluations
            (``iterations`` is then the cap); 0 = off, train exactly ``iterations`` updates.  The
            shipped configs (``config/train_<domain>.yaml``, what ``ompn_train`` runs) set 10 with a
            cap of 1200; the reproduction pins 0 and its fixed lengths.  The dataclass default stays
            0 because every run recorded before this option trained without it (a stored
            ``train_config`` without the key reads back as what it did).
        agreement_warmup: with the label-free ``'agreement'`` selection only: evaluations at or before
            this iteration are logged but neither become ``best/`` nor count towards ``patience``
            (the run's last evaluation always may).  A barely trained model can agree with itself on
            a trivial segmentation: on Dial the agreement peaked at iteration 20 (validation
            alignment 0.27) and early stopping then kept that checkpoint
            (docs/design.md#agreement-warm-up).  0 = off (the dataclass default, for the same reason as
            ``patience``); the shipped configs set 100.
        detector_lag: the lag of the 'hsmm' online detector fitted at the end of training (a
            boundary is published at least lag + 1 steps after its step, 0 … 10;
            ``ompn_ros.train.detector``).
        detector_delay: the mean delay (steps from a boundary to its publication) the 'hsmm'
            detector's threshold may cost on the validation episodes.
        boundary_head: with labels, also train the learned boundary head (online mode 'head') at the
            end of training and run it when its validation alignment is higher
            (``ompn_ros.train.detector``, docs/design.md#boundary-head).
        obs_norm: ``'none'`` (Craft one-hot features) or ``'maxabs'`` (Dial: (s − mean)/max|s|).
        eval_episodes: cap on validation episodes per evaluation (0 = all).
        eval_batch_size: episodes per teacher-forced evaluation batch.
        progress: show a tqdm progress bar.
        bf16: run the training forward's matmuls in bfloat16 autocast (``forward_sequence(bf16=True)``,
            ~1.4x faster on AVX512-BF16 CPUs; evaluation and inference stay float32).  Honoured only
            on a CPU with native bfloat16 (:mod:`ompn_ros.train.precision`); elsewhere training warns
            and runs in float32, and the checkpoints' ``train_config`` records ``bf16: false``.
        force_bf16: with ``bf16``, use bfloat16 even on a CPU without native support (slow).
        device: ``'cpu'``, ``'cuda'`` (the batched forward, loss and update on the GPU; ``bf16`` is then
            off) or ``'auto'`` (``cuda`` when torch sees a GPU); :mod:`ompn_ros.train.device`.

    Research options (each off by default, which is how the authors trained; the restart rule
    and ``candidates_no_final`` are set by the shipped configs):

    Attributes:
        restart_at: the restart rule (:mod:`ompn_ros.train.restart`): a run whose best validation
            criterion by its first evaluation at or after this iteration is below ``restart_below``
            trains to the end, then a new initialisation trains on the same split (in
            ``OUT/attempts/<k>/``, at most ``restarts`` times) and the attempt with the best
            validation criterion is kept.  Labelled selections only.  0 = off.
        restart_below: the bound of the restart rule (the selection criterion, e.g. alignment).
        restarts: the most extra initialisations one run trains under the rule.
        candidates: initialisations trained on the one split; the one with the best validation
            criterion is kept (:mod:`ompn_ros.train.candidates`, ``OUT/candidates.json``).  1 = one run.
        candidates_no_final: ``candidates`` for bags whose final observation the reader guessed (no
            observation after the last action), with validation labels: ``ompn_train`` raises
            ``candidates`` to this (:func:`~ompn_ros.train.candidates.resolve_candidates`).  The Craft
            config sets 2 (docs/design.md#best-of-two).
        weight_decay: decoupled weight decay (AdamW) per unit learning rate; 0 = plain Adam, as the
            authors trained.
        ema_decay: Polyak averaging of the weights (0 = off).  After every update the averaged copy
            moves by ``1 − d`` towards the trained weights, with ``d = min(ema_decay, (1+i)/(10+i))`` at
            iteration ``i`` so that early averages are not dominated by the initial weights.  When on,
            evaluation, selection and the ``best/`` and ``last/`` checkpoints use the averaged weights;
            the resumable state keeps both.
        lr_schedule: ``'constant'`` (the authors) or ``'cosine'``: the learning rate of update ``i``
            is ``lr · (1 + cos(π (i − 1) / iterations)) / 2``, a function of ``i`` alone (resume-exact).
        obs_dropout: input dropout on the training batches (0 = off, as the authors): each
            observation feature of each step is zeroed with this probability and the rest are scaled
            by ``1 / (1 − p)``.  The masks come from a generator seeded by ``(seed, iteration, rank)``,
            so a resumed run draws the same ones.  Validation, selection and inference see clean
            inputs.
        obs_dropout_range: ``[start, stop)`` feature indices that ``obs_dropout`` applies to (empty =
            every feature).  ``[525, 1050]`` is Craft's max-pooled global map block
            (docs/craft.md §1.7): dropping only it keeps the local view, inventory and direction intact.
        action_norm: continuous actions: ``'none'`` (the head fits raw actions, as every checkpoint
            trained before the option) or ``'standard'`` (per-dimension mean and std of the training
            split's actions; the head fits standardised actions, the loss is taken on the standardised
            residual, and the model still outputs the data's units; ``OMPNConfig.action_norm``).
            It is stored in the checkpoint's ``config.json``.
        distill_from: teacher checkpoint or ensemble directories (empty = no distillation; stored as
            absolute paths): the training loss adds ``distill_weight`` times the mean KL divergence
            from the teachers' averaged ``p_hat`` to the student's over the real steps
            (:mod:`ompn_ros.train.distill`).
        distill_weight: weight of that term (> 0 exactly when ``distill_from`` names teachers).
    """

    lr: float = 1e-3
    batch_size: int = 256
    clip_norm: float = 0.2
    bptt: int = 64
    iterations: int = 10000
    eval_every: int = 20
    val_ratio: float = 0.2
    seed: int = 0
    split_seed: int | None = None
    out_dir: str | None = None
    resume: bool = False
    tensorboard: bool = False
    no_done_loss: bool = False
    threads: Threads = "auto"
    selection: Selection = "align"
    labels: Labels = "auto"
    patience: int = 0
    agreement_warmup: int = 0
    detector_lag: int = DURATION_LAG
    detector_delay: float = DURATION_DELAY
    boundary_head: bool = True
    obs_norm: ObsNorm = "none"
    eval_episodes: int = 0
    eval_batch_size: int = 64
    progress: bool = True
    bf16: bool = False
    force_bf16: bool = False
    device: Device = "cpu"  # cuda and auto opt in: the CUDA path has not yet been run on a GPU (device.py)

    # research options
    restart_at: int = 0
    restart_below: float = 0.0
    restarts: int = 1
    candidates: int = 1
    candidates_no_final: int = 1
    weight_decay: float = 0.0
    ema_decay: float = 0.0
    lr_schedule: LrSchedule = "constant"
    obs_dropout: float = 0.0
    obs_dropout_range: list[int] = field(default_factory=list)
    action_norm: ActionNorm = "none"
    distill_from: list[str] = field(default_factory=list)
    distill_weight: float = 0.0

    def __post_init__(self) -> None:
        def need(cond: bool, name: str, what: str) -> None:
            if not cond:
                raise TrainConfigError(f"TrainConfig.{name} {what}, got {getattr(self, name)!r}")

        for name in _POSITIVE_INTS:
            need(_is_int(getattr(self, name)) and getattr(self, name) > 0, name, "must be a positive int")
        for name in _COUNTS:
            need(_is_int(getattr(self, name)) and getattr(self, name) >= 0, name, "must be an int >= 0")
        check_threads(self.threads)
        for name in _AT_LEAST_ONE:
            need(_is_int(getattr(self, name)) and getattr(self, name) >= 1, name, "must be an int >= 1")
        need(
            self.split_seed is None or (_is_int(self.split_seed) and self.split_seed >= 0),
            "split_seed",
            "must be None (use seed) or an int >= 0",
        )
        for name, (within, what) in _NUMBERS.items():
            value = getattr(self, name)
            need(_is_number(value) and within(value), name, what)
            setattr(self, name, float(value))
        span = self.obs_dropout_range
        listed = isinstance(span, list | tuple)
        pair = listed and len(span) == 2 and all(_is_int(v) for v in span) and 0 <= span[0] < span[1]
        need(
            listed and (len(span) == 0 or pair),
            "obs_dropout_range",
            "must be [] or [start, stop] with 0 <= start < stop (feature indices, stop exclusive)",
        )
        self.obs_dropout_range = [int(v) for v in span]
        for name in _FLAGS:
            need(isinstance(getattr(self, name), bool), name, "must be a bool")
        for name, choices in _CHOICES.items():
            need(getattr(self, name) in choices, name, f"must be one of {choices}")
        need(
            self.out_dir is None or isinstance(self.out_dir, str), "out_dir", "must be a path string or None"
        )
        need(not (self.resume and self.out_dir is None), "resume", "needs out_dir")
        need(_is_int(self.detector_lag) and 0 <= self.detector_lag <= MAX_LAG, "detector_lag",
             f"must be an int in [0, {MAX_LAG}]")
        self._check_distill(need)

    def _check_distill(self, need: Callable[[bool, str, str], None]) -> None:
        teachers = self.distill_from
        need(isinstance(teachers, list | tuple) and all(isinstance(t, str) and t for t in teachers),
             "distill_from", "must be a list of checkpoint or ensemble directories")
        self.distill_from = [str(Path(t).resolve()) for t in teachers]  # recorded as the directories named
        weight = self.distill_weight
        need(_is_number(weight) and weight >= 0,
             "distill_weight", "must be a number >= 0")
        self.distill_weight = float(weight)
        need(bool(self.distill_from) == (self.distill_weight > 0), "distill_weight",
             "must be > 0 exactly when distill_from names teachers")

    def to_dict(self) -> dict[str, Any]:
        """The fields in :data:`RECORDED_ORDER`, then any field added since (the ``train_config`` of a
        checkpoint's ``meta.json`` keeps its key order whatever the order of the fields above)."""
        data = asdict(self)
        ordered = {name: data.pop(name) for name in RECORDED_ORDER}
        ordered.update(data)
        return ordered

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise TrainConfigError(f"unknown TrainConfig keys {unknown}; known keys are {sorted(known)}")
        return cls(**data)
