"""Subtasks written back into a LeRobot dataset, in one of LeRobot's formats (docs/lerobot.md).

A *format* is named with its version, so that a name keeps its meaning when LeRobot's format moves on
(``index`` etc. name the newest version of each):

* ``index-v1``: a per-frame ``subtask_index`` (int64) in the frame files, its feature in
  ``meta/info.json`` and ``meta/subtasks.parquet`` (the subtask strings as the pandas index, column
  ``subtask_index``): LeRobot's first subtask format (early 2026, now called legacy).
* ``language-v1``: per frame ``language_persistent``, a list of rows ``{role: assistant, content:
  <subtask>, style: subtask, timestamp: <start of the subtask, s, float32>, camera: null, tool_calls:
  null}``, the same list on every frame of an episode (rows of other styles already there are kept),
  and ``language_events`` (kept, else empty); both declared ``dtype: language`` in ``meta/info.json``:
  LeRobot's current annotation format.
* ``episodes-v1``: per episode, in ``meta/episodes/``: ``subtask_names``, ``subtask_start_frames``,
  ``subtask_end_frames`` (frames within the episode, both inclusive), ``subtask_start_times`` and
  ``subtask_end_times`` (s): the columns LeRobot's SARM reward model reads.

Subtask ``k`` of an episode (0-based, in time order) is named ``"subtask k"``; it covers the frames
from the one after the previous boundary to its own boundary, and the last one runs to the last frame.
An episode of one frame (left out of the segmentation) is its subtask 0 in ``index``, and has no rows
or columns in the other formats.

Where: :func:`share_dataset` makes a new dataset folder of hard links to the unchanged files (symbolic
links across filesystems; videos are never copied); the files a format changes are then written there
(or, in place, in the dataset itself) each to a temporary sibling renamed into place
(``ompn_ros/atomic.py``), so an interrupted run leaves every file whole and a rerun completes it.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ompn_ros.atomic import atomic_write, atomic_write_text
from ompn_ros.data.errors import DatasetError
from ompn_ros.data.lerobot import DatasetFile, DatasetLayout, pyarrow_modules
from ompn_ros.data.lerobot.layout import INFO

Boundaries = Literal["online", "top_k"]
BOUNDARIES: tuple[Boundaries, ...] = ("online", "top_k")
"""Where the written subtasks come from: the online segmenter (what the node publishes) or Top-K."""
FORMATS = ("index-v1", "language-v1", "episodes-v1")
ALIASES = {"index": "index-v1", "language": "language-v1", "episodes": "episodes-v1"}
SUBTASKS = Path("meta/subtasks.parquet")
EPISODE_COLUMNS = ("subtask_names", "subtask_start_times", "subtask_end_times", "subtask_start_frames",
                   "subtask_end_frames")


def resolve_format(name: str) -> str:
    """The versioned format ``name`` means (an alias names the newest version)."""
    found = ALIASES.get(name, name)
    if found not in FORMATS:
        raise DatasetError(f"unknown subtask format '{name}': one of {sorted([*ALIASES, *FORMATS])}")
    return found


def subtask_name(ordinal: int) -> str:
    return f"subtask {ordinal}"


def frame_segments(steps: Sequence[int], frames: int) -> tuple[list[int], list[int]]:
    """First and last frame of each subtask of an episode of ``frames`` frames whose boundaries (the last
    step of each subtask, in ``[0, frames - 2]``) are ``steps``; the last subtask ends at the last frame."""
    cuts = sorted({int(s) for s in steps if 0 <= int(s) < frames - 2})
    return [0, *[c + 1 for c in cuts]], [*cuts, frames - 1]


def frame_ordinals(steps: Sequence[int], frames: int) -> np.ndarray:
    """The subtask ordinal of every frame (:func:`frame_segments`)."""
    starts, _ = frame_segments(steps, frames)
    return (np.searchsorted(np.asarray(starts), np.arange(frames), side="right") - 1).astype(np.int64)


def _link(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:  # another filesystem, or links refused: a symbolic link, never a copy
        os.symlink(source.resolve(), target)


def share_dataset(source: Path, out: Path, overwrite: bool = False) -> None:
    """Make ``out`` a dataset sharing every file of ``source`` (hard links, else symbolic links)."""
    src, dst = source.resolve(), out.resolve()
    if src == dst or src in dst.parents or dst in src.parents:
        raise DatasetError(f"the annotated dataset {out} must lie outside the dataset (or use --in-place)",
                           path=source)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise DatasetError(f"{out} exists and is not empty: pass --overwrite to replace it", path=source)
        if not (out / INFO).is_file():
            raise DatasetError(f"--overwrite replaces only a dataset folder, and {out} has no {INFO}",
                               path=source)
        shutil.rmtree(out)
    for path in sorted(src.rglob("*")):
        target = dst / path.relative_to(src)
        if path.is_dir():
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            _link(path, target)


@dataclass
class EpisodeSubtasks:
    """The subtasks of one episode in frames (:func:`frame_segments`) and seconds."""

    starts: list[int]
    ends: list[int]
    start_times: list[float]
    end_times: list[float]


@dataclass
class SubtaskWriter:
    """Writes one format into the dataset at ``layout`` (the copy, or the dataset itself in place):
    :meth:`add_file` per frame file, then :meth:`finish` for the metadata."""

    layout: DatasetLayout
    fmt: str
    episodes: dict[int, EpisodeSubtasks] = field(default_factory=dict)
    most: int = 0  # the largest number of subtasks of an episode

    def add_file(self, file: DatasetFile, steps: Mapping[int, Sequence[int]]) -> None:
        """Record the subtasks of ``file``'s episodes (boundary steps per episode index) and rewrite the
        frame file for the per-frame formats."""
        # a frame of no episode read (one frame long: nothing to segment) is that episode's subtask 0
        per_frame = np.zeros(file.table.num_rows if file.table is not None else 0, np.int64)
        for ep in file.episodes:
            starts, ends = frame_segments(steps.get(ep.index, ()), ep.frames)
            times = ep.timestamps
            self.episodes[ep.index] = EpisodeSubtasks(starts, ends, [float(times[s]) for s in starts],
                                                      [float(times[e]) for e in ends])
            self.most = max(self.most, len(starts))
            if per_frame.size:
                per_frame[ep.start:ep.stop] = frame_ordinals(steps.get(ep.index, ()), ep.frames)
        if self.fmt == "episodes-v1":
            return
        if file.table is None:
            raise ValueError("add_file needs the frame file's whole table for a per-frame format")
        table = self._indexed(file.table, per_frame) if self.fmt == "index-v1" else self._language(file)
        _write_table(file.path, table)  # the reader reads the dataset being written (copy or in place)

    def _indexed(self, table: Any, per_frame: np.ndarray) -> Any:
        pa, _ = pyarrow_modules()
        if "subtask_index" in table.column_names:
            table = table.drop_columns(["subtask_index"])
        table = table.append_column(pa.field("subtask_index", pa.int64()), pa.array(per_frame))
        return table.replace_schema_metadata(_hf_metadata(table.schema.metadata, {"subtask_index": {
            "dtype": "int64", "_type": "Value"}}))

    def _language(self, file: DatasetFile) -> Any:
        pa, _ = pyarrow_modules()
        table = file.table
        names = table.column_names
        old = table.column("language_persistent").to_pylist() if "language_persistent" in names else None
        rows: list[list[dict[str, Any]]] = [[] for _ in range(table.num_rows)]
        for ep in file.episodes:
            kept = [r for r in (old[ep.start] or [])] if old is not None else []
            subtasks = self.episodes[ep.index]
            new = [{"role": "assistant", "content": subtask_name(k), "style": "subtask", "timestamp": t,
                    "camera": None, "tool_calls": None} for k, t in enumerate(subtasks.start_times)]
            merged = sorted([r for r in kept if r.get("style") != "subtask"] + new,
                            key=lambda r: (float(r["timestamp"]), r.get("style") or "", r.get("role") or ""))
            for i in range(ep.start, ep.stop):
                rows[i] = merged
        events = (table.column("language_events") if "language_events" in table.column_names
                  else pa.array([[] for _ in range(table.num_rows)], type=pa.list_(_event_row(pa))))
        table = table.drop_columns([c for c in ("language_persistent", "language_events") if c in names])
        table = table.append_column("language_persistent", pa.array(rows, type=pa.list_(_persistent_row(pa))))
        table = table.append_column("language_events", events)
        metadata = {k: v for k, v in (table.schema.metadata or {}).items() if k != b"huggingface"}
        return table.replace_schema_metadata(metadata or None)

    def finish(self, provenance: dict[str, Any]) -> list[Path]:
        """Write the metadata of the format; returns the files written."""
        written: list[Path] = []
        if self.fmt == "episodes-v1":
            written += self._episode_tables()
        info = dict(self.layout.info)
        features = dict(info["features"])
        if self.fmt == "index-v1":
            features["subtask_index"] = {"dtype": "int64", "shape": [1], "names": None}
            written.append(_write_subtasks(self.layout.root / SUBTASKS, max(self.most, 1)))
        elif self.fmt == "language-v1":
            for name in ("language_persistent", "language_events"):
                features[name] = {"dtype": "language", "shape": [1], "names": None}
        info["features"] = features
        atomic_write_text(self.layout.root / "meta/ompn_subtasks.json", json.dumps(
            {"format": self.fmt, **provenance}, indent=1) + "\n")
        atomic_write_text(self.layout.root / INFO, json.dumps(info, indent=4) + "\n")
        return [*written, self.layout.root / "meta/ompn_subtasks.json", self.layout.root / INFO]

    def _episode_tables(self) -> list[Path]:
        pa, pq = pyarrow_modules()
        written = []
        for path in self.layout.episode_files():
            table = pq.read_table(path)
            table = table.drop_columns([c for c in EPISODE_COLUMNS if c in table.column_names])
            found = [self.episodes.get(int(i)) for i in table.column("episode_index").to_pylist()]
            values = {
                "subtask_names": ([subtask_name(k) for k in range(len(s.starts))] if s else None
                                  for s in found),
                "subtask_start_times": (s.start_times if s else None for s in found),
                "subtask_end_times": (s.end_times if s else None for s in found),
                "subtask_start_frames": (s.starts if s else None for s in found),
                "subtask_end_frames": (s.ends if s else None for s in found),
            }
            types = {"subtask_names": pa.string(), "subtask_start_times": pa.float64(),
                     "subtask_end_times": pa.float64(), "subtask_start_frames": pa.int64(),
                     "subtask_end_frames": pa.int64()}
            for name in EPISODE_COLUMNS:
                table = table.append_column(name, pa.array(list(values[name]), type=pa.list_(types[name])))
            _write_table(path, table)
            written.append(path)
        if not written:
            raise DatasetError("no episode table (meta/episodes/chunk-*/file-*.parquet) to write into",
                               path=self.layout.root)
        return written


def _persistent_row(pa: Any) -> Any:
    return pa.struct([pa.field("role", pa.string(), nullable=False), ("content", pa.string()),
                      ("style", pa.string()), pa.field("timestamp", pa.float32(), nullable=False),
                      ("camera", pa.string()), ("tool_calls", pa.list_(pa.string()))])


def _event_row(pa: Any) -> Any:
    return pa.struct([pa.field("role", pa.string(), nullable=False), ("content", pa.string()),
                      ("style", pa.string()), ("camera", pa.string()), ("tool_calls", pa.list_(pa.string()))])


def _hf_metadata(metadata: dict[bytes, bytes] | None, added: dict[str, Any]) -> dict[bytes, bytes] | None:
    """The schema metadata with ``added`` in Hugging Face's feature list (when the file has one)."""
    if not metadata or b"huggingface" not in metadata:
        return metadata
    try:
        doc = json.loads(metadata[b"huggingface"])
        doc["info"]["features"].update(added)
    except (ValueError, KeyError, TypeError):  # not the layout we know: leave it out rather than mislead
        return {k: v for k, v in metadata.items() if k != b"huggingface"} or None
    return {**metadata, b"huggingface": json.dumps(doc).encode()}


def _write_table(path: Path, table: Any) -> None:
    """``table`` to ``path`` atomically, with the mode of the file it replaces (else rw-r--r--)."""
    _, pq = pyarrow_modules()
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    atomic_write(path, lambda handle: pq.write_table(table, handle, compression="snappy"))
    path.chmod(mode)


def _write_subtasks(path: Path, count: int) -> Path:
    """``meta/subtasks.parquet``: the subtask names as the pandas index, ``subtask_index`` beside it."""
    pa, _ = pyarrow_modules()
    pandas = {"index_columns": ["subtask"], "column_indexes": [], "creator": {"library": "pyarrow",
              "version": pa.__version__}, "pandas_version": "2.0.0", "columns": [
        {"name": "subtask_index", "field_name": "subtask_index", "pandas_type": "int64",
         "numpy_type": "int64", "metadata": None},
        {"name": "subtask", "field_name": "subtask", "pandas_type": "unicode", "numpy_type": "object",
         "metadata": None}]}
    table = pa.table({"subtask_index": pa.array(range(count), pa.int64()),
                      "subtask": pa.array([subtask_name(k) for k in range(count)], pa.string())})
    _write_table(path, table.replace_schema_metadata({b"pandas": json.dumps(pandas).encode()}))
    return path


__all__ = ["ALIASES", "EPISODE_COLUMNS", "FORMATS", "SUBTASKS", "EpisodeSubtasks", "SubtaskWriter",
           "frame_ordinals", "frame_segments", "resolve_format", "share_dataset", "subtask_name"]
