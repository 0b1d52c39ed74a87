"""The identity of a cache entry: a BLAKE2b hash of everything its episodes are read from.

* :func:`content_key` (bags): the format version, the reader spec, ``on_error``, every storage and
  metadata file's bytes, and the bytes of the ``.msg`` files the spec's ``types:`` names (a folder of
  ``.msg`` files or an installed interface package, :func:`~ompn_ros.data.messages.types.source_files`),
  so a definition edited (a field renamed or retyped) misses as an edited bag does.
* :func:`dataset_key` (a LeRobot dataset): the format version, the dataset spec, ``meta/info.json``
  and every frame file's bytes.

Bytes, never sizes or modification times: an edited file always misses, whatever its size or mtime.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from pathlib import Path

from ..lerobot import DatasetReader
from ..lerobot.layout import INFO
from ..messages.types import source_files
from ..reader import ReaderSpec, storage_files
from .entry import CACHE_FORMAT

_CHUNK = 1 << 20


def _hash_files(h: hashlib.blake2b, files: Iterable[tuple[str, Path]]) -> None:
    """Feed each file's name, size and bytes to ``h``."""
    for name, file in files:
        h.update(f"\0{name}\0{file.stat().st_size}\0".encode())
        with open(file, "rb") as fh:
            while chunk := fh.read(_CHUNK):
                h.update(chunk)


def content_key(bags: Sequence[Path], spec: ReaderSpec, on_error: str) -> str:
    """BLAKE2b over format version, reader spec, every storage/metadata file's bytes and the ``.msg``
    files of the spec's ``types:``."""
    h = hashlib.blake2b(digest_size=20)
    h.update(json.dumps({"format": CACHE_FORMAT, "spec": spec.to_dict(), "on_error": on_error},
                        sort_keys=True).encode())
    for bag in bags:
        files = list(storage_files(bag))
        if bag.is_dir() and (bag / "metadata.yaml").is_file():
            files.append(bag / "metadata.yaml")
        _hash_files(h, ((file.name, file) for file in files))
    for source in spec.types:  # nothing for a spec without types: its key is the one it always had
        h.update(f"\0types\0{source}\0".encode())
        _hash_files(h, ((str(file.resolve()), file) for file in source_files(source)))
    return h.hexdigest()


def dataset_key(reader: DatasetReader) -> str:
    """BLAKE2b over the format version, the spec, ``meta/info.json`` and the frame files' bytes."""
    h = hashlib.blake2b(digest_size=20)
    doc = {"format": CACHE_FORMAT, "dataset_spec": reader.spec.to_dict()}
    h.update(json.dumps(doc, sort_keys=True).encode())
    files = [reader.layout.root / INFO, *reader.layout.data_files()]
    _hash_files(h, ((str(reader.layout.relative(file)), file) for file in files))
    return h.hexdigest()


__all__ = ["content_key", "dataset_key"]
