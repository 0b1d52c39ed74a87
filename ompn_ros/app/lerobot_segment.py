"""Segment a LeRobot dataset: ``ompn_segment --dataset DIR``, the dataset counterpart of a batch of bags.

Every episode is replayed through the :class:`~ompn_ros.segmenter.StreamingSegmenter` the node runs
(``app/replay.py``): the boundaries are what ``ompn_node`` would have published for the episode's
frames (``boundaries='online'``, the default), or the offline Top-K of the same replay
(``'top_k'``: K subtasks per episode, from ``subtasks`` or from the episode's labels).  The outputs
are the segments table of batch runs (``batch_table.py``: ``segments.csv``/``.parquet``, with the
dataset as the ``bag`` column, ``episode_index`` as the episode and frame timestamps as stamps),
``summary.json``, ``metrics.json`` when the dataset has labels, and, with a format, the subtasks
written back (``app/lerobot_write.py``) into a new dataset folder sharing the unchanged files or, in
place, into the dataset itself.

Streaming: one frame file at a time is read, segmented and (for the per-frame formats) rewritten, so
the peak memory does not grow with the number of episodes.  Cost: one model step per frame.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ompn_ros.app import batch_table
from ompn_ros.app.batch import episode_scores, segment_rows
from ompn_ros.app.errors import ReplayError
from ompn_ros.app.lerobot_write import BOUNDARIES, Boundaries, SubtaskWriter, resolve_format, share_dataset
from ompn_ros.app.replay import check_finite, replay_all
from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.lerobot import DatasetEpisode, DatasetFile, DatasetReader, DatasetSpec
from ompn_ros.detect import offline
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import BoundaryEvent, DetectorConfig
from ompn_ros.model.load import Stepper, stepper_from_checkpoint
from ompn_ros.segmenter import ReplayResult


@dataclass(frozen=True)
class DatasetRun:
    """One segmentation of a dataset.

    Attributes:
        checkpoint, detector, duration_model, head: the model and its online detector (as batch runs).
        out: the folder of the table, ``summary.json`` and ``metrics.json``.
        spec: which features are the observation, the action and the labels.
        boundaries: 'online' (what the node publishes) or 'top_k' (offline, ``subtasks`` per episode or
            the labels' count).
        fmt: the subtask format written back (None: none, only the table).
        annotate: the new dataset folder (default ``out/dataset``); ``in_place``: the dataset itself.
    """

    checkpoint: str
    detector: DetectorConfig
    out: Path
    spec: DatasetSpec = field(default_factory=DatasetSpec)
    duration_model: DurationModel | None = None
    head: BoundaryHead | None = None
    boundaries: Boundaries = "online"
    subtasks: int | None = None
    fmt: str | None = None
    annotate: Path | None = None
    in_place: bool = False
    overwrite: bool = False
    device: str = "cpu"


def dataset_spec(path: str | None) -> DatasetSpec:
    """The dataset spec of the YAML file ``path`` (None: the default features)."""
    return DatasetSpec.from_yaml(path) if path else DatasetSpec()


def _top_k(r: ReplayResult, k: int) -> list[BoundaryEvent]:
    """The ``k`` offline Top-K boundaries of a replay (on the stepped rows of a still-tolerant model)."""
    ends = None if r.run_ends is None else np.asarray(r.run_ends, dtype=np.int64)
    p_hat = r.p_hat if ends is None else r.p_hat[ends]
    found = offline.top_k_boundaries(p_hat, k)
    steps = sorted(int(s) for s in (found if ends is None else ends[found]))
    last = len(r.scores) - 1
    return [BoundaryEvent(step=s, detected_at=last, subtask=i, score=float(r.scores[s]), level=0, stamp_ns=0,
                          final=i == len(steps) - 1) for i, s in enumerate(steps)]


def _decided(run: DatasetRun, eps: list[DatasetEpisode], replays: list[ReplayResult]) -> list[ReplayResult]:
    """The replays with the boundaries ``run.boundaries`` asks for."""
    if run.boundaries == "online":
        return replays
    done = []
    for ep, r in zip(eps, replays, strict=True):
        k = run.subtasks or (len(ep.episode.boundaries) if ep.episode.subtask is not None else 0)
        if k < 1:
            raise ReplayError(f"--boundaries top_k needs --subtasks K or labels (episode {ep.index} has "
                              "none)")
        done.append(dataclasses.replace(r, boundaries=_top_k(r, k)))
    return done


def _target(run: DatasetRun, dataset: Path) -> Path:
    """The dataset the subtasks are written into (made as a copy sharing the files, unless in place)."""
    if run.in_place:
        return dataset
    target = run.annotate or run.out / "dataset"
    share_dataset(dataset, target, run.overwrite)
    return target


Progress = Callable[[str], None]
POSITION_STRIDE = 1 << 40
"""An episode's place in the dataset is ``file ordinal * POSITION_STRIDE + its first row in the file``:
the order of a whole run's rows, known to a shard that reads only its own episodes."""


@dataclass
class EpisodeDone:
    """One segmented episode: its ``index`` (``episode_index``), ``position`` (:data:`POSITION_STRIDE`),
    ``frames``, its table ``rows``, its ``scores`` (None without labels) and boundary ``steps``."""

    index: int
    position: int
    frames: int
    rows: list[dict[str, Any]]
    scores: dict[str, list[float]] | None
    steps: list[int]

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> EpisodeDone:
        return cls(int(doc["index"]), int(doc["position"]), int(doc["frames"]), list(doc["rows"]),
                   doc["scores"], [int(s) for s in doc["steps"]])


def load_dataset_stepper(run: DatasetRun) -> Stepper:
    """The model a dataset run steps (one torch thread)."""
    torch.set_num_threads(1)
    return stepper_from_checkpoint(run.checkpoint, "jit" if run.device == "cpu" else "torch", run.device)


def segment_file(run: DatasetRun, stepper: Stepper, file: DatasetFile, ordinal: int,
                 source: str) -> list[EpisodeDone]:
    """Segment the episodes of ``file`` (the ``ordinal``-th frame file of the dataset ``source``)."""
    eps = [e.episode for e in file.episodes]
    if not eps:
        return []
    replays = replay_all(stepper, eps, run.detector, run.duration_model, run.head)
    check_finite(replays, eps)
    replays = _decided(run, file.episodes, replays)
    mode = run.detector.mode if run.boundaries == "online" else "top_k"
    done = []
    for ep, r in zip(file.episodes, replays, strict=True):
        rows = [{"bag": source, **row} for row in segment_rows(ep.index, ep.episode, r, ep.stamps_ns(), mode)]
        done.append(EpisodeDone(ep.index, ordinal * POSITION_STRIDE + ep.start, ep.frames, rows,
                                episode_scores([ep.episode], [r]), [int(b.step) for b in r.boundaries]))
    return done


def segment_dataset(run: DatasetRun, dataset: str | Path, progress: Progress | None = None) -> dict[str, Any]:
    """Segment ``dataset`` as ``run`` says; returns the summary (also ``out/summary.json``)."""
    start = time.perf_counter()
    source = Path(dataset)
    reader = DatasetReader(source, run.spec)  # a bad spec is refused before anything is written
    fmt = resolve_format(run.fmt) if run.fmt else None
    if fmt is not None:
        reader = DatasetReader(_target(run, source), run.spec)
    writer = SubtaskWriter(reader.layout, fmt) if fmt is not None else None
    stepper = load_dataset_stepper(run)
    done: list[EpisodeDone] = []
    for ordinal, file in enumerate(reader.files(whole=fmt in ("index-v1", "language-v1"))):
        found = segment_file(run, stepper, file, ordinal, str(source))
        done += found
        if writer is not None:
            writer.add_file(file, {e.index: e.steps for e in found})
        if progress is not None:
            progress(f"{reader.layout.relative(file.path)}: {len(found)} episodes, {len(done)} so far")
    if not done:
        raise ReplayError(f"no episode of two frames or more in {source}")
    summary = dataset_summary(str(source), done, run.boundaries, reader.notes)
    if writer is not None:
        writer.finish(provenance(run))
        summary.update(format=fmt, written=str(reader.layout.root), in_place=run.in_place)
    return write_dataset_outputs(run.out, done, summary, time.perf_counter() - start)


def provenance(run: DatasetRun) -> dict[str, Any]:
    """What ``meta/ompn_subtasks.json`` records of the run besides the format."""
    return {"checkpoint": str(Path(run.checkpoint).resolve()), "boundaries": run.boundaries,
            "detector": run.detector.to_dict()}


def dataset_summary(source: str, done: list[EpisodeDone], boundaries: str,
                    notes: list[str]) -> dict[str, Any]:
    """The summary of the episodes ``done`` (before the table and the times are added)."""
    return {"dataset": source, "episodes": len(done), "frames": sum(e.frames for e in done),
            "segments": sum(len(e.rows) for e in done), "boundaries": boundaries, "notes": notes}


def write_dataset_outputs(out: Path, done: list[EpisodeDone], summary: dict[str, Any],
                          seconds: float) -> dict[str, Any]:
    """The table, ``metrics.json`` (labels) and ``summary.json`` of the episodes ``done``, in their order."""
    out.mkdir(parents=True, exist_ok=True)
    summary["table"] = [str(p) for p in batch_table.write_table(out, [row for e in done for row in e.rows])]
    unlabelled = any(e.scores is None for e in done)
    scores = None if unlabelled else [{"status": "segmented", "scores": e.scores} for e in done]
    metrics = batch_table.batch_metrics(scores) if scores else None
    if metrics is not None:
        summary["metrics"] = metrics
        atomic_write_text(out / batch_table.METRICS, json.dumps(metrics, indent=1) + "\n")
    summary.update(seconds=seconds, frames_per_s=summary["frames"] / seconds if seconds > 0 else None)
    atomic_write_text(out / batch_table.SUMMARY, json.dumps(summary, indent=1) + "\n")
    return summary


__all__ = ["BOUNDARIES", "POSITION_STRIDE", "DatasetRun", "EpisodeDone", "dataset_spec", "dataset_summary",
           "load_dataset_stepper", "provenance", "segment_dataset", "segment_file", "write_dataset_outputs"]
