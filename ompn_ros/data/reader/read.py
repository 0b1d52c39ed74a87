"""The entry points: read one bag, read many bags, iterate raw messages."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

from rosbags.rosbag2 import Reader

from ..episode import Episode
from ..errors import CorruptBagError
from .assemble import bag_episodes
from .context import BagContext
from .decode import decode_bag
from .paths import metadata_topic_types, resolve_bag_paths, wanted_topics
from .raw import RawBag, collect_rosbags
from .report import BagReport, ReadReport, ReadResult
from .salvage import salvage
from .spec import OnError, ReaderSpec


def read_raw(bag: Path, spec: ReaderSpec, on_error: OnError) -> RawBag:
    """Raw messages of the topics ``spec`` may use; a corrupt storage raises or is salvaged."""
    types = metadata_topic_types(bag)
    wanted = wanted_topics(spec, types) if types is not None else None
    try:
        raw = collect_rosbags(bag, wanted)
    except CorruptBagError as err:
        if on_error == "raise":
            raise
        raw = salvage(bag, wanted, err)
    if raw.corrupt is not None and on_error == "raise":
        raise raw.corrupt
    return raw


def read_bag(bag: Path, spec: ReaderSpec, on_error: OnError, report: BagReport) -> list[Episode]:
    """Read one bag (see :func:`read_episodes`); ``report`` is filled in."""
    raw = read_raw(bag, spec, on_error)
    if raw.corrupt is not None:
        report.error = str(raw.corrupt)
    ctx = BagContext(raw, spec, report)
    topics = ctx.resolve_all()
    decoded = decode_bag(ctx, topics, on_error)
    for topic in topics.used():
        report.messages[topic] = len(raw.topics[topic].stamps) if topic in raw.topics else 0
    return bag_episodes(ctx, topics, decoded)


def read_episodes(
    paths: str | Path | Sequence[str | Path],
    *,
    spec: ReaderSpec | None = None,
    on_error: OnError = "raise",
) -> ReadResult:
    """Read the episodes of one or more bags.

    Args:
        paths: a storage file, a bag directory, a directory of bags, a glob, or a sequence of them.
        spec: topics/types/alignment; ``None`` = defaults (our topic names, types as in the bag).
        on_error: ``'raise'`` or ``'skip_tail'`` (keep episodes before a corrupt tail, report it).

    Returns:
        ``ReadResult(episodes, report)``.
    """
    if on_error not in ("raise", "skip_tail"):
        raise ValueError(f"on_error must be 'raise' or 'skip_tail', got '{on_error}'")
    spec = spec or ReaderSpec()
    report = ReadReport()
    episodes: list[Episode] = []
    for bag in resolve_bag_paths(paths):
        bag_report = BagReport(str(bag))
        report.bags.append(bag_report)
        episodes.extend(read_bag(bag, spec, on_error, bag_report))
    return ReadResult(episodes, report)


def iter_raw_messages(bag: str | Path) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, stamp, raw)`` of every message (rosbags order); the baseline of the benchmark."""
    with Reader(Path(bag)) as reader:
        for conn, stamp, data in reader.messages():
            yield conn.topic, stamp, data
