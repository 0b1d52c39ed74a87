"""Split bags without their metadata.yaml: read as one bag, as ``ros2 bag reindex`` would restore it.

rosbag2 names the storage files of bag directory ``<dir>`` ``<dir>_0.<ext>``, ``<dir>_1.<ext>``, ...
(the splits) and writes ``metadata.yaml`` only when recording ends, so a recorder that crashed (or was
killed) leaves the files without it.  Read one by one, every file boundary would cut an episode in
two.  :func:`reindexed_view` gives such a directory a metadata.yaml in a temporary directory (the
storage files linked, not copied; the user's directory is not written), listing the files in split
order, with the connections and message counts of each file.  Message compression needs no entry:
the reader recognises zstd frames (:mod:`.compressed`).

Cost: opening each storage file once more (its summary or topics table; a file without summary,
e.g. the truncated last split, is scanned record by record); no message is decoded.
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from glob import escape as glob_escape
from pathlib import Path
from typing import Any

import yaml
from mcap.records import Channel, Schema
from mcap.stream_reader import StreamReader
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import dump_qos_v9

from ..errors import CorruptBagError

STORAGE_IDS = {".mcap": "mcap", ".db3": "sqlite3"}


def split_files(folder: Path) -> list[Path]:
    """rosbag2's storage files of bag directory ``folder``, by split number ``n``: the files
    ``<folder name>_<n>.<ext>``, else (a directory the user renamed) the files ``<name>_<n>.<ext>``
    of one ``<name>``, as ``ros2 bag reindex`` takes any ``<name>_<n>.<ext>``, when they are every
    storage file of the directory and numbered ``0 .. k-1`` (files of separate recordings, e.g.
    ``run_1.mcap``, ``run_2.mcap``, stay separate bags)."""
    series: dict[str, list[tuple[int, Path]]] = {}
    others = 0
    for child in folder.iterdir() if folder.is_dir() else ():
        match = SPLIT_NAME.match(child.name)
        if match and child.is_file():
            series.setdefault(match.group(1), []).append((int(match.group(2)), child))
        elif child.suffix in (".mcap", ".db3"):
            others += 1
    found = series.get(folder.name)
    if found is None and len(series) == 1 and not others:
        (candidate,) = series.values()
        found = candidate if sorted(n for n, _ in candidate) == list(range(len(candidate))) else None
    return [path for _, path in sorted(found or [])]


SPLIT_NAME = re.compile(r"(.+)_(\d+)(?:\.mcap|\.db3)$")
"""A split storage file: ``<name>_<n>.<ext>``."""


def needs_reindex(bag: Path) -> bool:
    """Whether ``bag`` is a directory of split storage files without a metadata.yaml."""
    return bag.is_dir() and not (bag / "metadata.yaml").is_file() and len(split_files(bag)) > 1


@contextmanager
def reindexed_view(bag: Path) -> Iterator[tuple[Path, list[str]]]:
    """``(path to read, notes)``: ``bag`` itself, or while the context is open a temporary directory of
    the same name holding links to its split files (and journals) and a reconstructed metadata.yaml."""
    if not needs_reindex(bag):
        yield bag, []
        return
    files = split_files(bag)
    kinds = sorted({f.suffix for f in files})
    if len(kinds) > 1:
        raise CorruptBagError(f"no metadata.yaml and split storage files of several kinds {kinds}; run "
                              "`ros2 bag reindex` on the bag, or move the files of each kind apart", path=bag)
    with tempfile.TemporaryDirectory(prefix="ompn_reindex_") as tmp:
        view = Path(tmp) / bag.name
        view.mkdir()
        for file in files:
            for item in (file, *sorted(bag.glob(glob_escape(file.name) + "-*"))):  # with journals (.journal)
                if item.is_file():
                    (view / item.name).symlink_to(item.resolve())
        text = yaml.safe_dump({"rosbag2_bagfile_information": _metadata(files)}, sort_keys=False)
        (view / "metadata.yaml").write_text(text, encoding="utf-8")
        names = ", ".join(f.name for f in files)
        command = f"ros2 bag reindex {bag} {STORAGE_IDS[files[0].suffix]}"
        yield view, [f"no metadata.yaml: its {len(files)} storage files ({names}) were read as one bag in "
                     f"split order, as `{command}` would restore it (run that to repair the bag itself)"]


def _metadata(files: list[Path]) -> dict[str, Any]:
    """A version-9 ``rosbag2_bagfile_information`` for ``files`` (one storage kind, split order)."""
    topics: dict[tuple[str, str], dict[str, Any]] = {}
    entries = []
    start, end = None, None
    for file in files:
        first, last, counts = _scan(file, topics)
        if first is not None and last is not None:
            start = first if start is None else min(start, first)
            end = last if end is None else max(end, last)
        entries.append({"path": file.name, "starting_time": {"nanoseconds_since_epoch": first or 0},
                        "duration": {"nanoseconds": max(0, (last or 0) - (first or 0))},
                        "message_count": sum(counts.values())})
        for key, n in counts.items():
            topics[key]["message_count"] += n
    total = sum(t["message_count"] for t in topics.values())
    return {
        "version": 9, "storage_identifier": STORAGE_IDS[files[0].suffix],
        "relative_file_paths": [f.name for f in files],
        "duration": {"nanoseconds": max(0, (end or 0) - (start or 0))},
        "starting_time": {"nanoseconds_since_epoch": start or 0},
        "message_count": total, "topics_with_message_count": list(topics.values()),
        "compression_format": "", "compression_mode": "", "files": entries, "custom_data": None,
        "ros_distro": "",
    }


def _scan(file: Path, topics: dict[tuple[str, str], dict[str, Any]]) -> tuple[int | None, int | None,
                                                                           dict[tuple[str, str], int]]:
    """First and last stamp and message counts of ``file``; its topics are added to ``topics``."""
    counts: dict[tuple[str, str], int] = {}
    try:
        with Reader(file) as reader:
            for conn in reader.connections:
                key = (conn.topic, conn.msgtype)
                ext: Any = conn.ext
                topics.setdefault(key, _topic(conn.topic, conn.msgtype, conn.digest,
                                              dump_qos_v9(list(ext.offered_qos_profiles))))
                counts[key] = counts.get(key, 0) + int(conn.msgcount or 0)
            if not reader.message_count:
                return None, None, counts
            return reader.start_time, reader.end_time - 1, counts
    except Exception:  # no summary (a truncated last split): its channels from the records themselves
        for topic, msgtype in _stream_channels(file):
            topics.setdefault((topic, msgtype), _topic(topic, msgtype, "", []))
        return None, None, {}


def _topic(name: str, msgtype: str, digest: str, qos: list[Any]) -> dict[str, Any]:
    return {"topic_metadata": {"name": name, "type": msgtype, "serialization_format": "cdr",
                               "offered_qos_profiles": qos, "type_description_hash": digest},
            "message_count": 0}


def _stream_channels(file: Path) -> list[tuple[str, str]]:
    """``(topic, type)`` of the channels of an mcap file read record by record up to where it breaks."""
    schemas: dict[int, str] = {}
    found: list[tuple[str, str]] = []
    if file.suffix != ".mcap":
        return found
    try:
        with open(file, "rb") as fh:
            for rec in StreamReader(fh, record_size_limit=1 << 30).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    found.append((rec.topic, schemas.get(rec.schema_id, "")))
    except Exception:  # the broken end of the stream: what was found so far stands
        pass
    return found
