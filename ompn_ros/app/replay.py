"""Replay episodes through the :class:`~ompn_ros.segmenter.StreamingSegmenter` (as the node runs
them) and score or tune the online detector on the replays (:mod:`ompn_ros.detect.tune`).

This is the library behind ``ompn_segment``: :func:`run_replay` writes the replay files
(``pi.npz``, ``boundaries.json``, ``metrics.json``, plots) of a bag or generated episodes.
Cost: one model step per observation, O(Σ T) steps in all.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.app.annotate import AnnotateReport, annotate_bag, observation_stamps
from ompn_ros.app.errors import ReplayError
from ompn_ros.app.final_record import resolve_final
from ompn_ros.atomic import atomic_write, atomic_write_text
from ompn_ros.data.episode import OBS_STAMPS, Episode
from ompn_ros.data.reader import OnError, ReaderSpec, ReadResult, read_episodes, resolve_bag_paths
from ompn_ros.detect import offline
from ompn_ros.detect.choose import with_tuned
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import BoundaryEvent, DetectorConfig
from ompn_ros.detect.settings import load_detector_settings, save_detector_settings
from ompn_ros.detect.tune import Metrics, compare_on_replays
from ompn_ros.plotting import plot_episode
from ompn_ros.segmenter import ReplayResult, StreamingSegmenter
from ompn_ros.stream.replay import replay_episode


def reader_spec(reader_config: str | None, domain: str | None, checkpoint: str | None = None) -> ReaderSpec:
    """The reader spec of ``reader_config`` (YAML), else the preset of ``domain``, else the defaults;
    ``final_observation: auto`` reads as ``checkpoint`` was trained (:func:`resolve_final`)."""
    if reader_config:
        spec = ReaderSpec.from_yaml(reader_config)
    else:
        spec = ReaderSpec.for_domain(domain) if domain else ReaderSpec()
    return resolve_final(spec, checkpoint)


def read_bag_episodes(
    bag: str, reader_config: str | None, domain: str | None, on_error: OnError = "raise",
    checkpoint: str | None = None,
) -> ReadResult:
    """Episodes of ``bag`` with :func:`reader_spec`."""
    return read_episodes(bag, spec=reader_spec(reader_config, domain, checkpoint), on_error=on_error)


def generate_episodes(domain: str, count: int, seed: int) -> list[Episode]:
    """``count`` fresh expert episodes of ``domain`` with seeds ``seed, seed + 1, ...`` (Craft: the
    paper's tasks in turn, as in the training data)."""
    from sim_nodes.registry import DOMAINS, default_tasks, expert_episode  # the sims load for --generate only

    if domain not in DOMAINS:
        raise ReplayError(f"--generate needs --domain craft|dial, got {domain!r}")
    if seed < 0:
        raise ReplayError(f"--seed must be >= 0, got {seed}")
    tasks = default_tasks(domain)
    return [expert_episode(domain, seed + i, task=tasks[i % len(tasks)]) for i in range(count)]


def read_report_doc(result: ReadResult, on_error: str) -> dict[str, Any]:
    """The read report of a replayed bag (:func:`~ompn_ros.app.read_report.write_read_report`): the
    episodes kept, the errors met and the reader's summary."""
    return {
        "on_error": on_error,
        "episodes": len(result.episodes),
        "errors": result.report.errors,
        "summary": result.report.summary(),
    }


def replay_all(policy: Any, episodes: Sequence[Episode], config: DetectorConfig,
               duration_model: DurationModel | None = None, head: BoundaryHead | None = None
               ) -> list[ReplayResult]:
    """Replay every episode (done step included, as live) through one StreamingSegmenter."""
    segmenter = StreamingSegmenter(policy, config, duration_model, head)
    return [replay_episode(segmenter, ep, include_done_step=True) for ep in episodes]


def check_finite(replays: Sequence[ReplayResult], episodes: Sequence[Episode]) -> None:
    """Raise :class:`ReplayError` naming the first episode whose ``p_hat`` is not finite."""
    for i, (r, ep) in enumerate(zip(replays, episodes, strict=True)):
        if not np.all(np.isfinite(r.p_hat)):
            raise ReplayError(
                f"episode {i} ({ep.task}, seed {ep.seed}): the model produced non-finite "
                "p_hat (NaN or inf); the checkpoint or the observations are broken"
            )


def compare_detectors(
    policy: Any,
    episodes: Sequence[Episode],
    online_configs: dict[str, DetectorConfig] | None = None,
    *,
    offline_thresholds: Iterable[float] = (0.5,),
    replays: Sequence[ReplayResult] | None = None,
    duration_model: DurationModel | None = None,
    head: BoundaryHead | None = None,
) -> dict[str, Metrics]:
    """Online vs offline detectors on ``episodes`` (see :func:`ompn_ros.detect.tune.compare_on_replays`)."""
    configs = online_configs or {"online": DetectorConfig()}
    if replays is None:
        replays = replay_all(policy, episodes, next(iter(configs.values())), duration_model, head)
    return compare_on_replays(replays, episodes, configs, offline_thresholds, duration_model, head)


def json_safe(value: Any) -> Any:
    """NaN/inf -> None (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _episode_doc(i: int, ep: Episode, r: ReplayResult) -> dict[str, Any]:
    """One episode of ``boundaries.json``: a boundary per subtask, with the bag log stamps of its step
    and of the step it was decided at when the reader gave them (``stamp_ns`` 0 and ``decided_stamp_ns``
    absent otherwise)."""
    stamps = ep.extras.get(OBS_STAMPS)

    def stamped(b: BoundaryEvent) -> dict[str, Any]:
        doc = asdict(b)
        if stamps is not None and len(stamps):
            doc["stamp_ns"] = int(stamps[min(b.step, len(stamps) - 1)])
            doc["decided_stamp_ns"] = int(stamps[min(b.detected_at, len(stamps) - 1)])
        return doc

    return {
        "episode": i,
        "task": ep.task,
        "seed": ep.seed,
        "steps": ep.length,
        "boundaries": [stamped(b) for b in r.boundaries],
        "true_boundaries": ep.boundaries.tolist() if ep.subtask is not None else None,
    }


def _plot(path: Path, ep: Episode, r: ReplayResult, config: DetectorConfig) -> None:
    gt = ep.boundaries.tolist() if ep.subtask is not None else None
    auto = offline.auto_threshold_boundaries(r.p_hat, len(gt))[0].tolist() if gt else None
    plot_episode(
        path,
        r.pi,
        r.pi_end,
        r.scores,
        true_boundaries=gt,
        detected_boundaries=[b.step for b in r.boundaries],
        offline_boundaries=auto,
        high=config.high,
        low=config.low_threshold,
        title=f"{ep.task} seed {ep.seed}: online detector {config.mode}",
    )


def annotate(bag: str, out: Path, episodes: Sequence[Episode], replays: Sequence[ReplayResult],
             spec: ReaderSpec, *, overwrite: bool = False) -> AnnotateReport:
    """Write ``out``: a copy of ``bag`` with the node's ``~/pi``, ``~/segment`` and ``~/boundary``
    added at the observation stamps (:func:`ompn_ros.app.annotate.annotate_bag`); one bag only."""
    bags = resolve_bag_paths(bag)
    if len(bags) != 1:
        raise ReplayError(f"--annotate writes a copy of one bag, but '{bag}' names {len(bags)} bags")
    stamps = observation_stamps(bags[0], episodes, topic=spec.observation.topic, namespace=spec.namespace)
    return annotate_bag(bags[0], out, list(zip(stamps, replays, strict=True)), overwrite=overwrite,
                        sketches=[ep.sketch for ep in episodes])


def store_tuned(checkpoint: str | Path, best: DetectorConfig, metrics: Metrics, provenance: str,
                duration_model: DurationModel | None = None) -> Path:
    """Store a tuned online detector in the checkpoint's ``detector.json``
    (:func:`ompn_ros.detect.choose.with_tuned`).  Returns the file."""
    stored = load_detector_settings(checkpoint)
    return save_detector_settings(checkpoint, with_tuned(stored, best, metrics, provenance, duration_model))


def run_replay(
    policy: Any, episodes: Sequence[Episode], config: DetectorConfig, out: Path, plot_episodes: int = 3,
    *, replays: Sequence[ReplayResult] | None = None, duration_model: DurationModel | None = None,
    head: BoundaryHead | None = None,
) -> dict[str, Any]:
    """Replay ``episodes`` (unless ``replays`` are given) and write the output files into ``out``;
    returns the summary.  ``duration_model``: the model of an online detector of mode 'hsmm' or
    'head_hsmm'; ``head``: the boundary head of mode 'head' or 'head_hsmm'."""
    out.mkdir(parents=True, exist_ok=True)
    if replays is None:
        replays = replay_all(policy, episodes, config, duration_model, head)
    check_finite(replays, episodes)
    arrays: dict[str, np.ndarray] = {}
    for i, r in enumerate(replays):
        for key in ("pi", "p_hat", "pi_end", "expected_position", "scores"):
            arrays[f"ep{i}_{key.rstrip('s') if key == 'scores' else key}"] = getattr(r, key)
    for i, (ep, r) in enumerate(zip(episodes[:plot_episodes], replays, strict=False)):
        _plot(out / f"episode_{i}.png", ep, r, config)
    # every file whole or absent (a full disk fails with one line naming the file: WriteFailure)
    atomic_write(out / "pi.npz", lambda handle: np.savez_compressed(handle, **arrays))  # type: ignore[arg-type]
    doc = [_episode_doc(i, ep, r) for i, (ep, r) in enumerate(zip(episodes, replays, strict=True))]
    atomic_write_text(out / "boundaries.json", json.dumps({"detector": config.to_dict(), "episodes": doc},
                                                          indent=1))
    summary: dict[str, Any] = {"episodes": len(episodes), "detector": config.to_dict()}
    if episodes and all(ep.subtask is not None for ep in episodes):
        summary["metrics"] = compare_detectors(policy, episodes, {"online": config}, replays=replays,
                                               duration_model=duration_model, head=head)
        atomic_write_text(out / "metrics.json", json.dumps(json_safe(summary["metrics"]), indent=1))
    return summary
