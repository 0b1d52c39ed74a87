"""One cache entry for all the bags: parsed one bag at a time, memory-mapped once built.

:func:`load_entry` reads the bags **one at a time** with
:func:`~ompn_ros.data.reader.read_episodes` and appends each bag's episodes to the entry on disk
before reading the next bag (:class:`~.entry.EntryWriter`), so building it holds one bag's parse in
memory, never the whole dataset: peak memory is the reader's peak on the largest bag plus
O(episodes) bookkeeping.  A hit needs the same key (:func:`~.key.content_key`); a stale entry found
under the key is deleted and rebuilt, and entries of other formats are deleted from the cache
directory when a new entry is built there.  :func:`in_memory` reads without a cache.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from ompn_ros.atomic import remove_stale_temps

from ..errors import CacheEntryError, CacheFormatError, EmptyEntryError, MixedBagsError, NpyAppendError
from ..reader import OnError, ReaderSpec, ReadReport, read_episodes
from .arrays import EpisodeArrays
from .entry import CACHE_FORMAT, INDEX, EntryWriter
from .key import content_key


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


def load_entry(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError, root: Path) -> EpisodeArrays:
    """The episodes of ``bags`` from their entry under ``root``, built when missing or stale (then with
    the bags parsed one at a time); the step arrays are memory-mapped either way."""
    key = content_key(bags, spec, on_error)
    remove_stale_temps(root)
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
        writer.finish(report.summary(), report.facts())
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


def in_memory(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError) -> EpisodeArrays:
    """The episodes of ``bags`` read into memory, no file written (memory grows with the dataset)."""
    result = read_episodes(bags, spec=spec, on_error=on_error)
    if not result.episodes:
        raise EmptyEntryError(f"no episodes could be read from {[str(b) for b in bags]}:\n"
                              f"{result.report.summary()}")
    arrays = EpisodeArrays.from_episodes(result.episodes)
    arrays.report, arrays.facts = result.report.summary(), result.report.facts()
    return arrays


__all__ = ["build_entry", "default_cache_dir", "in_memory", "load_entry", "open_hit", "with_notes"]
