"""The episode cache for a LeRobot dataset (``ompn_train --dataset DIR``).

:func:`load_dataset_arrays` reads the dataset one frame file at a time
(:class:`~ompn_ros.data.lerobot.DatasetReader`) into one cache entry (:class:`~.entry.EntryWriter`, as
bags are), so building it holds one frame file in memory; training then reads the entry
memory-mapped.  The key is :func:`~.key.dataset_key`: a changed dataset always misses.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import EmptyEntryError
from ..lerobot import DatasetReader, DatasetSpec
from ..reader import BagFacts
from .arrays import EpisodeArrays
from .build import default_cache_dir, open_hit
from .entry import EntryWriter
from .key import dataset_key


def _summary(reader: DatasetReader, episodes: int, frames: int) -> str:
    lines = [f"LeRobot dataset {reader.layout.root}: {episodes} episodes, {frames} frames read "
             f"(observation {list(reader.spec.observation)}, action {reader.spec.action}, "
             f"labels {reader.spec.labels or 'none'})"]
    return "\n".join([*lines, *reader.notes])


def build_dataset_entry(reader: DatasetReader, entry: Path) -> None:
    """Read the dataset file by file into the entry at ``entry``."""
    writer = EntryWriter(entry)
    frames = steps = 0
    try:
        for file in reader.files():
            writer.add(e.episode for e in file.episodes)
            frames += sum(e.frames for e in file.episodes)
            steps += sum(e.episode.length for e in file.episodes)
        if len(writer) == 0:
            raise EmptyEntryError(f"no episode of two frames or more in {reader.layout.root}")
        facts = BagFacts(str(reader.layout.root), len(writer), steps)  # no row T guessed, no idle rule
        writer.finish(_summary(reader, len(writer), frames), [facts])
    except BaseException:
        writer.abort()
        raise


def load_dataset_arrays(root: str | Path, spec: DatasetSpec | None = None, *,
                        cache_dir: str | Path | None = None) -> EpisodeArrays:
    """The episodes of the dataset at ``root`` as memory-mapped :class:`EpisodeArrays` (cached)."""
    reader = DatasetReader(root, spec)
    key = dataset_key(reader)
    entry = (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / f"episodes_lerobot_{key}"
    hit = open_hit(entry)
    if hit is None:
        build_dataset_entry(reader, entry)
        hit = EpisodeArrays.load(entry)
    else:
        hit.cache_hit = True
    hit.key = key
    return hit


__all__ = ["build_dataset_entry", "load_dataset_arrays"]
