"""Batch segmentation: many bags replayed through the online segmenter over a pool of processes.

This is the library behind ``ompn_segment --bags SOURCE --jobs N``.  Every bag is one task
(:func:`segment_bag`): read it, replay its episodes through the
:class:`~ompn_ros.segmenter.StreamingSegmenter` the node runs (``app/replay.py``), optionally
write its annotated copy (``data/annotate.py``), then its record (``batch_bags.py``): the segments, the
per-episode scores when it has labels, or the one-line reason it was refused.  A bag that fails is
refused and the others go on (a bag that is missing, vanishes, dangles or cannot be read included).
A rerun skips the bags whose record is complete for the same settings and bag files and redoes the
rest; the run's table and summary are rebuilt from all records (``batch_table.py``), so a killed run
loses no completed bag.  The workers, stopping on SIGINT/SIGTERM and the start-up paid once:
``batch_pool.py``; one shard of the bags per machine: ``shards.py``.

Cost: one model step per observation (O(Σ T) over all bags), plus one pass over a bag for its
observation stamps; memory: one bag's episodes per worker.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import sys
import time
import traceback
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ompn_ros.app import batch_bags as records
from ompn_ros.app.annotate import annotate_bag, observation_stamps
from ompn_ros.app.batch_bags import BatchBag
from ompn_ros.app.batch_pool import HardStop, Pool, Stop
from ompn_ros.app.errors import AnnotateError, ReplayError
from ompn_ros.app.replay import check_finite, reader_spec, replay_all
from ompn_ros.app.segment_setup import load_stepper
from ompn_ros.data.episode import Episode
from ompn_ros.data.errors import BagError
from ompn_ros.data.reader import OnError, ReaderSpec, read_episodes
from ompn_ros.detect.duration import DurationModel
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.errors import KNOWN_ERRORS, error_line
from ompn_ros.metrics import alignment_counts, f1_with_tolerance
from ompn_ros.model.load import Stepper, stepper_from_checkpoint
from ompn_ros.model.streaming import Backend
from ompn_ros.segmenter import ReplayResult


@dataclass(frozen=True)
class BatchSettings:
    """What every task of a batch shares.

    Attributes:
        checkpoint: the checkpoint (or ensemble) directory.
        detector: the online detector (resolved once, ``detect/settings.py``), its duration model and
            boundary head.
        out: the run's folder (records, table, summary).
        annotate: the folder of annotated copies (None: none written).
        reader_config, domain, on_error: how bags are read (``app/replay.py``).
        device: where the policy steps: 'cpu' (the compiled kernel) or 'cuda' (its torch module).
    """

    checkpoint: str
    detector: DetectorConfig
    out: Path
    duration_model: DurationModel | None = None
    head: BoundaryHead | None = None
    annotate: Path | None = None
    reader_config: str | None = None
    domain: str | None = None
    on_error: OnError = "raise"
    device: str = "cpu"

    def fingerprint(self) -> dict[str, Any]:
        """What a complete record must have been made with (else the bag is redone): the checkpoint's
        files (size, newest change), the detector, the reader spec, ``on_error``, whether copies are made."""
        spec = Path(self.reader_config).read_bytes() if self.reader_config else b""
        doc = {"checkpoint": str(Path(self.checkpoint).resolve()),
               "checkpoint_stamp": records.bag_stamp(Path(self.checkpoint)),
               "detector": self.detector.to_dict(),
               "reader": hashlib.sha256(spec).hexdigest() if spec else self.domain or "",
               "on_error": self.on_error, "annotate": self.annotate is not None}
        return dict(json.loads(json.dumps(doc)))  # as read back from a record


_STEPPERS: dict[tuple[str, str], Stepper] = {}


def _stepper(checkpoint: str, device: str = "cpu") -> Stepper:
    """One stepper per checkpoint, device and process (loaded by :func:`preload`, or by the first
    task of a spawned worker)."""
    if (checkpoint, device) not in _STEPPERS:
        backend: Backend = "jit" if device == "cpu" else "torch"
        _STEPPERS[checkpoint, device] = stepper_from_checkpoint(checkpoint, backend, device)
    return _STEPPERS[checkpoint, device]


_SPECS: dict[tuple[str | None, str | None, str], ReaderSpec] = {}


def _reader_spec(settings: BatchSettings) -> ReaderSpec:
    """The reader spec of a run, read once per process (the parent reads it before the workers are
    forked, :func:`run_batch`): not twice per bag, YAML and checkpoint config each time."""
    key = settings.reader_config, settings.domain, settings.checkpoint
    if key not in _SPECS:
        _SPECS[key] = reader_spec(*key)
    return _SPECS[key]


def preload(checkpoint: str, device: str = "cpu") -> Stepper:
    """Load the stepper of this process before any task (a bad checkpoint refuses the run, not every
    bag; forked workers inherit it: ``batch_pool.py``)."""
    torch.set_num_threads(1)
    if (checkpoint, device) not in _STEPPERS:
        _STEPPERS[checkpoint, device] = load_stepper(checkpoint, device)
    return _STEPPERS[checkpoint, device]


def is_complete(settings: BatchSettings, bag: BatchBag, fingerprint: dict[str, Any]) -> bool:
    """True when ``bag`` has a record of a segmentation with these settings of these bag files."""
    doc = records.read_record(settings.out, bag.key)
    if doc is None or bag.path is None or doc.get("status") != "segmented":
        return False
    try:
        if doc.get("settings") != fingerprint or doc.get("bag_stamp") != records.bag_stamp(bag.path):
            return False
    except OSError:  # gone or unreadable: redone, and refused on its own line
        return False
    return settings.annotate is None or (settings.annotate / bag.key / "metadata.yaml").is_file()


def segment_rows(number: int, ep: Episode, r: ReplayResult, stamps: np.ndarray | None,
                 detector: str) -> list[dict[str, Any]]:
    """One row per subtask the episode reported (see ``batch_table.COLUMNS``): each ends at its
    boundary, the last at the episode's last step (the episode's end closes it, docs/design.md#episode-end);
    an episode without a boundary is one row, its ``score`` empty."""
    rows, start = [], 0
    ends = sorted(r.boundaries, key=lambda e: e.step)
    last = ep.length - 1
    for i, b in enumerate(ends or [None]):
        end = last if i == len(ends) - 1 or b is None else int(b.step)
        subtask = i if b is None else int(b.subtask)
        sketch = ep.sketch
        known = int(sketch[subtask]) if sketch is not None and 0 <= subtask < len(sketch) else None
        rows.append({
            "episode": number, "task": ep.task, "start_step": start, "end_step": end,
            "start_stamp_ns": int(stamps[start]) if stamps is not None else None,
            "end_stamp_ns": int(stamps[end]) if stamps is not None else None,
            "subtask": subtask, "subtask_id": known,
            "score": None if b is None else float(b.score), "detector": detector,
        })
        start = end + 1
    return rows


def episode_scores(episodes: Sequence[Episode],
                   replays: Sequence[ReplayResult]) -> dict[str, list[float]] | None:
    """Per episode: F1 at tolerance 0 and 1 and the alignment counts (authors', strict) of the online
    boundaries; None unless every episode has labels.  Summed over bags they give
    ``detect/tune.score_predictions`` of all episodes."""
    if not episodes or any(ep.subtask is None for ep in episodes):
        return None
    doc: dict[str, list[float]] = {k: [] for k in ("f1_tol0", "f1_tol1", "align", "align_strict", "steps")}
    for ep, r in zip(episodes, replays, strict=True):
        pred, labels = r.boundary_steps, np.asarray(ep.subtask)
        doc["f1_tol0"].append(f1_with_tolerance(pred, ep.boundaries, 0).f1)
        doc["f1_tol1"].append(f1_with_tolerance(pred, ep.boundaries, 1).f1)
        doc["align"].append(alignment_counts(pred, labels, "authors")[0])
        doc["align_strict"].append(alignment_counts(pred, labels, "strict")[0])
        doc["steps"].append(int(labels.size))
    return doc


def _stamps(settings: BatchSettings, path: Path, episodes: Sequence[Episode]) -> list[np.ndarray] | None:
    """The observation stamps of ``episodes`` (None when the bag cannot give them and no copy is due)."""
    spec = _reader_spec(settings)
    try:
        return observation_stamps(path, episodes, topic=spec.observation.topic, namespace=spec.namespace)
    except AnnotateError:
        if settings.annotate is not None:
            raise
        return None


def _segment(settings: BatchSettings, bag: BatchBag, path: Path) -> dict[str, Any]:
    spec = _reader_spec(settings)
    result = read_episodes(path, spec=spec, on_error=settings.on_error)
    episodes = list(result.episodes)
    doc: dict[str, Any] = {"read": True, "read_summary": result.report.summary(), "episodes": len(episodes)}
    if not episodes:
        raise BagError("no episodes found", path=path)
    stepper = _stepper(settings.checkpoint, settings.device)
    replays = replay_all(stepper, episodes, settings.detector, settings.duration_model, settings.head)
    check_finite(replays, episodes)
    stamps = _stamps(settings, path, episodes)
    if settings.annotate is not None and stamps is not None:
        settings.annotate.mkdir(parents=True, exist_ok=True)
        pairs = list(zip(stamps, replays, strict=True))
        annotate_bag(path, settings.annotate / bag.key, pairs, overwrite=True,
                     sketches=[ep.sketch for ep in episodes])
    rows = [row for i, (ep, r) in enumerate(zip(episodes, replays, strict=True))
            for row in segment_rows(i, ep, r, None if stamps is None else stamps[i], settings.detector.mode)]
    return {**doc, "steps": sum(ep.length for ep in episodes), "rows": rows,
            "scores": episode_scores(episodes, replays),
            "annotated": str(settings.annotate / bag.key) if settings.annotate is not None else None}


def segment_bag(settings: BatchSettings, bag: BatchBag, fingerprint: dict[str, Any]) -> dict[str, Any]:
    """Segment one bag and write its record; returns the record.  Never raises for a bad bag (one that
    is missing, vanishes, dangles or cannot be read included)."""
    start = time.perf_counter()
    doc: dict[str, Any] = {"key": bag.key, "bag": str(bag.path or bag.key), "settings": fingerprint}
    if bag.path is None:
        return {**doc, "status": "refused", "reason": bag.problem, "read": False}
    try:
        doc["bag_stamp"] = records.bag_stamp(bag.path)
        doc["bytes"] = doc["bag_stamp"][0]
        doc.update(_segment(settings, bag, bag.path), status="segmented")
    except KNOWN_ERRORS as exc:  # a bad bag: the one-line reason of the commands
        doc.update(status="refused", reason=error_line(exc))
    except Exception as exc:  # a bug: refuse this bag, show the traceback, keep going
        traceback.print_exc(file=sys.stderr)
        doc.update(status="refused", reason=f"unexpected {type(exc).__name__}: {error_line(exc)} (a bug; "
                   f"rerun this bag alone with ompn_segment --bag ... --debug)")
    doc.setdefault("read", False)
    doc["seconds"] = time.perf_counter() - start
    records.write_record(settings.out, bag.key, doc)
    return doc


def _died(bag: BatchBag, reason: str) -> dict[str, Any]:
    """The result of a bag whose worker died (no record: the bag is redone by a rerun)."""
    return {"key": bag.key, "bag": str(bag.path or bag.key), "status": "refused", "read": False,
            "reason": reason}


def _outcomes(settings: BatchSettings, todo: Sequence[BatchBag], jobs: int, fingerprint: dict[str, Any],
              stop: Stop) -> Generator[dict[str, Any], None, None]:
    """Records of ``todo`` as they complete: in this process (``jobs == 1``) or over a pool
    (``batch_pool.py``); none is started once a stop is requested."""
    if jobs <= 1 or len(todo) <= 1:
        for bag in todo:
            if stop.requested:
                return
            yield segment_bag(settings, bag, fingerprint)
        return
    task = functools.partial(segment_bag, settings, fingerprint=fingerprint)
    yield from Pool(task, _died, jobs, settings.device, stop).run(todo)


Progress = Callable[[dict[str, Any], int, int], None]


def run_batch(settings: BatchSettings, bags: Sequence[BatchBag], jobs: int = 1,
              progress: Progress | None = None, stop: Stop | None = None,
              clean: bool = True) -> list[dict[str, Any]]:
    """Segment ``bags`` (``jobs`` worker processes) skipping the complete ones; returns the record of
    every bag done or skipped, in the order of ``bags`` (a skipped bag's with ``skipped: True``): all of
    them unless ``stop`` was requested (then those finished before it).  ``progress(record, done,
    total)`` is called as each bag finishes.  ``clean``: remove the temporary records of killed runs
    first (by process id: not where other machines write into ``settings.out`` too)."""
    if jobs < 1:
        raise ReplayError(f"--jobs must be at least 1, got {jobs}")
    stop = stop or Stop()
    if clean:
        records.clean_temporaries(settings.out)
    fingerprint = settings.fingerprint()
    preload(settings.checkpoint, settings.device)
    with contextlib.suppress(*KNOWN_ERRORS):  # a bad spec: each bag is refused with its line, as before
        _reader_spec(settings)
    found: dict[str, dict[str, Any]] = {}
    todo = []
    for bag in bags:
        if is_complete(settings, bag, fingerprint):
            found[bag.key] = {**(records.read_record(settings.out, bag.key) or {}), "skipped": True}
        else:
            todo.append(bag)
    done = 0
    try:
        for doc in found.values():
            done += 1
            if progress is not None:
                progress(doc, done, len(bags))
        with contextlib.closing(_outcomes(settings, todo, jobs, fingerprint, stop)) as outcomes:
            for doc in outcomes:
                done += 1
                found[doc["key"]] = doc
                if progress is not None:
                    progress(doc, done, len(bags))
    except HardStop:
        pass  # the records of the bags finished are kept; the caller writes them
    finally:
        stop.settle()
    return [found[bag.key] for bag in bags if bag.key in found]


__all__ = ["BatchSettings", "episode_scores", "is_complete", "preload", "run_batch", "segment_bag",
           "segment_rows"]
