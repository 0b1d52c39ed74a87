"""Fast path for training: bags -> contiguous numpy arrays, cached on disk and memory-mapped.

:func:`load_arrays` reads the bags **one at a time** with
:func:`~ompn_ros.data.reader.read_episodes` and appends each bag's episodes to the cache entry
on disk before reading the next bag (:class:`~ompn_ros.data.cache_store.EntryWriter`), so building
the cache holds one bag's parse in memory, never the whole dataset: peak memory is the reader's
peak on the largest bag plus O(episodes) bookkeeping.  An entry is a directory of uncompressed
``.npy`` files (observations, actions, subtasks, sketches, per-episode offsets and metadata) and
``index.json``, under ``cache_dir`` (default ``$OMPN_CACHE_DIR`` or ``~/.cache/ompn_ros``).  It is
opened with ``np.load(mmap_mode='r')``: the :class:`Episode` objects handed to training are
read-only views into the mapped files, so training reads from disk (the page cache) and a dataset
larger than the process's memory can be trained on.

The cache key is a BLAKE2b hash of the bag files' **bytes** (plus their relative names, the reader
spec and the format version), so editing or re-recording a bag always misses, whatever its size or
mtime.  Entries of another format version (``CACHE_FORMAT``) are never hit: a stale entry found
under the key is deleted and rebuilt, and entries of other formats (directories whose
``index.json`` names another version) are deleted from ``cache_dir`` when a new entry is built
there.  Nothing is pickled.

Every entry carries its key and a checksum of each file, verified when it is opened
(:mod:`ompn_ros.data.cache_store`), and its offsets are checked against its arrays: a damaged,
edited or misplaced entry is rebuilt from the bags, with a note in the read report (``notes``), and
temporaries of killed runs are removed when a run starts (their process is gone).
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.data.errors import (
    CacheEntryError,
    CacheFormatError,
    EmptyEntryError,
    MixedBagsError,
    NpyAppendError,
)

from .cache_store import (
    CACHE_FORMAT,
    INDEX,
    JOINT_KEYS,
    STEP_KEYS,
    EntryWriter,
    common_obs_names,
    open_entry,
    remove_stale_entries,
    write_entry,
)
from .episode import Episode
from .reader import OnError, ReaderSpec, ReadReport, read_episodes, resolve_bag_paths, storage_files

_CHUNK = 1 << 20


def _load_libc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "malloc_trim") else None  # glibc only
    except OSError:
        return None


_LIBC = _load_libc()


def default_cache_dir() -> Path:
    """``$OMPN_CACHE_DIR`` if set, else ``~/.cache/ompn_ros``."""
    env = os.environ.get("OMPN_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "ompn_ros"


@dataclass
class EpisodeArrays:
    """All episodes of a dataset in contiguous arrays.

    Episode ``i`` has observations ``observations[obs_offsets[i]:obs_offsets[i+1]]`` (``T_i + 1``
    rows) and actions/subtask ``[act_offsets[i]:act_offsets[i+1]]`` (``T_i`` rows).  ``subtask`` is
    ``-1`` where an episode has no labels (``has_subtask[i]`` False); sketches are concatenated
    with ``sketch_offsets`` (``has_sketch[i]`` False = no sketch).  ``step_extras`` holds per-step
    arrays aligned with the actions (``subtask_id``), ``extras`` joint arrays aligned with the
    observations, each when every episode has them.  ``obs_names`` names the observation's elements
    (``Episode.extras['obs_names']``, e.g. from ``ReaderSpec.assemble``) when every episode has the
    same names, else it is empty.
    """

    observations: np.ndarray
    obs_offsets: np.ndarray
    actions: np.ndarray
    act_offsets: np.ndarray
    subtask: np.ndarray
    has_subtask: np.ndarray
    sketch: np.ndarray
    sketch_offsets: np.ndarray
    has_sketch: np.ndarray
    tasks: np.ndarray
    seeds: np.ndarray
    success: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    step_extras: dict[str, np.ndarray] = field(default_factory=dict)
    obs_names: tuple[str, ...] = ()
    report: str = ""  # ReadReport.summary() of the parse that built the arrays
    key: str = ""
    cache_hit: bool = False
    cache_path: Path | None = None
    notes: list[str] = field(default_factory=list)  # entries found broken and rebuilt on the way

    def __len__(self) -> int:
        return len(self.obs_offsets) - 1

    def episode(self, i: int) -> Episode:
        """Episode ``i`` as an :class:`Episode` (arrays are views into this dataset)."""
        o0, o1 = self.obs_offsets[i], self.obs_offsets[i + 1]
        a0, a1 = self.act_offsets[i], self.act_offsets[i + 1]
        s0, s1 = self.sketch_offsets[i], self.sketch_offsets[i + 1]
        extras: dict[str, Any] = {k: v[o0:o1] for k, v in self.extras.items()}
        extras.update({k: v[a0:a1] for k, v in self.step_extras.items()})
        if self.obs_names:
            extras["obs_names"] = list(self.obs_names)
        return Episode(
            observations=self.observations[o0:o1],
            actions=self.actions[a0:a1],
            subtask=self.subtask[a0:a1] if self.has_subtask[i] else None,
            sketch=self.sketch[s0:s1] if self.has_sketch[i] else None,
            task=str(self.tasks[i]),
            seed=int(self.seeds[i]),
            success=bool(self.success[i]),
            extras=extras,
        )

    def episodes(self) -> list[Episode]:
        return [self.episode(i) for i in range(len(self))]

    @classmethod
    def from_episodes(cls, episodes: Sequence[Episode]) -> EpisodeArrays:
        """Concatenate ``episodes`` (all with the same observation size and action kind)."""
        if not episodes:
            raise ValueError("no episodes to concatenate")
        lengths = np.asarray([e.length for e in episodes], dtype=np.int64)
        act_offsets = np.concatenate([[0], np.cumsum(lengths)])
        obs_offsets = act_offsets + np.arange(len(episodes) + 1)
        sk = [np.zeros(0, np.int64) if e.sketch is None else np.asarray(e.sketch, np.int64) for e in episodes]
        sketch_offsets = np.concatenate([[0], np.cumsum([len(s) for s in sk])]).astype(np.int64)
        extras: dict[str, np.ndarray] = {}
        for key in JOINT_KEYS:
            if all(key in e.extras and len(e.extras[key]) == len(e.observations) for e in episodes):
                extras[key] = np.concatenate([np.asarray(e.extras[key]) for e in episodes])
        step_extras = {key: np.concatenate([np.asarray(e.extras[key]) for e in episodes])
                       for key in STEP_KEYS
                       if all(key in e.extras and len(e.extras[key]) == e.length for e in episodes)}
        return cls(
            observations=np.concatenate([e.observations for e in episodes]).astype(np.float32, copy=False),
            obs_offsets=obs_offsets.astype(np.int64),
            actions=np.concatenate([np.asarray(e.actions) for e in episodes]),
            act_offsets=act_offsets.astype(np.int64),
            subtask=np.concatenate([np.full(e.length, -1, np.int64) if e.subtask is None
                                    else np.asarray(e.subtask, np.int64) for e in episodes]),
            has_subtask=np.asarray([e.subtask is not None for e in episodes]),
            sketch=np.concatenate(sk),
            sketch_offsets=sketch_offsets,
            has_sketch=np.asarray([e.sketch is not None for e in episodes]),
            tasks=np.asarray([e.task for e in episodes], dtype=str),
            seeds=np.asarray([e.seed for e in episodes], dtype=np.int64),
            success=np.asarray([e.success for e in episodes]),
            extras=extras,
            step_extras=step_extras,
            obs_names=common_obs_names(episodes),
        )

    def _arrays(self) -> dict[str, np.ndarray]:
        names = ("observations", "obs_offsets", "actions", "act_offsets", "subtask", "has_subtask",
                 "sketch", "sketch_offsets", "has_sketch", "tasks", "seeds", "success")
        out = {n: getattr(self, n) for n in names}
        out.update({f"extras__{k}": v for k, v in self.extras.items()})
        out.update({f"step_extras__{k}": v for k, v in self.step_extras.items()})
        out["obs_names"] = np.asarray(self.obs_names, dtype=str)
        return out

    def save(self, path: Path, key: str = "") -> None:
        """Write as a cache entry: a directory of ``.npy`` files and ``index.json``, atomically."""
        write_entry(path, self._arrays(), self.report, key)

    @classmethod
    def load(cls, path: Path, key: str | None = None) -> EpisodeArrays:
        """Open an entry written by :meth:`save` or :func:`load_arrays`, step arrays memory-mapped;
        ``key``: the identity it must have.

        Raises :class:`~ompn_ros.data.errors.CacheFormatError` (a ``ValueError``) for an entry
        of another format version, :class:`~ompn_ros.data.errors.CacheEntryError` for one whose
        key, checksums or offsets do not hold, and ``OSError`` when it is missing.
        """
        arrays, report = open_entry(path, key)
        extras = {k[len("extras__"):]: arrays.pop(k) for k in list(arrays) if k.startswith("extras__")}
        step = {k[len("step_extras__"):]: arrays.pop(k) for k in list(arrays)
                if k.startswith("step_extras__")}
        names = tuple(str(n) for n in arrays.pop("obs_names"))
        try:
            out = cls(**arrays, extras=extras, step_extras=step, obs_names=names, report=report,
                      cache_path=path)
        except TypeError as exc:  # an array missing from the index, or one it should not have
            raise CacheEntryError(f"cache entry {path}: {exc}") from None
        out.check_layout()
        return out

    def check_layout(self) -> None:
        """Raise :class:`~ompn_ros.data.errors.CacheEntryError` unless the offsets cut the arrays into
        whole episodes (monotone, from 0 to each array's end, ``T + 1`` observations for ``T``
        actions) and every per-episode array has one value per episode.  O(episodes)."""
        n = len(self.obs_offsets) - 1
        obs, act, sk = (np.asarray(a, np.int64) for a in (self.obs_offsets, self.act_offsets,
                                                            self.sketch_offsets))
        per_episode = (self.has_subtask, self.has_sketch, self.tasks, self.seeds, self.success)
        problems = [
            n < 0 or len(act) != n + 1 or len(sk) != n + 1,
            n >= 0 and (obs[0] != 0 or act[0] != 0 or sk[0] != 0),
            bool(np.any(np.diff(act) < 0)) or bool(np.any(np.diff(sk) < 0)),
            len(obs) == len(act) and bool(np.any(obs != act + np.arange(n + 1))),
            n >= 0 and (obs[-1] != len(self.observations) or act[-1] != len(self.actions)
                        or act[-1] != len(self.subtask) or sk[-1] != len(self.sketch)),
            any(len(a) != n for a in per_episode),
        ]
        if any(problems):
            raise CacheEntryError(f"cache entry {self.cache_path}: its offsets do not cut its arrays into "
                                  f"{n} whole episodes")


def content_key(bags: Sequence[Path], spec: ReaderSpec, on_error: str) -> str:
    """BLAKE2b over format version, reader spec and every storage/metadata file's bytes."""
    h = hashlib.blake2b(digest_size=20)
    h.update(json.dumps({"format": CACHE_FORMAT, "spec": spec.to_dict(), "on_error": on_error},
                        sort_keys=True).encode())
    for bag in bags:
        files = list(storage_files(bag))
        if bag.is_dir() and (bag / "metadata.yaml").is_file():
            files.append(bag / "metadata.yaml")
        for file in files:
            h.update(f"\0{file.name}\0{file.stat().st_size}\0".encode())
            with open(file, "rb") as fh:
                while chunk := fh.read(_CHUNK):
                    h.update(chunk)
    return h.hexdigest()


def load_arrays(
    paths: str | Path | Sequence[str | Path],
    *,
    spec: ReaderSpec | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
    on_error: OnError = "raise",
) -> EpisodeArrays:
    """Episodes of ``paths`` as :class:`EpisodeArrays`, from the on-disk cache when possible.

    A hit needs the same bag bytes, reader spec and ``on_error``; otherwise the bags are parsed
    one at a time into a new entry (if ``use_cache``).  Either way the result's step arrays are
    memory-mapped from the entry.  ``use_cache=False`` reads everything into memory instead (no
    file written; memory grows with the dataset).
    """
    spec = spec or ReaderSpec()
    bags = resolve_bag_paths(paths)
    if not use_cache:
        return _in_memory(bags, spec, on_error)
    key = content_key(bags, spec, on_error)
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    remove_stale_entries(root)
    entry = root / f"episodes_{key}"
    notes: list[str] = []
    hit = open_hit(entry, key, notes)
    if hit is None:
        _prune_other_formats(root)
        build_entry(bags, spec, on_error, entry, key)
        hit = EpisodeArrays.load(entry, key)
    else:
        hit.cache_hit = True
    hit.key = key
    return with_notes(hit, notes)


def with_notes(arrays: EpisodeArrays, notes: list[str]) -> EpisodeArrays:
    """``arrays`` with ``notes`` kept and appended to its read report (one line each)."""
    if notes:
        arrays.notes = list(notes)
        arrays.report = "\n".join([arrays.report, *notes]) if arrays.report else "\n".join(notes)
    return arrays


def open_hit(entry: Path, key: str | None = None, notes: list[str] | None = None) -> EpisodeArrays | None:
    """The entry if it is complete, of this format and (given ``key``) of this identity; a stale or
    broken one is deleted (a damaged one with a line in ``notes``: it will be rebuilt)."""
    if not entry.exists():
        return None
    try:
        return EpisodeArrays.load(entry, key)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:  # rebuilt by the caller
        other_format = isinstance(exc, CacheFormatError) and not isinstance(exc, CacheEntryError)
        if notes is not None and not other_format:  # an old format is expected after an upgrade
            notes.append(f"note: cache entry rebuilt from the bags: {exc}")
        shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
        return None


def _prune_other_formats(root: Path) -> None:
    """Delete entries of other formats (directories whose ``index.json`` names another version); their
    keys can never be hit again."""
    if not root.is_dir():
        return
    for entry in root.glob("episodes_*"):
        try:
            stale = entry.is_dir() and json.loads((entry / INDEX).read_text()).get("format") != CACHE_FORMAT
        except (OSError, ValueError, AttributeError):  # no readable index: not ours to judge
            stale = False
        if stale:
            shutil.rmtree(entry, ignore_errors=True)


def build_entry(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError, entry: Path,
                key: str = "") -> None:
    """Parse ``bags`` one at a time into the entry at ``entry`` (memory: one bag's parse); ``key``:
    its identity (:func:`content_key`)."""
    report = ReadReport()
    writer = EntryWriter(entry, key)
    joint_orders: dict[str, tuple[str, ...]] = {}  # one joint order for every bag (reader.joints)
    try:
        for bag in bags:
            result = read_episodes([bag], spec=spec, on_error=on_error, joint_orders=joint_orders)
            report.bags.extend(result.report.bags)
            try:
                writer.add(result.episodes)
            except NpyAppendError as err:
                raise MixedBagsError(f"bag {bag} does not fit the bags before it: {err}") from err
            del result  # release this bag's parse before reading the next one
            _release_freed_memory()
        if len(writer) == 0:
            names = [str(b) for b in bags]
            raise EmptyEntryError(f"no episodes could be read from {names}:\n{report.summary()}")
        writer.finish(report.summary())
    except BaseException:
        writer.abort()
        raise


def _release_freed_memory() -> None:
    """Hand the heap pages freed by a bag's parse back to the OS (glibc ``malloc_trim``).

    A bag's raw messages are many small blocks; glibc keeps them after they are freed, and the next
    bag's parse does not always fit into them, so without trimming the RSS of a many-bag build
    grows by up to a bag per bag.  No-op where the C library has no ``malloc_trim``.
    """
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _in_memory(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError) -> EpisodeArrays:
    result = read_episodes(bags, spec=spec, on_error=on_error)
    if not result.episodes:
        raise EmptyEntryError(f"no episodes could be read from {[str(b) for b in bags]}:\n"
                         f"{result.report.summary()}")
    arrays = EpisodeArrays.from_episodes(result.episodes)
    arrays.report = result.report.summary()
    return arrays


__all__ = ["EpisodeArrays", "build_entry",
           "content_key", "default_cache_dir", "load_arrays", "open_hit", "with_notes"]
