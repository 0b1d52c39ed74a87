"""Raw messages of the wanted topics, undecoded: the normal read through ``rosbags``.

Cost: one pass over the bag's storage, O(bytes of the wanted topics) memory (raw CDR is kept,
decoding happens per topic in bulk afterwards).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rosbags.rosbag2 import Reader

from ..errors import CorruptBagError
from .paths import storage_files


@dataclass
class TopicData:
    """Stamps (ns, as read), raw CDR messages and record positions (``seqs``: the message's index
    in the bag's record order, across topics) of one topic."""

    msgtype: str
    stamps: list[int] = field(default_factory=list)
    raws: list[bytes] = field(default_factory=list)
    seqs: list[int] = field(default_factory=list)


@dataclass
class RawBag:
    """Everything read from one bag; ``corrupt`` = the corruption that ended the read, if any."""

    path: Path
    types: dict[str, str]
    topics: dict[str, TopicData]
    corrupt: CorruptBagError | None = None
    untrusted: str | None = None  # damage found that no scan could locate: no episode is trusted
    count: int = 0  # messages read so far (wanted or not): the next record position

    def append(self, wanted: set[str] | None, topic: str, msgtype: str, stamp: int, data: bytes) -> None:
        """Add one message when its topic is wanted."""
        self.count += 1
        if wanted is not None and topic not in wanted:
            return
        tdata = self.topics.get(topic)
        if tdata is None:
            tdata = self.topics[topic] = TopicData(msgtype)
        tdata.stamps.append(stamp)
        tdata.raws.append(data)
        tdata.seqs.append(self.count - 1)

    def truncate(self, stamp: int) -> None:
        """Drop every message stamped at or after ``stamp`` (the corrupt tail)."""
        for tdata in self.topics.values():
            keep = [i for i, s in enumerate(tdata.stamps) if s < stamp]
            if len(keep) != len(tdata.stamps):
                tdata.stamps = [tdata.stamps[i] for i in keep]
                tdata.raws = [tdata.raws[i] for i in keep]
                tdata.seqs = [tdata.seqs[i] for i in keep]


def collect_rosbags(bag: Path, wanted: set[str] | None) -> RawBag:
    """Read every message of the wanted topics with ``rosbags`` (the normal path).

    ``rosbags`` checks mcap chunk CRCs when the writer set them; a mismatch ends the read like
    any other storage error: the messages read before it are kept and ``corrupt`` names the file.
    Raises :class:`CorruptBagError` when the bag cannot even be opened.
    """
    raw = RawBag(bag, {}, {})
    read = 0
    reader = Reader(bag)
    try:
        reader.open()
    except Exception as err:  # rosbags raises many types on broken storage
        files = storage_files(bag) if bag.is_dir() else [bag]
        where = files[0] if len(files) == 1 else bag
        raise CorruptBagError(f"cannot open bag: {err}", path=where) from err
    try:
        raw.types = {c.topic: c.msgtype for c in reader.connections}
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for topic in {c.topic for c in conns}:
            raw.topics[topic] = TopicData(raw.types[topic])
        if conns:
            by_id = {c.id: raw.topics[c.topic] for c in conns}
            for conn, stamp, data in reader.messages(connections=conns):
                tdata = by_id[conn.id]
                tdata.stamps.append(stamp)
                tdata.raws.append(data)
                tdata.seqs.append(read)
                read += 1
    except Exception as err:  # any storage error ends the read; the caller decides what to keep
        raw.corrupt = CorruptBagError(f"read failed after {read} messages: {type(err).__name__} {err}",
                                      path=bag)
    finally:
        try:
            reader.close()
        except Exception:  # closing a broken storage must not hide the real error
            pass
    raw.count = read
    return raw
