"""Scoring and tuning of the online boundary detector on labelled, already replayed episodes.

The inputs are per-episode score curves and expansion distributions (anything with ``scores``
``[T]`` and ``p_hat`` ``[T, n + 1]`` attributes, e.g. :class:`ompn_ros.segmenter.ReplayResult`),
so everything here is ROS-free and model-free: replaying the model is the caller's job.

* :func:`score_online` / :func:`compare_on_replays`: the causal detector of ``ompn_node``
  (:func:`ompn_ros.detect.online.detect_sequence`) against the offline detectors of the paper
  (Top-K, Algorithm 1; automatic threshold, Algorithm 2; Lu et al., ICLR 2021, §3.3) with K = the
  true number of boundaries.
* :func:`choose_on_replays`: a grid search over :class:`DetectorConfig` (:func:`default_grid`, on
  request with shortest segments relative to the episodes' typical length) maximising boundary F1
  (tolerance 1) or strict alignment accuracy (the paper's headline metrics, §4.1-4.2), settings
  within one standard error of the best counting as tied (:func:`pick_within_error`); for long
  subtasks also over the chosen setting's ``offset`` (:func:`offset_grid`,
  docs/design.md#detector-grid).

Cost: one detector pass is O(T) per episode, so a grid of G settings costs O(G · Σ T).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect import offline
from ompn_ros.detect.defaults import DEFAULT_OBJECTIVE as DEFAULT_OBJECTIVE  # light for --help
from ompn_ros.detect.defaults import OBJECTIVES as OBJECTIVES
from ompn_ros.detect.defaults import Objective as Objective
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.errors import TuneError
from ompn_ros.detect.factory import make_detector
from ompn_ros.detect.head import BoundaryHead, HeadDetector, decode_all
from ompn_ros.detect.head_duration import HeadDurationDetector, decode_head_duration
from ompn_ros.detect.online import MAX_OFFSET, MODES, BoundaryEvent, DetectorConfig, run_detector
from ompn_ros.metrics import alignment_accuracy, mean_f1

MATCH_TOLERANCE = 2
"""A detection within this many steps of a true boundary counts as that boundary (for delays)."""

Metrics = dict[str, float]


class Replayed(Protocol):
    """One replayed episode: per-step online scores and expansion distributions."""

    @property
    def scores(self) -> np.ndarray: ...

    @property
    def p_hat(self) -> np.ndarray: ...


def delay_stats(
    events: Sequence[Sequence[BoundaryEvent] | Sequence[int] | np.ndarray],
    gts: Sequence[np.ndarray],
    detected_at: Sequence[Sequence[int]] | None = None,
) -> Metrics:
    """Detection delay (``detected_at - true boundary``), false alarms per episode and the share of
    inner detections published only at the episode end (``at_end_share``).

    The final boundary (``T - 1``, closed by the episode end) is excluded from all three.  A true
    boundary is detected by the first non-final detection within ``MATCH_TOLERANCE`` steps; a
    detection more than one step from every true boundary is a false alarm.  A detection made at the
    last step or later (the decoder's episode-end pass, docs/design.md#duration-decoder; every offline
    detection) counts as published at the end: its delay says when, this share says how often.
    O(B²) per episode for B boundaries.
    """
    delays: list[int] = []
    false_alarms = at_end = n_inner = 0
    for i, (evs, gt) in enumerate(zip(events, gts, strict=True)):
        steps = [int(e.step) if isinstance(e, BoundaryEvent) else int(e) for e in evs]
        when = (
            [int(e.detected_at) for e in evs if isinstance(e, BoundaryEvent)]
            if detected_at is None
            else list(detected_at[i])
        )
        last = int(gt[-1])
        inner = [(s, w) for s, w in zip(steps, when, strict=True) if s != last]
        for g in gt[:-1]:
            hits = [w for s, w in inner if abs(s - int(g)) <= MATCH_TOLERANCE]
            if hits:
                delays.append(min(hits) - int(g))
        false_alarms += sum(1 for s, _ in inner if np.min(np.abs(gt - s)) > 1)
        at_end += sum(1 for _, w in inner if w >= last)
        n_inner += len(inner)
    return {
        "delay_mean": float(np.mean(delays)) if delays else float("nan"),
        "delay_max": float(np.max(delays)) if delays else float("nan"),
        "false_alarms_per_episode": false_alarms / max(1, len(gts)),
        "at_end_share": at_end / n_inner if n_inner else 0.0,
    }


def score_predictions(preds: Sequence[np.ndarray], episodes: Sequence[Episode]) -> Metrics:
    """F1 at tolerance 0 and 1 and alignment accuracy (authors' and strict decoding), paper §4."""
    gts = [ep.boundaries for ep in episodes]
    labels = [np.asarray(ep.subtask) for ep in episodes]
    return {
        "f1_tol0": mean_f1(preds, gts, 0).f1,
        "f1_tol1": mean_f1(preds, gts, 1).f1,
        "align": alignment_accuracy(preds, labels, "authors"),
        "align_strict": alignment_accuracy(preds, labels, "strict"),
    }


def _check_labelled(replays: Sequence[Replayed], episodes: Sequence[Episode]) -> None:
    if not episodes or any(ep.subtask is None for ep in episodes):
        raise TuneError("detector scoring needs episodes with subtask labels")
    if len(replays) != len(episodes):
        raise TuneError(f"replays: {len(replays)} replays for {len(episodes)} episodes")


def score_online(replays: Sequence[Replayed], episodes: Sequence[Episode], config: DetectorConfig,
                 duration_model: DurationModel | None = None, head: BoundaryHead | None = None) -> Metrics:
    """The causal detector ``config`` (with ``duration_model`` for mode 'hsmm', ``head`` for mode
    'head', both for 'head_hsmm'; the head reads the replays' ``outputs``) on the replays: F1,
    alignment and delays (O(Σ T))."""
    detector = make_detector(config, duration_model, head)
    events = [on_rows(_decode(detector, config, r), run_ends(r)) for r in replays]
    preds = [np.array([e.step for e in evs], dtype=np.int64) for evs in events]
    return {**score_predictions(preds, episodes), **delay_stats(events, [ep.boundaries for ep in episodes])}


def run_ends(replay: Replayed) -> np.ndarray | None:
    """The rows of a replay that hold a step's output (a model with ``still_tolerance``), else None."""
    ends = getattr(replay, "run_ends", None)
    return None if ends is None else np.asarray(ends, dtype=np.int64)


def on_rows(events: list[BoundaryEvent], ends: np.ndarray | None) -> list[BoundaryEvent]:
    """Events decoded from a replay's stepped rows (``ends``), their steps mapped back to those rows."""
    if ends is None or not len(ends):
        return events
    last = len(ends) - 1
    return [replace(e, step=int(ends[min(e.step, last)]), detected_at=int(ends[min(e.detected_at, last)]))
            for e in events]


def _decode(detector: Any, config: DetectorConfig, replay: Replayed) -> list[BoundaryEvent]:
    """The causal detector over one replay's stepped rows (every row, unless :func:`run_ends`)."""
    ends = run_ends(replay)
    scores = replay.scores if ends is None else replay.scores[ends]
    if isinstance(detector, HeadDetector | HeadDurationDetector):
        outputs = _outputs(replay, config)
        q = detector.head.probabilities(outputs if ends is None else outputs[ends])
        if isinstance(detector, HeadDetector):
            return list(decode_all([q], config, detector.peak)[0])
        return list(decode_head_duration(detector.model, q, config, scores))
    return list(run_detector(detector, scores))


def _outputs(replay: Replayed, config: DetectorConfig) -> np.ndarray:
    got = getattr(replay, "outputs", None)
    if got is None:
        raise TuneError(f"detector mode '{config.mode}' reads the model's outputs, and these replays carry "
                        "none")
    return np.asarray(got)


def compare_on_replays(
    replays: Sequence[Replayed],
    episodes: Sequence[Episode],
    online_configs: dict[str, DetectorConfig],
    offline_thresholds: Iterable[float] = (0.5,),
    duration_model: DurationModel | None = None,
    head: BoundaryHead | None = None,
) -> dict[str, Metrics]:
    """Online vs offline detectors on the same replays (paper Algorithms 1-2, K = true count).

    Online detectors see the scores causally (delay ``detected_at - boundary``); offline ones need
    the whole episode, so their delay is measured to the episode end (``T - 1 - boundary``).
    Returns ``{detector name: {metric: value}}``.
    """
    _check_labelled(replays, episodes)
    results = {name: score_online(replays, episodes, cfg, duration_model, head)
               for name, cfg in online_configs.items()}
    thresholds = list(offline_thresholds)
    preds: dict[str, list[np.ndarray]] = {"offline_topk": [], "offline_auto": []}
    preds.update({f"offline_thr{thr:g}": [] for thr in thresholds})
    gts = [ep.boundaries for ep in episodes]
    for r, gt in zip(replays, gts, strict=True):
        k, ends = len(gt), run_ends(r)
        p_hat = r.p_hat if ends is None else r.p_hat[ends]  # the stepped rows, mapped back below

        def rows(found: np.ndarray, ends: np.ndarray | None = ends) -> np.ndarray:
            return found if ends is None else ends[np.asarray(found, dtype=np.int64)]

        preds["offline_topk"].append(rows(offline.top_k_boundaries(p_hat, k)))
        preds["offline_auto"].append(rows(offline.auto_threshold_boundaries(p_hat, k)[0]))
        for thr in thresholds:
            preds[f"offline_thr{thr:g}"].append(rows(offline.threshold_boundaries(p_hat, thr, k)))
    for name, found in preds.items():
        at_end = [[len(r.scores) - 1] * len(p) for r, p in zip(replays, found, strict=True)]
        results[name] = {**score_predictions(found, episodes), **delay_stats(found, gts, at_end)}
    return results


MIN_SEGMENT_LENGTHS = (1, 3)
"""The grid's absolute choices of ``min_segment_length`` (steps)."""
MIN_SEGMENT_FRACTIONS = (0.25, 0.5)
"""The grid's relative choices of ``min_segment_length``: these fractions of the typical segment length
of the tuning targets (:func:`typical_segment_length`; docs/design.md#detector-grid)."""


def typical_segment_length(boundaries: Sequence[np.ndarray]) -> float:
    """The median over episodes of the mean segment length in steps (``T / K`` for K boundaries, the
    last at ``T - 1``); 0 without boundaries.  O(E log E)."""
    lengths = [(int(b[-1]) + 1) / len(b) for b in boundaries if len(b)]
    return float(np.median(lengths)) if lengths else 0.0


def default_grid(segment_length: float = 0.0) -> list[DetectorConfig]:
    """The detector settings searched by :func:`choose_on_replays` and the calibration: 18 highs × 2
    hystereses × the ``min_segment_length`` choices × 3 modes.  The choices are
    ``MIN_SEGMENT_LENGTHS`` and, for a ``segment_length`` > 0 (the targets'
    :func:`typical_segment_length`), its ``MIN_SEGMENT_FRACTIONS``, so that a domain of long subtasks
    can rule out false alarms right after a boundary."""
    highs = [round(float(h), 2) for h in np.arange(0.05, 0.91, 0.05)]
    relative = (max(1, round(f * segment_length)) for f in MIN_SEGMENT_FRACTIONS)
    min_lengths = sorted({*MIN_SEGMENT_LENGTHS, *relative})
    return [
        DetectorConfig(
            high=high,
            low=max(0.0, round(high - hyst, 2)) if hyst else None,
            min_segment_length=min_len,
            mode=mode,
        )
        for high, hyst, min_len, mode in itertools.product(highs, (0.0, 0.1), min_lengths, MODES)
    ]


def offset_grid(config: DetectorConfig) -> list[DetectorConfig]:
    """``config`` with every ``offset`` from 0 to ``MAX_OFFSET`` (0 first, so that a tie keeps it); the
    second stage of a tuning for long subtasks.  Only ``config`` for mode 'hsmm'."""
    if config.mode not in MODES:
        return [config]
    return [replace(config, offset=offset) for offset in range(MAX_OFFSET + 1)]


def _metric_order(objective: Objective) -> tuple[str, str]:
    return ("f1_tol1", "align_strict") if objective == "f1" else ("align_strict", "f1_tol1")


def objective_key(metrics: Metrics, objective: Objective = "f1") -> tuple[float, float, float]:
    """Sort key of a detector's metrics: the objective, then the other metric, then a short delay."""
    delay = metrics["delay_mean"]
    first, second = _metric_order(objective)
    return (metrics[first], metrics[second], -(delay if np.isfinite(delay) else 1e9))


def pick_setting(rows: Sequence[Metrics], objective: Objective = "f1", band: float = 0.0) -> int:
    """Index of the setting a tuning keeps among settings with metrics ``rows``: of those whose
    objective metric is within ``band`` of the best, the one with the best other metric, then
    objective, then delay (the first on ties).  ``band`` 0 is the plain :func:`objective_key` order.
    O(G)."""
    if not rows:
        raise TuneError("no detector settings to choose from")
    if not band >= 0:
        raise TuneError(f"band must be >= 0, got {band}")
    first, _ = _metric_order(objective)
    top = max(row[first] for row in rows)
    near = [g for g, row in enumerate(rows) if row[first] >= top - band]

    def key(g: int) -> tuple[float, float, float, int]:
        first_value, second_value, delay = objective_key(rows[g], objective)
        return (second_value, first_value, delay, -g)

    return max(near, key=key)


def standard_error(per_episode: Sequence[Metrics], lengths: Sequence[int], objective: Objective) -> float:
    """Standard error over episodes of one setting's objective metric, from its metrics on each
    episode alone (``lengths``: their steps).  F1@1 is a mean over episodes (sample std / sqrt(E));
    alignment pools the steps of all episodes, a ratio of sums (delta method).  0 below two
    episodes.  O(E)."""
    n = len(per_episode)
    if n < 2:
        return 0.0
    if objective == "f1":
        return float(np.std([m["f1_tol1"] for m in per_episode], ddof=1) / np.sqrt(n))
    steps = np.asarray(lengths, dtype=np.float64)
    correct = np.array([m["align_strict"] for m in per_episode]) * steps
    ratio = correct.sum() / steps.sum()
    return float(np.sqrt(((correct - ratio * steps) ** 2).sum() * n / (n - 1)) / steps.sum())


def pick_within_error(rows: Sequence[Metrics], objective: Objective,
                      per_episode: Callable[[int], Sequence[Metrics]], lengths: Sequence[int]) -> int:
    """The setting a tuning on labels keeps: :func:`pick_setting` with a band of one standard error
    of the best setting's objective (``per_episode(g)``: setting ``g``'s metrics on each episode),
    the one-standard-error rule of model selection.  Validation cannot tell apart settings closer
    than that on the objective, while the other metric can differ by tens of points between them
    (docs/design.md#detector-grid).  O(G + E)."""
    top = pick_setting(rows, objective)
    return pick_setting(rows, objective, standard_error(per_episode(top), lengths, objective))


def choose_on_replays(
    replays: Sequence[Replayed],
    episodes: Sequence[Episode],
    grid: Sequence[DetectorConfig] | None = None,
    objective: str = "f1",
    long_subtasks: bool = False,
) -> tuple[DetectorConfig, Metrics, dict[str, Metrics]]:
    """Grid-search the online detector, maximising ``objective`` (one of ``OBJECTIVES``).
    ``long_subtasks`` (off by default; docs/design.md#detector-grid): the default grid also tries
    shortest segments relative to the episodes' :func:`typical_segment_length`, and the chosen
    setting's ``offset`` is searched next (:func:`offset_grid`).

    :func:`pick_within_error` keeps one setting (one standard error over the episodes).  Returns
    ``(best config, its metrics, comparison with the offline detectors)``.  O((|grid| + MAX_OFFSET) · Σ T).
    """
    if objective not in OBJECTIVES:
        raise TuneError(f"detector tuning objective must be one of {OBJECTIVES}, got {objective!r}")
    _check_labelled(replays, episodes)
    typical = typical_segment_length([ep.boundaries for ep in episodes]) if long_subtasks else 0.0
    grid = list(grid or default_grid(typical))
    if not grid:
        raise TuneError("grid: no detector settings to search")
    config, metrics = _search(replays, episodes, grid, objective)
    if long_subtasks:
        config, metrics = _search(replays, episodes, offset_grid(config), objective)
    return config, metrics, compare_on_replays(replays, episodes, {"online": config})


def _search(replays: Sequence[Replayed], episodes: Sequence[Episode], grid: Sequence[DetectorConfig],
            objective: str) -> tuple[DetectorConfig, Metrics]:
    """The setting of ``grid`` that :func:`pick_within_error` keeps, and its metrics."""
    rows = [score_online(replays, episodes, cfg) for cfg in grid]

    def per_episode(g: int) -> list[Metrics]:
        return [score_online(replays[i:i + 1], episodes[i:i + 1], grid[g]) for i in range(len(episodes))]

    best = pick_within_error(rows, objective, per_episode, [ep.length for ep in episodes])  # type: ignore[arg-type]
    return grid[best], rows[best]
