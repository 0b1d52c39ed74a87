"""Shards over a LeRobot dataset's episodes, and the one annotated dataset ``aggregate`` makes of them.

``ompn_segment --dataset DIR --num-shards N --shard-index I`` segments the episodes whose
``episode_index`` is ``I`` modulo ``N`` (:func:`episode_shard`): an episode's index never changes, so
every machine computes the same split from the dataset alone, the shards differ by at most one
episode, and episodes appended later join shards without moving the old ones.  A shard reads every
frame file (the columns it needs) and segments its own episodes in it.  After each frame file it
writes that file's *record*, ``OUT/shards/<I>-of-<N>/files/<file>.json`` (its episodes: place in the
dataset, table rows, scores, boundary steps), atomically: a rerun skips the files whose record has the
same settings and file size, so a shard is resumable (a killed one loses the file in progress) and
idempotent.  Its manifest (``app/shards.py``) lists the frame files and their records; its own table,
summary and metrics lie beside it.

A shard writes no dataset, even with ``--write-subtasks``: the records hold every episode's
subtasks, and :func:`merge_episodes` (``shards.MERGERS['episodes']``, run by ``ompn_segment
aggregate``) writes the one annotated dataset from them with the writer a whole run uses
(``app/lerobot_write.py``), into a staging folder renamed into place once it is whole: the dataset of
one unsharded run, frame for frame.  The table is the records' rows in the dataset's order (the
table of one run, row for row).  An annotated dataset cannot be partial: a missing or failed shard
stops the merge before anything is written (``shards.PARTIAL``).

Cost: a shard reads every frame file's columns (cheap beside the model) and steps its episodes only;
the merge reads and rewrites the frame files once, without the model.
"""

from __future__ import annotations

import functools
import json
import shutil
import time
from pathlib import Path
from typing import Any

from ompn_ros.app import shards
from ompn_ros.app.batch_bags import bag_stamp
from ompn_ros.app.errors import ReplayError
from ompn_ros.app.lerobot_segment import (
    DatasetRun,
    EpisodeDone,
    Progress,
    dataset_summary,
    load_dataset_stepper,
    segment_file,
    write_dataset_outputs,
)
from ompn_ros.app.lerobot_write import SubtaskWriter, resolve_format, share_dataset
from ompn_ros.atomic import atomic_write_text, make_temp_dir, umask_mode
from ompn_ros.data.lerobot import DatasetReader, DatasetSpec

KIND = "episodes"
RECORDS = "files"
RECORD_FORMAT = "ompn_ros.dataset_shard_file"
SUBTASKS_RECORD = Path("meta/ompn_subtasks.json")


def episode_shard(index: int, count: int) -> int:
    """The shard of episode ``index`` among ``count``."""
    return index % count


def shard_settings(run: DatasetRun, source: Path) -> dict[str, Any]:
    """What a complete record must have been made with (else its frame file is redone)."""
    doc = {"dataset": str(source.resolve()), "checkpoint": str(Path(run.checkpoint).resolve()),
           "checkpoint_stamp": bag_stamp(Path(run.checkpoint)), "detector": run.detector.to_dict(),
           "spec": run.spec.to_dict(), "boundaries": run.boundaries, "subtasks": run.subtasks,
           "format": resolve_format(run.fmt) if run.fmt else None}
    return dict(json.loads(json.dumps(doc)))  # as read back from a record


def record_name(key: str) -> str:
    """The record of the frame file ``key`` (its path in the dataset), below the shard's folder."""
    return f"{RECORDS}/{key.removesuffix('.parquet').replace('/', '__')}.json"


def _complete(path: Path, settings: dict[str, Any], size: int) -> dict[str, Any] | None:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != RECORD_FORMAT:
        return None
    return doc if doc.get("settings") == settings and doc.get("bytes") == size else None


def run_shard(run: DatasetRun, dataset: str | Path, count: int, index: int,
              progress: Progress | None = None) -> dict[str, Any]:
    """Segment the episodes of shard ``index`` of ``count`` (see the module doc); returns its summary."""
    start = time.perf_counter()
    source = Path(dataset)
    reader = DatasetReader(source, run.spec, select=lambda e: episode_shard(e, count) == index)
    folder = shards.shard_dir(run.out, count, index)
    settings = shard_settings(run, source)
    files = reader.layout.data_files()
    keys = [str(reader.layout.relative(path)) for path in files]
    record = functools.partial(_record_below_out, count, index)
    note = functools.partial(shards.write_manifest, run.out, count, index, list(enumerate(keys)), len(keys),
                             settings, kind=KIND, record=record)
    note("running")
    notes, done, stepper = list(reader.notes), [], None
    for ordinal, (path, key) in enumerate(zip(files, keys, strict=True)):
        target = folder / record_name(key)
        doc = _complete(target, settings, path.stat().st_size)
        if doc is None:
            stepper = stepper or load_dataset_stepper(run)
            began, before = time.perf_counter(), len(reader.notes)
            found = segment_file(run, stepper, reader.read_file(path), ordinal, str(source))
            doc = {"format": RECORD_FORMAT, "settings": settings, "file": key, "bytes": path.stat().st_size,
                   "dataset": str(source), "notes": reader.notes[before:],
                   "seconds": time.perf_counter() - began, "episodes": [vars(e) for e in found]}
            atomic_write_text(target, json.dumps(doc))
        done += [EpisodeDone.from_dict(e) for e in doc["episodes"]]
        notes += doc["notes"]
        if progress is not None:
            progress(f"shard {index} of {count}: {key}: {len(doc['episodes'])} episodes, {len(done)} so far")
    summary = dataset_summary(str(source), done, run.boundaries, notes)
    summary["shard"] = {"count": count, "index": index}
    summary = write_dataset_outputs(folder, done, summary, time.perf_counter() - start)
    note("complete")
    return summary


def _record_below_out(count: int, index: int, key: str) -> str:
    return f"{shards.SHARDS}/{index}-of-{count}/{record_name(key)}"


def merge_episodes(result: shards.Aggregate, target: shards.MergeTarget) -> dict[str, Any]:
    """The table and, when the shards recorded a format, the one annotated dataset of every shard's
    records (``result``: all shards complete)."""
    settings = result.settings
    done = sorted((EpisodeDone.from_dict(e) for doc in result.docs for e in doc["episodes"]),
                  key=lambda e: e.position)
    notes = [*dict.fromkeys(n for doc in result.docs for n in doc["notes"])]
    if not done:
        raise ReplayError("the shards' records hold no episode of two frames or more")
    source = target.source or Path(settings["dataset"])
    summary = dataset_summary(result.docs[0]["dataset"], done, settings["boundaries"], notes)
    if settings["format"] is not None:
        written = _annotated(settings, done, source, target.annotate or target.out / "dataset")
        summary.update(format=settings["format"], written=str(written), in_place=False)
    seconds = sum(float(doc.get("seconds", 0.0)) for doc in result.docs)
    return write_dataset_outputs(target.out, done, summary, seconds)


def _annotated(settings: dict[str, Any], done: list[EpisodeDone], source: Path, final: Path) -> Path:
    """Write the annotated dataset ``final`` from ``source`` and the episodes' boundary steps: in a
    staging folder beside it, renamed into place when whole (a previous aggregate's is replaced)."""
    if final.exists() and any(final.iterdir()) and not (final / SUBTASKS_RECORD).is_file():
        raise ReplayError(f"{final} exists and is not an annotated dataset written by ompn_segment: give "
                          "another --annotate DIR")
    stage = make_temp_dir(final.parent, final.name)
    try:
        share_dataset(source, stage)
        _write_subtasks(stage, DatasetSpec.from_dict(settings["spec"]), settings, done)
        stage.chmod(umask_mode(directory=True))
        if final.exists():
            old = make_temp_dir(final.parent, final.name, "old")
            final.rename(old / final.name)
            stage.rename(final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            stage.rename(final)
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)
    return final


def _write_subtasks(root: Path, spec: DatasetSpec, settings: dict[str, Any], done: list[EpisodeDone]) -> None:
    """The format of ``settings`` written into the dataset at ``root`` (a share of the source)."""
    fmt = str(settings["format"])
    steps = {e.index: e.steps for e in done}
    reader = DatasetReader(root, spec)
    writer = SubtaskWriter(reader.layout, fmt)
    for file in reader.files(whole=fmt in ("index-v1", "language-v1")):
        unknown = [ep.index for ep in file.episodes if ep.index not in steps]
        if unknown:
            raise ReplayError(f"episode {unknown[0]} of {reader.layout.relative(file.path)} is in no shard's "
                              "records: the dataset changed since the shards ran, or --dataset names another "
                              "one; rerun the shards")
        writer.add_file(file, steps)
    writer.finish({"checkpoint": settings["checkpoint"], "boundaries": settings["boundaries"],
                   "detector": settings["detector"]})


shards.MERGERS[KIND] = merge_episodes

__all__ = ["KIND", "episode_shard", "merge_episodes", "record_name", "run_shard", "shard_settings"]
