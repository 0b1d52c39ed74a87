"""The cache's one way in for bags: :func:`load_arrays` (one entry, per-bag entries, or no cache)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..reader import OnError, ReaderSpec, resolve_bag_paths
from .arrays import EpisodeArrays
from .build import default_cache_dir, in_memory, load_entry
from .per_bag import load_per_bag


def load_arrays(
    paths: str | Path | Sequence[str | Path],
    *,
    spec: ReaderSpec | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
    on_error: OnError = "raise",
    workers: int = 0,
) -> EpisodeArrays:
    """Episodes of ``paths`` as :class:`EpisodeArrays`, from the on-disk cache when possible.

    A hit needs the same bag bytes, reader spec (with the ``.msg`` files of its ``types:``) and
    ``on_error``; otherwise the bags are parsed one at a time into a new entry.  ``workers``: 0 keeps
    one entry for all the bags (:mod:`.build`); N >= 1 keeps one entry per bag, the missing ones
    built over N processes and reused when bags are added (:mod:`.per_bag`).  Either way the result's
    step arrays are memory-mapped from an entry.  ``use_cache=False`` reads everything into memory
    instead (no file written; memory grows with the dataset).
    """
    if workers < 0:
        raise ValueError(f"workers must be 0 (one entry) or more (per-bag entries), got {workers}")
    spec = spec or ReaderSpec()
    bags = resolve_bag_paths(paths)
    if not use_cache:
        return in_memory(bags, spec, on_error)
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    if workers:
        return load_per_bag(bags, spec, on_error, root, workers)
    return load_entry(bags, spec, on_error, root)


__all__ = ["load_arrays"]
