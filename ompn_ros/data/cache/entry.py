"""The episode cache's on-disk entry: a directory of uncompressed ``.npy`` files and ``index.json``.

An entry holds one ``.npy`` file per array (see :class:`~.arrays.EpisodeArrays`, with
``obs_names``: the observation's element names, ``Episode.extras['obs_names']``, empty when the
episodes do not name them alike) and ``index.json`` (format version, every array's file, dtype and
shape, the reader's report: its summary text for people and its facts as data,
:class:`~ompn_ros.data.reader.BagFacts`, for the code that uses them).  It is
opened with ``np.load(mmap_mode='r')``: the step arrays (observations, actions, labels, sketches,
joint extras) stay on disk and pages are read when touched, so a dataset larger than memory can be
trained on; the per-episode arrays (offsets, seeds, ...) are small and read into memory.

:class:`EntryWriter` builds an entry while bags are read: every episode's rows are appended to the
files at once, so memory holds one bag's episodes at a time, never the dataset.  Entries are
written into a temporary directory (``.<entry>.tmp-<pid>-<random>``, :mod:`ompn_ros.atomic`) and
renamed into place, so a reader never sees half an entry; the temporary of a killed writer is removed
by the next run that finds its process gone (:func:`ompn_ros.atomic.remove_stale_temps`).

An entry defends itself (since format 5): ``index.json`` holds the entry's **key** (the identity of its bags
and reader settings, :func:`~.key.content_key`) and a BLAKE2b checksum of every file.
:func:`open_entry` verifies both before anything is mapped, so garbage values, another bag's entry
copied under this key, a truncated or edited offsets file are a :class:`CacheEntryError` (the
caller rebuilds the entry with a note), never data trained on.  Verifying reads every byte once per
open (about 1 GB/s, in the page cache afterwards, where training reads it again).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ompn_ros.atomic import make_temp_dir, umask_mode

from ..episode import Episode
from ..errors import CacheEntryError, CacheFormatError
from ..reader import BagFacts
from .npy import NpyAppender

CACHE_FORMAT = 6  # 6: + the read's facts; 5: + key, checksums; 4: + obs_names; 3: .npy files (2: one .npz)
_CHUNK = 1 << 20
INDEX = "index.json"
JOINT_KEYS = ("joint_position", "joint_velocity", "joint_effort")  # [T + 1] extras
STEP_KEYS = ("subtask_id",)  # per-step extras [T] (labels: id)
STEP_ARRAYS = ("observations", "actions", "subtask", "sketch")  # memory-mapped (with the extras)


def _mapped(name: str) -> bool:
    return name in STEP_ARRAYS or name.startswith(("extras__", "step_extras__"))


def write_entry(path: Path, arrays: dict[str, np.ndarray], report: str, key: str = "",
                facts: Sequence[BagFacts] = ()) -> None:
    """Write ``arrays`` as an entry at ``path`` (replacing an old one), atomically; ``key``: its
    identity (checked by :func:`open_entry`); ``report`` and ``facts``: the read's summary and facts."""
    tmp = make_temp_dir(_parent(path), path.name)
    try:
        index = {name: _save(tmp, name, np.asarray(arr)) for name, arr in arrays.items()}
        _finish(tmp, path, index, report, key, facts)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _parent(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.parent


def _save(directory: Path, name: str, arr: np.ndarray) -> dict[str, Any]:
    if arr.dtype == object:
        raise CacheFormatError(f"array '{name}' holds Python objects; the cache stores plain arrays only")
    np.save(directory / f"{name}.npy", arr, allow_pickle=False)
    return {"file": f"{name}.npy", "dtype": arr.dtype.str, "shape": list(arr.shape)}


def file_digest(path: Path) -> str:
    """BLAKE2b (20 bytes, hex) of the file's bytes."""
    h = hashlib.blake2b(digest_size=20)
    with open(path, "rb") as handle:
        while chunk := handle.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _finish(tmp: Path, path: Path, index: dict[str, dict[str, Any]], report: str, key: str,
            facts: Sequence[BagFacts]) -> None:
    for info in index.values():
        info["blake2b"] = file_digest(tmp / info["file"])
    doc = {"format": CACHE_FORMAT, "key": key, "arrays": index, "report": report,
           "facts": [asdict(bag) for bag in facts]}
    (tmp / INDEX).write_text(json.dumps(doc, indent=1) + "\n")
    tmp.chmod(umask_mode(directory=True))  # the temporary was owner-only
    if path.exists():
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    try:
        tmp.rename(path)
    except OSError:
        if not (path / INDEX).is_file():
            raise
        shutil.rmtree(tmp, ignore_errors=True)  # another process published the entry meanwhile


def read_index(path: Path, key: str | None = None) -> dict[str, Any]:
    """The index of the entry at ``path`` when it is of this format and, given ``key``, of this
    identity; :class:`CacheFormatError` (another format) or :class:`CacheEntryError` otherwise."""
    try:
        index = json.loads((path / INDEX).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise CacheEntryError(f"cache entry {path}: {INDEX} is not readable JSON ({exc})") from None
    if not isinstance(index, dict) or index.get("format") != CACHE_FORMAT:
        found = index.get("format") if isinstance(index, dict) else None
        raise CacheFormatError(f"cache entry {path} has format {found}, expected {CACHE_FORMAT}")
    if key is not None and index.get("key") != key:
        raise CacheEntryError(f"cache entry {path} holds the entry of other bags or settings (key "
                              f"{index.get('key')!r}, expected {key!r})")
    if not isinstance(index.get("arrays"), dict):
        raise CacheEntryError(f"cache entry {path}: {INDEX} lists no arrays")
    return index


def open_entry(path: Path, key: str | None = None) -> tuple[dict[str, Any], str, tuple[BagFacts, ...]]:
    """The arrays of the entry at ``path`` (step arrays memory-mapped read-only), its report's summary
    and facts, once its key (when ``key`` is given) and every file's checksum are verified.

    Raises :class:`CacheFormatError` for another format version, :class:`CacheEntryError` (a
    ``CacheFormatError``) for another identity, a file that does not match its checksum or the
    index, ``OSError`` when a file is missing.
    """
    index = read_index(path, key)
    arrays: dict[str, Any] = {}
    for name, info in index["arrays"].items():
        if not isinstance(info, dict) or file_digest(path / str(info.get("file"))) != info.get("blake2b"):
            raise CacheEntryError(f"cache entry {path}: {name}.npy does not match its checksum (changed "
                                  "or damaged since it was written)")
        mode: Literal["r"] | None = "r" if _mapped(name) and int(np.prod(info["shape"])) > 0 else None
        arr = np.load(path / info["file"], mmap_mode=mode, allow_pickle=False)
        if list(arr.shape) != info["shape"] or arr.dtype.str != info["dtype"]:
            raise CacheFormatError(f"{path / info['file']}: {arr.dtype.str}{list(arr.shape)} does not match "
                                   f"the index ({info['dtype']}{info['shape']})")
        arrays[name] = arr
    return arrays, str(index.get("report", "")), _facts(path, index.get("facts"))


def _facts(path: Path, doc: Any) -> tuple[BagFacts, ...]:
    """The read's facts as the index keeps them; :class:`CacheEntryError` when they do not hold."""
    if not isinstance(doc, list):
        raise CacheEntryError(f"cache entry {path}: {INDEX} holds no list of the read's facts")
    try:
        return tuple(BagFacts.from_dict(bag) for bag in doc)
    except ValueError as exc:
        raise CacheEntryError(f"cache entry {path}: {exc}") from None


class EntryWriter:
    """Build an entry from batches of episodes (one bag at a time); :meth:`finish` publishes it.

    Memory: the episodes handed to :meth:`add` plus O(episodes) per-episode values.  A joint or
    per-step extra is kept only when every episode has it (as in ``EpisodeArrays.from_episodes``).
    """

    def __init__(self, path: Path, key: str = "") -> None:
        self.path, self.key = path, key
        self.tmp = make_temp_dir(_parent(path), path.name)
        self._cols: dict[str, NpyAppender] = {
            "observations": NpyAppender(self.tmp / "observations.npy", np.float32),
            "actions": NpyAppender(self.tmp / "actions.npy"),
            "subtask": NpyAppender(self.tmp / "subtask.npy", np.int64, ()),
            "sketch": NpyAppender(self.tmp / "sketch.npy", np.int64, ()),
        }
        self._extras: dict[str, NpyAppender] | None = None  # decided by the first episode
        self._names: tuple[str, ...] | None = None  # obs_names shared by every episode so far
        self._per: dict[str, list[Any]] = {k: [] for k in ("length", "sketch_len", "has_subtask",
                                                          "has_sketch", "tasks", "seeds", "success")}

    def __len__(self) -> int:
        return len(self._per["length"])

    def add(self, episodes: Iterable[Episode]) -> None:
        """Append ``episodes`` to the files (raises :class:`NpyAppendError` on a shape/dtype clash)."""
        for ep in episodes:
            self._cols["observations"].append(ep.observations)
            self._cols["actions"].append(np.asarray(ep.actions))
            labels = np.full(ep.length, -1, np.int64) if ep.subtask is None else np.asarray(ep.subtask)
            self._cols["subtask"].append(labels)
            if ep.sketch is not None:
                self._cols["sketch"].append(np.asarray(ep.sketch, np.int64))
            self._add_extras(ep)
            names = episode_obs_names(ep)
            self._names = names if self._names is None or self._names == names else ()
            per = self._per
            per["length"].append(ep.length)
            per["sketch_len"].append(0 if ep.sketch is None else len(ep.sketch))
            per["has_subtask"].append(ep.subtask is not None)
            per["has_sketch"].append(ep.sketch is not None)
            per["tasks"].append(ep.task)
            per["seeds"].append(ep.seed)
            per["success"].append(ep.success)

    def _add_extras(self, ep: Episode) -> None:
        wanted = {**{f"extras__{k}": len(ep.observations) for k in JOINT_KEYS},
                  **{f"step_extras__{k}": ep.length for k in STEP_KEYS}}
        if self._extras is None:
            self._extras = {name: NpyAppender(self.tmp / f"{name}.npy") for name, rows in wanted.items()
                            if _extra(ep, name) is not None and len(_extra(ep, name)) == rows}
        for name in list(self._extras):
            value = _extra(ep, name)
            if value is None or len(value) != wanted[name]:
                self._extras.pop(name).abort()  # not every episode has it: dropped, as from_episodes
            else:
                self._extras[name].append(np.asarray(value))

    def finish(self, report: str, facts: Sequence[BagFacts] = ()) -> None:
        """Close the files, write the per-episode arrays and the index (with the read's ``report`` and
        ``facts``), and rename into place."""
        per = self._per
        act_offsets = np.concatenate([[0], np.cumsum(np.asarray(per["length"], np.int64))]).astype(np.int64)
        small = {
            "obs_offsets": act_offsets + np.arange(len(self) + 1, dtype=np.int64),
            "act_offsets": act_offsets,
            "sketch_offsets": np.concatenate([[0], np.cumsum(per["sketch_len"])]).astype(np.int64),
            "has_subtask": np.asarray(per["has_subtask"], bool),
            "has_sketch": np.asarray(per["has_sketch"], bool),
            "tasks": np.asarray(per["tasks"], dtype=str),
            "seeds": np.asarray(per["seeds"], np.int64),
            "success": np.asarray(per["success"], bool),
            "obs_names": np.asarray(self._names or (), dtype=str),
        }
        try:
            index = {}
            for name, col in {**self._cols, **(self._extras or {})}.items():
                shape = col.close()
                index[name] = {"file": col.path.name, "dtype": np.dtype(col.dtype).str, "shape": list(shape)}
            index.update({name: _save(self.tmp, name, arr) for name, arr in small.items()})
            _finish(self.tmp, self.path, index, report, self.key, facts)
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Drop the unfinished entry."""
        for col in [*self._cols.values(), *(self._extras or {}).values()]:
            col.abort()
        shutil.rmtree(self.tmp, ignore_errors=True)


def episode_obs_names(ep: Episode) -> tuple[str, ...]:
    """``ep.extras['obs_names']`` as a tuple (empty when the episode does not name its elements)."""
    return tuple(str(n) for n in ep.extras.get("obs_names", ()))


def common_obs_names(episodes: Iterable[Episode]) -> tuple[str, ...]:
    """The observation names every episode has alike, else ``()``."""
    names: tuple[str, ...] | None = None
    for ep in episodes:
        own = episode_obs_names(ep)
        names = own if names is None or names == own else ()
    return names or ()


def _extra(ep: Episode, name: str) -> Any:
    return ep.extras.get(name.split("__", 1)[1])


__all__ = ["CACHE_FORMAT", "EntryWriter", "common_obs_names", "file_digest",
           "open_entry", "read_index", "write_entry"]
