"""LeRobot dataset -> Episodes, one frame file at a time.

Step contract: an episode of ``N`` frames is ``T = N - 1`` steps.  Frame ``t < T`` gives observation
row ``t`` and action ``t``; the last frame's observation is the final observation (row ``T``) and its
action is not used, so a replay steps exactly the ``N`` observations the robot recorded, as the node
would have.  Labels (optional) give ``Episode.subtask`` for the ``T`` steps: ``label_kind: id`` makes a
new ordinal wherever the value changes (the values are kept in ``extras['subtask_id']``), ``ordinal``
takes them as they are.  Stamps are the frames' ``timestamp`` (seconds from the episode's start).

Memory: one frame file at a time (LeRobot caps them at ``data_files_size_in_mb``, 100 MB by
default), so the peak does not grow with the number of episodes.  An episode of one frame has no step
to segment: it is left out and named in :attr:`DatasetReader.notes`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.data.errors import DatasetError, DatasetSpecError

from .layout import DatasetLayout, pyarrow_modules
from .spec import DatasetSpec

_NUMERIC = ("float", "int", "uint", "bool")


@dataclass
class DatasetEpisode:
    """One episode of a dataset: its ``index`` (``episode_index``), the :class:`Episode`, the frames'
    ``timestamps`` (s) and ``frame_index``, and where its frames lie (``file``, rows ``[start, stop)``)."""

    index: int
    episode: Episode
    timestamps: np.ndarray
    frame_index: np.ndarray
    file: Path
    start: int
    stop: int

    @property
    def frames(self) -> int:
        return self.stop - self.start

    def stamps_ns(self) -> np.ndarray:
        return np.rint(self.timestamps * 1e9).astype(np.int64)


@dataclass
class DatasetFile:
    """The episodes of one frame file, and the file's whole table when it was read for writing."""

    path: Path
    episodes: list[DatasetEpisode]
    table: Any = None


class DatasetReader:
    """Episodes of the dataset at ``root`` under ``spec`` (:meth:`files`, :meth:`episodes`); ``select``
    (an ``episode_index`` -> keep) leaves the other episodes out, e.g. those of other shards."""

    def __init__(self, root: str | Path, spec: DatasetSpec | None = None,
                 select: Callable[[int], bool] | None = None) -> None:
        self.layout = DatasetLayout.open(root)
        self.spec = spec or DatasetSpec()
        self.select = select
        self._check_spec()
        self.discrete = self._action_is_discrete()
        self.tasks = self.layout.task_names()
        named = set(self.spec.features)
        left = [k for k in self.layout.media_features if k not in named]
        self.notes: list[str] = [f"video/image features not read: {', '.join(left)} (the model reads the "
                                 "vectors the dataset spec names)"] if left else []

    def _check_spec(self) -> None:
        features = self.layout.features
        for name in self.spec.features:
            feature = features.get(name)
            if feature is None:
                vectors = [k for k, v in features.items() if str(v.get("dtype", "")).startswith(_NUMERIC)]
                raise DatasetSpecError(f"dataset spec names '{name}', which {self.layout.root} does not "
                                       f"have; its numeric features: {vectors}")
            dtype = str(feature.get("dtype", ""))
            if dtype in ("video", "image"):
                raise DatasetSpecError(f"dataset spec names '{name}', a {dtype} feature: name vector "
                                       "features (e.g. observation.state); video and image features are not "
                                       "read")
            if not dtype.startswith(_NUMERIC):
                raise DatasetSpecError(f"dataset spec names '{name}' of dtype {dtype}: only numeric features "
                                       "are read")

    def _action_is_discrete(self) -> bool:
        feature = self.layout.features[self.spec.action]
        shape = list(feature.get("shape") or [1])
        return not str(feature["dtype"]).startswith("float") and shape == [1]

    @property
    def columns(self) -> list[str]:
        """The columns a segmentation reads."""
        return [*dict.fromkeys([*self.spec.features, "timestamp", "frame_index", "episode_index",
                                "task_index"])]

    def files(self, *, whole: bool = False) -> Iterator[DatasetFile]:
        """Each frame file's episodes in order (``whole``: with the file's full table, for writing)."""
        for path in self.layout.data_files():
            yield self.read_file(path, whole=whole)

    def read_file(self, path: Path, *, whole: bool = False) -> DatasetFile:
        """The episodes of the frame file ``path`` (``whole``: with its full table, for writing)."""
        _, pq = pyarrow_modules()
        try:
            table = pq.read_table(path, columns=None if whole else self._present(pq, path))
        except (OSError, ValueError) as exc:  # pyarrow's ArrowInvalid is a ValueError
            raise DatasetError(f"{self.layout.relative(path)} cannot be read: {exc}",
                               path=self.layout.root) from exc
        return DatasetFile(path, self._episodes(path, table), table if whole else None)

    def _present(self, pq: Any, path: Path) -> list[str]:
        names = set(pq.read_schema(path).names)
        missing = [c for c in ("timestamp", "episode_index", *self.spec.features) if c not in names]
        if missing:
            raise DatasetError(f"{self.layout.relative(path)} has no column {missing[0]}",
                               path=self.layout.root)
        return [c for c in self.columns if c in names]

    def episodes(self) -> Iterator[DatasetEpisode]:
        """Every episode, file after file."""
        for file in self.files():
            yield from file.episodes

    def _episodes(self, path: Path, table: Any) -> list[DatasetEpisode]:
        where = self.layout.relative(path)
        n = table.num_rows
        index = _scalars(table, "episode_index", n, where).astype(np.int64)
        starts = np.concatenate([[0], np.flatnonzero(index[1:] != index[:-1]) + 1]).astype(np.int64)
        if len(np.unique(index[starts])) != len(starts):
            raise DatasetError(f"{where}: the frames of an episode are not contiguous (episode_index "
                               f"{_repeated(index[starts])} appears in two runs)", path=self.layout.root)
        stops = np.concatenate([starts[1:], [n]])
        columns = {name: _matrix(table, name, n, where) for name in self.spec.features}
        stamps = _scalars(table, "timestamp", n, where).astype(np.float64)
        names = table.column_names
        frames = _scalars(table, "frame_index", n, where).astype(np.int64) if "frame_index" in names else None
        tasks = _scalars(table, "task_index", n, where).astype(np.int64) if "task_index" in names else None
        found = []
        for start, stop in zip(starts.tolist(), stops.tolist(), strict=True):
            number = int(index[start])
            if self.select is not None and not self.select(number):
                continue
            if stop - start < 2:
                self.notes.append(f"episode {number} has {stop - start} frame: no step to segment, left out")
                continue
            ep = self._episode(columns, start, stop, number, where,
                               self.tasks.get(int(tasks[start]), "") if tasks is not None else "")
            frame = frames[start:stop] if frames is not None else np.arange(stop - start, dtype=np.int64)
            if np.any(np.diff(frame) <= 0):
                raise DatasetError(f"{where}: episode {number}'s frame_index does not increase",
                                   path=self.layout.root)
            found.append(DatasetEpisode(number, ep, stamps[start:stop], frame, path, start, stop))
        return found

    def _episode(self, columns: dict[str, np.ndarray], start: int, stop: int, number: int, where: Path,
                 task: str) -> Episode:
        parts = [columns[n][start:stop] for n in self.spec.observation]
        obs = np.concatenate(parts, axis=1).astype(np.float32)
        raw = columns[self.spec.action][start:stop - 1]
        actions = raw[:, 0].astype(np.int64) if self.discrete else raw.astype(np.float32)
        for name, values in ((self.spec.observation[0], obs), (self.spec.action, raw)):
            if not np.all(np.isfinite(values)):
                raise DatasetError(f"{where}: episode {number} has NaN or infinite values in {name}",
                                   path=self.layout.root)
        subtask: np.ndarray | None = None
        extras: dict[str, Any] = {}
        if self.spec.labels:
            values = columns[self.spec.labels][start:stop - 1, 0].astype(np.int64)
            if self.spec.label_kind == "id":
                subtask = np.concatenate([[0], np.cumsum(values[1:] != values[:-1])]).astype(np.int64)
                extras["subtask_id"] = values
            else:
                subtask = values.astype(np.int64)
        return Episode(observations=obs, actions=actions, subtask=subtask, task=task, seed=-1, extras=extras)


def _repeated(values: np.ndarray) -> int:
    seen, counts = np.unique(values, return_counts=True)
    return int(seen[counts > 1][0])


def _matrix(table: Any, name: str, n: int, where: Path) -> np.ndarray:
    """Column ``name`` as an ``[n, width]`` array (a vector feature, or a scalar as width 1)."""
    if name not in table.column_names:
        raise DatasetError(f"{where}: no column '{name}'")
    column = table.column(name).combine_chunks()
    if column.null_count:
        raise DatasetError(f"{where}: feature '{name}' has {column.null_count} empty value(s)")
    values = column
    while hasattr(values, "flatten") and hasattr(values.type, "value_type"):
        values = values.flatten()
    flat = np.asarray(values.to_numpy(zero_copy_only=False))
    if n == 0 or flat.size % n:
        raise DatasetError(f"{where}: feature '{name}' has vectors of different lengths")
    return flat.reshape(n, flat.size // n)


def _scalars(table: Any, name: str, n: int, where: Path) -> np.ndarray:
    return _matrix(table, name, n, where)[:, 0]


__all__ = ["DatasetEpisode", "DatasetFile", "DatasetReader"]
