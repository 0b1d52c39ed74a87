"""The episode cache for many bags: one entry per bag, built in parallel, reused when bags are added.

:func:`load_per_bag` keeps an entry per bag under ``<cache_dir>/bags/`` (the key of
:func:`~.key.content_key` over that bag alone: its bytes, the reader spec, ``on_error``, the
``types:`` definitions), builds the missing ones over ``workers`` processes (one bag per task, each
parsed as :func:`~.build.load_entry` parses one, so a process holds one bag's parse at a time:
about 1.5x the largest bag, times ``workers`` in all), then appends the per-bag entries, in bag
order and memory-mapped, into one dataset entry ``episodes_set_<key>`` (``key``: a hash of the
per-bag keys).  Adding bags to a dataset parses only the new ones; the assembly copies the arrays
once more (disk: the per-bag entries plus the dataset entry).

``ompn_train`` uses it with ``data.cache_workers: N`` (N >= 1; 0 is the single-entry cache).  The
workers end with the process that started them, however it ends (:mod:`ompn_ros.workers`).
"""

from __future__ import annotations

import hashlib
import multiprocessing
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from ompn_ros.atomic import remove_stale_temps
from ompn_ros.workers import die_with_parent, started_here

from ..errors import EmptyEntryError, MixedBagsError, NpyAppendError
from ..reader import BagFacts, OnError, ReaderSpec
from .arrays import EpisodeArrays
from .build import build_entry, open_hit, with_notes
from .entry import EntryWriter
from .key import content_key

BAGS_DIR = "bags"
MAX_REPORT_LINES = 40


def _build_one(bag: Path, spec: ReaderSpec, on_error: OnError, entry: Path, key: str) -> bool:
    """Build the entry of ``bag`` unless it exists; False when the bag has no episode to keep
    (``on_error='skip_tail'``: such a bag gets no entry and is read again next time)."""
    if open_hit(entry, key) is not None:  # another run may have built it meanwhile
        return True
    try:
        build_entry([bag], spec, on_error, entry, key)
    except EmptyEntryError:
        return False
    return True


def build_bag_entries(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError, root: Path,
                      workers: int = 1, notes: list[str] | None = None) -> tuple[list[Path], int]:
    """The entries of the bags that have episodes (built where missing, over ``workers`` processes) and
    how many bags were parsed; a broken entry is rebuilt with a line in ``notes``."""
    if workers < 1:
        raise ValueError(f"data.cache_workers must be at least 1 for per-bag entries, got {workers}")
    remove_stale_temps(root / BAGS_DIR)
    keys = [content_key([bag], spec, on_error) for bag in bags]
    entries = [root / BAGS_DIR / f"bag_{key}" for key in keys]
    missing = [(bag, entry, key) for bag, entry, key in zip(bags, entries, keys, strict=True)
               if open_hit(entry, key, notes) is None]
    empty: set[Path] = set()
    if workers == 1 or len(missing) <= 1:
        empty = {entry for bag, entry, key in missing if not _build_one(bag, spec, on_error, entry, key)}
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(missing)), mp_context=context,
                                 initializer=die_with_parent, initargs=started_here()) as pool:
            futures = {entry: pool.submit(_build_one, bag, spec, on_error, entry, key)
                       for bag, entry, key in missing}
            for entry, future in futures.items():  # the first bag that fails stops the build, named
                if not future.result():
                    empty.add(entry)
    kept = [entry for entry in entries if entry not in empty]
    if not kept:
        raise EmptyEntryError(f"no episodes could be read from {[str(b) for b in bags]}")
    return kept, len(missing)


def merged_report(reports: Sequence[str], episodes: int, bags: int) -> str:
    """One summary of the per-bag reports: a total line, then each distinct line once (bounded)."""
    lines = [f"read {bags} bag(s) through per-bag cache entries: {episodes} episode(s)"]
    seen = set(lines)
    for report in reports:
        for line in report.splitlines()[1:]:
            if line not in seen and len(lines) < MAX_REPORT_LINES:
                seen.add(line)
                lines.append(line)
    return "\n".join(lines)


def assemble(entries: Sequence[Path], target: Path, key: str = "") -> None:
    """Append the episodes of ``entries`` (memory-mapped, one entry at a time) into one entry ``target``
    of identity ``key``."""
    writer = EntryWriter(target, key)
    reports: list[str] = []
    facts: list[BagFacts] = []
    try:
        for entry in entries:
            part = EpisodeArrays.load(entry)
            reports.append(part.report)
            facts.extend(part.facts)
            try:
                writer.add(part.episodes())
            except NpyAppendError as err:
                raise MixedBagsError(f"cache entry {entry} does not fit the bags before it: {err}") from err
            del part
        writer.finish(merged_report(reports, len(writer), len(entries)), facts)
    except BaseException:
        writer.abort()
        raise


def load_per_bag(bags: Sequence[Path], spec: ReaderSpec, on_error: OnError, root: Path,
                 workers: int = 1) -> EpisodeArrays:
    """The episodes of ``bags`` through per-bag entries under ``root`` (see the module doc); ``built``
    bags are counted in the result's ``report`` header."""
    remove_stale_temps(root)
    notes: list[str] = []
    entries, built = build_bag_entries(bags, spec, on_error, root, workers, notes)
    key = hashlib.blake2b("\n".join(e.name for e in entries).encode(), digest_size=20).hexdigest()
    target = root / f"episodes_set_{key}"
    hit = open_hit(target, key, notes)
    if hit is None:
        assemble(entries, target, key)
        hit = EpisodeArrays.load(target, key)
    hit.cache_hit = built == 0
    hit.key = key
    return with_notes(hit, notes)


__all__ = ["assemble", "build_bag_entries", "load_per_bag", "merged_report"]
