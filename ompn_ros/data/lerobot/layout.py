"""Where a LeRobot v3.0 dataset keeps what: ``meta/info.json``, the frame files, the episode table.

A dataset is a local folder (the Hub is never asked)::

    meta/info.json                           codebase_version "v3.x", fps, features {name: dtype, shape}
    meta/tasks.parquet                       task strings (the pandas index) and task_index
    meta/episodes/chunk-NNN/file-NNN.parquet one row per episode: episode_index, length, data/chunk_index,
                                             data/file_index, dataset_from_index, dataset_to_index, stats/...
    data/chunk-NNN/file-NNN.parquet          one row per frame: the features, timestamp (s, float32),
                                             frame_index, episode_index, index, task_index
    videos/<key>/chunk-NNN/file-NNN.mp4      video features (never read here)

Every episode lies whole in one data file, its frames in order.  ``pyarrow`` reads the parquet files;
it is needed for datasets only, and its absence is one line saying how to install it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

from ompn_ros.data.errors import DatasetError

INFO = Path("meta/info.json")
TASKS = Path("meta/tasks.parquet")
EPISODES = Path("meta/episodes")
DATA = Path("data")
FRAME_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
"""The columns LeRobot writes on every frame besides the features of the dataset."""


def pyarrow_modules() -> tuple[ModuleType, ModuleType]:
    """``pyarrow`` and ``pyarrow.parquet``; a :class:`DatasetError` saying how to install them."""
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError as exc:
        raise DatasetError(f"reading a LeRobot dataset needs pyarrow ({exc}): pip install pyarrow") from exc
    return pyarrow, pyarrow.parquet


@dataclass(frozen=True)
class DatasetLayout:
    """The files of the dataset at ``root`` and its ``meta/info.json``."""

    root: Path
    info: dict[str, Any] = field(repr=False)

    @classmethod
    def open(cls, root: str | Path) -> DatasetLayout:
        """The dataset at ``root``; a :class:`DatasetError` when it is not a LeRobot v3 dataset."""
        path = Path(root)
        if not path.is_dir():
            raise DatasetError("no such folder (give the local folder of a LeRobot dataset)", path=path)
        try:
            info = json.loads((path / INFO).read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise DatasetError(f"no {INFO}: not a LeRobot dataset folder", path=path) from exc
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise DatasetError(f"{INFO} cannot be read: {exc}", path=path) from exc
        version = str(info.get("codebase_version", "")) if isinstance(info, dict) else ""
        if not version.startswith("v3."):
            raise DatasetError(f"{INFO} says codebase_version {version or 'nothing'}: only LeRobot v3 "
                               "datasets are read (convert older ones with LeRobot's v2.1 -> v3.0 converter)",
                               path=path)
        if not isinstance(info.get("features"), dict):
            raise DatasetError(f"{INFO} has no 'features' mapping", path=path)
        return cls(path, info)

    @property
    def features(self) -> dict[str, dict[str, Any]]:
        return dict(self.info["features"])

    @property
    def fps(self) -> float:
        return float(self.info.get("fps") or 0.0)

    @property
    def media_features(self) -> list[str]:
        """The video and image features (left out unless named, and then refused)."""
        return [k for k, v in self.features.items()
                if isinstance(v, dict) and v.get("dtype") in ("video", "image")]

    def data_files(self) -> list[Path]:
        """The frame files in chunk and file order."""
        files = sorted((self.root / DATA).glob("chunk-*/file-*.parquet"))
        if not files:
            raise DatasetError(f"no frame files ({DATA}/chunk-*/file-*.parquet)", path=self.root)
        return files

    def episode_files(self) -> list[Path]:
        """The episode table's files in chunk and file order."""
        return sorted((self.root / EPISODES).glob("chunk-*/file-*.parquet"))

    def task_names(self) -> dict[int, str]:
        """``task_index`` -> task string (empty when ``meta/tasks.parquet`` is missing)."""
        path = self.root / TASKS
        if not path.is_file():
            return {}
        _, pq = pyarrow_modules()
        table = pq.read_table(path)
        names = [n for n in table.column_names if n != "task_index"]
        if "task_index" not in table.column_names or not names:
            return {}
        text = table.column("task" if "task" in names else names[0]).to_pylist()
        return {int(i): str(t) for i, t in zip(table.column("task_index").to_pylist(), text, strict=True)}

    def relative(self, path: Path) -> Path:
        return path.relative_to(self.root)


__all__ = ["DATA", "EPISODES", "FRAME_COLUMNS", "INFO", "TASKS", "DatasetLayout", "pyarrow_modules"]
