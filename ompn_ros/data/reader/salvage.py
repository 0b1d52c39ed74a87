"""Read what precedes a corruption, record by record, without the storage's index.

Used with ``on_error='skip_tail'`` when ``rosbags`` cannot open a bag (a truncated mcap has no
summary; a damaged sqlite header).  mcap chunks are checked against their CRC when it is set;
message-compressed messages are decompressed (:mod:`.compressed`).
Cost: one sequential pass over each storage file.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from ..errors import CorruptBagError
from .compressed import decompress, is_compressed
from .paths import storage_files
from .raw import Chooser, RawBag
from .verify import open_readonly


def salvage(bag: Path, wanted: set[str] | None, first_error: CorruptBagError | None,
            choose: Chooser | None = None) -> RawBag:
    """Messages of ``bag`` up to the first unreadable record; later storage files are not trusted
    (``first_error``: what made the normal read fail; ``None``: the bag is not known to be damaged).
    ``choose``: the topics to keep by their types when ``wanted`` is ``None`` (no metadata.yaml),
    applied to each topic as the storage names it."""
    raw = RawBag(bag, {}, {}, corrupt=first_error)
    for file in storage_files(bag):
        try:
            reader = _salvage_mcap if file.suffix == ".mcap" else _salvage_sqlite
            ok = reader(file, _Keep(wanted, choose), raw)
        except (OSError, McapError, sqlite3.Error, ValueError, KeyError) as err:
            raw.corrupt = CorruptBagError(f"unreadable storage: {err}", path=file)
            ok = False
        if not ok:
            break  # later files are after the corruption: not a tail we can trust
    return raw


class _Keep:
    """The topics to keep: ``wanted``, else those ``choose`` picks among the topics seen so far."""

    def __init__(self, wanted: set[str] | None, choose: Chooser | None) -> None:
        self.wanted, self.choose = wanted, choose
        self.topics: set[str] | None = wanted if wanted is not None or choose is None else set()

    def see(self, topic: str, msgtype: str) -> None:
        if self.wanted is None and self.choose is not None and self.topics is not None:
            self.topics |= self.choose({topic: msgtype})


def _salvage_mcap(file: Path, keep: _Keep, raw: RawBag) -> bool:
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    n = 0
    with open(file, "rb") as fh:
        try:
            for rec in StreamReader(fh, record_size_limit=1 << 30, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
                    raw.types.setdefault(rec.topic, schemas.get(rec.schema_id, ""))
                    keep.see(*channels[rec.id])
                elif isinstance(rec, Message):
                    topic, msgtype = channels[rec.channel_id]
                    data = decompress(rec.data) if is_compressed(rec.data) else rec.data
                    raw.append(keep.topics, topic, msgtype, rec.log_time, data)
                    n += 1
        except Exception as err:  # the mcap stream reader raises many types on a broken stream
            text = f"mcap stream broken after {n} messages: {type(err).__name__} {err}".rstrip()
            raw.corrupt = CorruptBagError(text, path=file)
            return False
    return True


def _salvage_sqlite(file: Path, keep: _Keep, raw: RawBag) -> bool:
    con = open_readonly(file)
    n = 0
    try:
        topics = {tid: (name, typ) for tid, name, typ in con.execute("SELECT id, name, type FROM topics")}
        for name, typ in topics.values():
            raw.types.setdefault(name, typ)
            keep.see(name, typ)
        try:
            for tid, stamp, data in con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id"):
                name, typ = topics[tid]
                data = decompress(data) if is_compressed(data) else bytes(data)
                raw.append(keep.topics, name, typ, int(stamp), data)
                n += 1
        except sqlite3.DatabaseError as err:
            text = f"sqlite scan broken after {n} messages: {type(err).__name__} {err}"
            raw.corrupt = CorruptBagError(text, path=file)
            return False
    finally:
        con.close()
    return True
