"""StreamingSegmenter: a StreamingPolicy plus a causal boundary detector, one step per observation.

The stream rule (:mod:`ompn_ros.stream`: stamps, episode cuts, markers) drives this class for
``ompn_node`` and for the offline replay (``ompn_segment``) alike, so live and offline segmentation
cannot drift apart.

One entry point, :meth:`StreamingSegmenter.step`, validates, steps and detects.  Validation happens
*before* the model is touched: a rejected observation raises a subclass of :class:`InvalidInput` and
leaves the ordered memory, the step counter and the detector exactly as they were (the next valid
observation gives the same output as if the bad one had never arrived).  Rejections are counted by
reason in :attr:`StreamingSegmenter.rejected`.  The segmenter keeps no stamps: the caller names the
stamp an observation must follow (the stream rule owns the episode and its last stamp).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, overload

import numpy as np
from numba import njit

from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.errors import BoundaryHeadError
from ompn_ros.detect.factory import Detector, make_detector
from ompn_ros.detect.head import BoundaryHead, FedByHead, step_outputs
from ompn_ros.detect.online import (
    BoundaryEvent,
    DetectorConfig,
    expansion_level,
    expansion_score,
)
from ompn_ros.validate import (
    REJECT_REASONS,
    EpisodeClosed,
    InvalidInput,
    MissingSketch,
    OutOfOrderStamp,
    SketchError,
    validate_observation,
    validate_sketch,
)


class PolicyConfigLike(Protocol):
    obs_dim: int
    n_slots: int
    action_type: str
    action_dim: int
    sketch_mode: str


class StreamingPolicyLike(Protocol):
    """What the segmenter needs from ``ompn_ros.model.streaming.StreamingPolicy``."""

    config: Any

    def reset(self, sketch: np.ndarray | None = None) -> None: ...

    def step(self, obs: np.ndarray) -> Any: ...


@dataclass(frozen=True)
class SegmenterOutput:
    """Result of one accepted step.

    Attributes:
        step_output: the policy's ``StepOutput`` (action, pi, pi_end, p_hat, expected_position, ...).
        boundary: the boundary committed at this step, if any (it may refer to an earlier step).
        step_index: 0-based index of this step within the episode.
        score: the detector score of this step (code-weighted pi_avg / n, in [0, 1]).
        level: argmax expansion level of this step (1 = bottom slot ... n + 1 = pi_end).
    """

    step_output: Any
    boundary: BoundaryEvent | None
    step_index: int
    score: float
    level: int


@njit(cache=True)
def _all_finite(a: np.ndarray) -> bool:  # pragma: no cover - compiled
    """No NaN or infinity in the 1-D ``a``: the per-step check (numpy's ufunc path is slower with cold
    caches, BENCHMARKS.md "Where the boundary latency goes")."""
    for i in range(a.shape[0]):
        if not math.isfinite(a[i]):
            return False
    return True


def _checked_head(head: BoundaryHead | None, config: Any) -> BoundaryHead | None:
    """``head`` when it reads this model's outputs per step (``n + 1 + A``), else a BoundaryHeadError."""
    if head is None:
        return None
    outputs = int(config.n_slots) + 1 + int(config.action_dim)
    if head.features != outputs:
        raise BoundaryHeadError(
            f"the boundary head reads {head.features} outputs per step and this model gives {outputs} "
            f"(n_slots {config.n_slots} + 1 + action_dim {config.action_dim}): it belongs to another model"
        )
    return head


class StreamingSegmenter:
    """Validate, step the policy's ordered memory, score the expansion and detect boundaries."""

    def __init__(self, policy: StreamingPolicyLike, detector_config: DetectorConfig | None = None,
                 duration_model: DurationModel | None = None, head: BoundaryHead | None = None) -> None:
        self.policy = policy
        self.duration_model = duration_model
        self.head = _checked_head(head, policy.config)
        self.detector_config = detector_config or DetectorConfig()
        self.detector: Detector = make_detector(self.detector_config, duration_model, head)
        self._detector_changed = False
        _all_finite(np.zeros(1, dtype=np.float32))  # compiled (or loaded from numba's cache) now
        self.obs_dim = int(policy.config.obs_dim)
        # the model's still_tolerance: 0, every observation is a step; the stream rule applies it
        self.still_tolerance = float(getattr(policy.config, "still_tolerance", 0.0))
        # validate() already checked the observation: skip the policy's own check when it offers that
        self._step_policy = getattr(policy, "step_trusted", policy.step)
        self.rejected: Counter[str] = Counter({reason: 0 for reason in REJECT_REASONS})
        self.accepted = 0
        self.episodes = 0
        self._step_index = -1
        self._sketch: np.ndarray | None = None
        self._ready = False
        if self.needs_sketch:
            self.episodes = 0  # waits for reset(sketch)
        else:
            self.reset()

    @property
    def needs_sketch(self) -> bool:
        """True when the model conditions on a sketch (``reset`` must be given one)."""
        return getattr(self.policy.config, "sketch_mode", "none") != "none"

    @property
    def ready(self) -> bool:
        """False until an episode was started (sketch models wait for their sketch)."""
        return self._ready

    @property
    def step_index(self) -> int:
        """Index of the last accepted step of the current episode (-1 before the first)."""
        return self._step_index

    @property
    def sketch(self) -> np.ndarray | None:
        return self._sketch

    @property
    def sketch_vocab(self) -> int | None:
        """The model's sketch vocabulary (``None``: not limited)."""
        vocab = getattr(self.policy.config, "sketch_vocab", None)
        return None if vocab is None else int(vocab)

    def reset(self, sketch: np.ndarray | None = None) -> None:
        """Start a new episode: clear the memory (initialised from ``sketch`` if the model uses one)."""
        sketch_arr = self._validate_sketch(sketch)
        self.policy.reset(sketch_arr)
        if self._detector_changed:
            self.detector = make_detector(self.detector_config, self.duration_model, self.head)
            self._detector_changed = False
        self.detector.reset()
        self._sketch = sketch_arr
        self._step_index = -1
        self._ready = True
        self.episodes += 1

    def stop(self) -> None:
        """Leave the current episode without starting another: steps are rejected as ``no_sketch``
        until the next :meth:`reset` (an episode start whose sketch was refused)."""
        self._ready = False
        self._step_index = -1

    @overload
    def step(self, obs: Any, stamp_ns: int | None = None, *, after_ns: int | None = None,
             hold: None = None) -> SegmenterOutput: ...

    @overload
    def step(self, obs: Any, stamp_ns: int | None = None, *, after_ns: int | None = None,
             hold: Callable[[np.ndarray, int], bool]) -> SegmenterOutput | None: ...

    def step(self, obs: Any, stamp_ns: int | None = None, *, after_ns: int | None = None,
             hold: Callable[[np.ndarray, int], bool] | None = None) -> SegmenterOutput | None:
        """Validate and consume one observation: the policy's step and the detector's update.

        ``after_ns``: the stamp ``stamp_ns`` must be later than (the previous step's; ``None``: any).
        ``hold(observation, stamp)``: asked with the validated observation whether it is stepped;
        False returns ``None`` without a step (the still rule, :mod:`ompn_ros.data.cuts.still`).  An
        invalid input raises its :class:`InvalidInput`, counted by reason, without side effects."""
        try:
            arr = self._validate(obs, stamp_ns, after_ns)
        except InvalidInput as exc:
            self.rejected[exc.reason] += 1
            raise
        stamp = 0 if stamp_ns is None else int(stamp_ns)
        if hold is not None and not hold(arr, stamp):
            return None
        out = self._step_policy(arr)
        self._step_index += 1
        self.accepted += 1
        p_hat = np.asarray(out.p_hat)
        score = expansion_score(p_hat)
        level = expansion_level(p_hat)
        if isinstance(self.detector, FedByHead):  # the head reads the whole output, not the score
            self.detector.feed(step_outputs(out))
        boundary = self.detector.update(score, level, stamp)
        return SegmenterOutput(out, boundary, self._step_index, score, level)

    def _validate(self, obs: Any, stamp_ns: int | None, after_ns: int | None) -> np.ndarray:
        """``obs`` as float32 ``[obs_dim]`` (as it is when it already is one), or an :class:`InvalidInput`."""
        if not self._ready:
            raise MissingSketch("no episode started: the model needs a sketch (reset(sketch)) first")
        if self.detector.closed:
            raise EpisodeClosed("the episode was ended (end_episode); reset() starts the next one")
        arr = validate_observation(obs, self.obs_dim, _all_finite)
        if stamp_ns is not None and after_ns is not None and int(stamp_ns) <= after_ns:
            raise OutOfOrderStamp(
                f"observation stamp {int(stamp_ns)} ns is not after the previous step's {after_ns} ns"
            )
        return arr

    def end_episode(self, last_step: int | None = None) -> list[BoundaryEvent]:
        """Close the current episode: the events that close it, the ``final`` one last (the last
        segment's boundary or the episode end, see ``OnlineDetector.end_episode``; the duration decoder
        also decides the steps still in its lag).

        ``last_step`` lets the caller exclude the final 'done' observation: with the layout's step
        contract an episode of ``T`` real steps publishes ``T + 1`` observations, so pass ``T - 1``.
        """
        return self.detector.close(last_step)

    def set_detector(self, config: DetectorConfig) -> str:
        """Run ``config``: from the next step, or from the next episode when it changes the decoder
        (mode 'hsmm', 'head' or 'head_hsmm' on or off, or their lag) in the middle of one.  Returns
        which; raises :class:`~ompn_ros.detect.errors.DurationModelError` or
        :class:`~ompn_ros.detect.errors.BoundaryHeadError` (nothing changed) for a mode without the
        duration model or the boundary head it needs."""
        fresh = make_detector(config, self.duration_model, self.head)
        self.detector_config, running = config, self.detector
        if type(running) is type(fresh) and getattr(running, "lag", 0) == getattr(fresh, "lag", 0):
            running.configure(config)  # the same decoder: only its thresholds change
            self._detector_changed = False
            return "from the next step"
        if self.detector.steps_seen == 0:
            self.detector, self._detector_changed = fresh, False
            return "from the next step"
        self._detector_changed = True
        return "from the next episode"

    def count_rejection(self, error: InvalidInput) -> None:
        """Count an input the caller rejected before :meth:`step` (e.g. an undecodable message)."""
        self.rejected[error.reason] += 1

    @property
    def rejected_total(self) -> int:
        return int(sum(self.rejected.values()))

    def _validate_sketch(self, sketch: np.ndarray | None) -> np.ndarray | None:
        mode = getattr(self.policy.config, "sketch_mode", "none")
        if sketch is None:
            if mode != "none":
                raise SketchError(f"the model uses sketch_mode='{mode}' and needs a sketch; none was given")
            return None
        if mode == "none":
            return None  # a sketch may be published, but this model ignores it
        return validate_sketch(sketch, self.sketch_vocab)


@dataclass
class ReplayResult:
    """Per-step outputs of one episode replayed through a :class:`StreamingSegmenter`
    (:func:`ompn_ros.stream.replay.replay_episode`)."""

    p_hat: np.ndarray  # [T, n+1]
    pi: np.ndarray  # [T, n] lowest slot first
    pi_end: np.ndarray  # [T]
    expected_position: np.ndarray  # [T]
    scores: np.ndarray  # [T]
    boundaries: list[BoundaryEvent] = field(default_factory=list)
    """One event per subtask the episode reported, within its ``T`` real steps (a boundary decided on
    the final observation, row T, ends step T - 1); the episode end is not among them."""
    actions: list[Any] = field(default_factory=list)
    published: list[BoundaryEvent] = field(default_factory=list)
    """Every event ``ompn_node`` publishes on ``~/boundary`` for the episode, in order: one per subtask,
    the last event ``final`` (the episode end when no subtask ended with the episode,
    docs/design.md#episode-end)."""
    outputs: np.ndarray | None = None
    """``[T, n + 1 + A]``: what the boundary head reads (:func:`~ompn_ros.detect.head.head_outputs`)."""
    run_ends: np.ndarray | None = None
    """A model with ``still_tolerance``: the rows that hold a step's output (the last row of each run,
    :mod:`ompn_ros.data.cuts.still`), in step order; ``None`` when every row is a step.  A detector decoded
    again from the arrays reads these rows and maps its steps back to them, as the node does."""

    @property
    def boundary_steps(self) -> np.ndarray:
        """The boundaries the metrics score: every subtask's end and the episode's last step ``T - 1``
        (Algorithm 1 appends it), each step once, sorted."""
        steps = [b.step for b in self.boundaries] + ([len(self.scores) - 1] if len(self.scores) else [])
        return np.unique(np.array(steps, dtype=np.int64))
