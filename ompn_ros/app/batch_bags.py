"""The bags of a batch run and where each one's outputs go.

A batch source is a folder of bags, a glob, or a *list file* (a text file naming one bag, folder or
glob per line; blank lines and ``#`` comments are skipped; relative entries are taken from the list
file's folder).  Every bag gets a *key*: its path relative to the folder all bags share, with the
path separators written ``__`` and the storage suffix dropped, unique within the run.  The key names
its record (``<out>/bags/<key>.json``) and its annotated copy (``<annotate>/<key>``).

Records are written atomically (a temporary sibling renamed into place), last of a bag's outputs: a
bag with a record of the same settings is complete, one without is redone.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ompn_ros.atomic import atomic_write_text, remove_stale_temps
from ompn_ros.data.errors import BagError
from ompn_ros.data.reader import STORAGE_SUFFIXES, list_bag_paths

RECORDS = "bags"
RECORD_FORMAT = "ompn_ros.batch_bag"


@dataclass(frozen=True)
class BatchBag:
    """One entry of a batch: ``path`` (None when the entry names no bag) and its ``key``;
    ``problem`` is the one-line reason an entry was refused before it was read."""

    key: str
    path: Path | None
    problem: str = ""


def _is_bag_file(path: Path) -> bool:
    return path.suffix in STORAGE_SUFFIXES or path.name == "metadata.yaml"


def _entries(source: str) -> tuple[list[str], Path | None]:
    """The entries of ``source``: the lines of a list file (and its folder), else ``source`` itself."""
    path = Path(source)
    if path.is_file() and not _is_bag_file(path):
        try:
            lines = path.read_text().splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise BagError(f"cannot read the list of bags: {exc}", path=path) from exc
        entries = [line.strip() for line in lines if line.strip() and not line.strip().startswith("#")]
        if not entries:
            raise BagError("the list of bags names no bag (one path, folder or glob per line)", path=path)
        return entries, path.parent
    return [source], None


def list_bags(source: str) -> list[BatchBag]:
    """The bags of ``source`` in order, each with its key; an entry of a list file that names no bag,
    and an entry below a listed folder that cannot be looked at, become a refused :class:`BatchBag`
    (the others still run).  Each real folder is listed once and each bag appears once
    (:func:`~ompn_ros.data.reader.list_bag_paths`).  A folder or glob that names no bag raises
    :class:`~ompn_ros.data.errors.BagError`."""
    entries, base = _entries(source)
    found: list[Path | str] = []
    problems: dict[Path | str, str] = {}
    for entry in entries:
        target = str(base / entry) if base is not None and not Path(entry).is_absolute() else entry
        try:
            listing = list_bag_paths(target)
        except BagError as exc:
            if base is None:
                raise
            found.append(entry)
            problems[entry] = str(exc)
            continue
        found.extend(listing.bags)
        for path, reason in listing.refused:
            found.append(path)
            problems[path] = f"{path}: {reason}"
    paths = _unique(found)
    keys = bag_keys([p for p in paths if isinstance(p, Path)])
    return [BatchBag(key=keys[p], path=None if p in problems else p, problem=problems.get(p, ""))
            if isinstance(p, Path) else BatchBag(key=_safe(p), path=None, problem=problems[p]) for p in paths]


def _unique(found: list[Path | str]) -> list[Path | str]:
    """Each bag once (by real path: two list entries may reach one bag), in first-seen order."""
    seen: dict[str, Path | str] = {}
    for item in found:
        seen.setdefault(os.path.realpath(item) if isinstance(item, Path) else f"\0{item}", item)
    return list(seen.values())


def _safe(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text).strip(".") or "bag"


def bag_keys(paths: list[Path]) -> dict[Path, str]:
    """A unique, file-name-safe key per bag: its path below the folder all share (see module doc)."""
    if not paths:
        return {}
    absolute = [Path(os.path.abspath(p)) for p in paths]  # links kept: a dangling one moves no key
    root = Path(os.path.commonpath([str(p.parent) for p in absolute]))
    keys: dict[Path, str] = {}
    used: set[str] = set()
    for path, full in zip(paths, absolute, strict=True):
        rel = full.relative_to(root)
        stem = rel.with_suffix("") if rel.suffix in STORAGE_SUFFIXES else rel
        key = base = _safe("__".join(stem.parts))
        number = 2
        while key in used:
            key, number = f"{base}-{number}", number + 1
        used.add(key)
        keys[path] = key
    return keys


def bag_stamp(path: Path) -> list[int]:
    """Size and newest modification time (ns) of the files of a bag (or any folder): a changed bag is
    redone.  Raises ``OSError`` when the bag is gone or cannot be looked at."""
    files = [f for f in sorted(path.rglob("*")) if f.is_file()] if path.is_dir() else [path]
    stats = [f.stat() for f in files]
    return [sum(s.st_size for s in stats), max((s.st_mtime_ns for s in stats), default=0)]


def record_path(out: Path, key: str) -> Path:
    return out / RECORDS / f"{key}.json"


def write_record(out: Path, key: str, doc: dict[str, Any]) -> Path:
    """Write ``doc`` as the record of ``key`` atomically (a killed writer leaves only a stale temporary).
    Not synced to disk: a record lost to a power failure is read as none, and its bag redone."""
    target = record_path(out, key)
    atomic_write_text(target, json.dumps({"format": RECORD_FORMAT, **doc}), durable=False)
    return target


def read_record(out: Path, key: str) -> dict[str, Any] | None:
    """The record of ``key``, or None when there is none or it is unreadable (the bag is then redone)."""
    try:
        doc = json.loads(record_path(out, key).read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("format") == RECORD_FORMAT else None


def clean_temporaries(out: Path) -> list[Path]:
    """Remove the temporary records a killed run left behind."""
    return remove_stale_temps(out / RECORDS)


__all__ = ["BatchBag", "bag_keys", "bag_stamp", "clean_temporaries", "list_bags", "read_record",
           "record_path", "write_record"]
