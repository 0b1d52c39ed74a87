"""The entry points: read one bag, read many bags, iterate raw messages."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import TypeVar

from rosbags.rosbag2 import Reader

from ompn_ros import layout

from ..episode import Episode
from ..errors import BagError, CorruptBagError, NoEpisodeError, ReaderSpecError
from .assemble import bag_episodes
from .context import BagContext
from .decode import decode_bag
from .journal import committed_view
from .paths import metadata_topic_types, resolve_bag_paths, storage_files, wanted_topics
from .plan import stream_plan
from .raw import Chooser, RawBag, collect_rosbags
from .reindex import reindexed_view
from .report import BagReport, ReadReport, ReadResult
from .salvage import salvage
from .spec import OnError, ReaderSpec
from .steps import restamp_log
from .verify import mcap_bad_chunks, mcap_chunks_without_crc, sqlite_problem


def read_raw(bag: Path, spec: ReaderSpec, on_error: OnError) -> RawBag:
    """Raw messages of the topics ``spec`` may use; a corrupt storage raises or is salvaged.

    sqlite3 files pass ``PRAGMA quick_check`` first; with ``skip_tail`` a damaged one is scanned
    row by row and cut where the scan breaks, and when it does not break (damage inside message
    payloads) no episode of the bag is trusted.
    """
    types = metadata_topic_types(bag)
    wanted = wanted_topics(spec, types) if types is not None else None
    choose = partial(wanted_topics, spec)  # without metadata.yaml: from the storage's own topics
    damage = _sqlite_damage(bag)
    if damage is not None:
        if on_error == "raise":
            raise damage
        raw = salvage(bag, wanted, damage, choose)
        if raw.corrupt is damage:
            raw.untrusted = str(damage)
        return raw
    try:
        raw = collect_rosbags(bag, wanted, lambda bag_types: stream_plan(bag, spec, bag_types), choose)
    except CorruptBagError as err:
        if _rosbags_refuses(bag, err):
            return _record_by_record(bag, wanted, choose, err)
        if on_error == "raise":
            raise
        raw = salvage(bag, wanted, err, choose)
    if raw.corrupt is not None and _rosbags_refuses(bag, raw.corrupt):
        return _record_by_record(bag, wanted, choose, raw.corrupt)
    if raw.corrupt is not None:
        raw.corrupt = _locate_crc_failure(bag, raw.corrupt)
        if on_error == "raise":
            raise raw.corrupt
    return raw


ROSBAGS_REFUSES = {"Profile is not ros2": "its mcap profile is not 'ros2'",
                   "not in timestamp order": "it has no index and its messages are not in log-time order"}
"""What ``rosbags`` refuses in an intact mcap file (its error -> the note): a profile other than
``ros2`` (a writer that leaves it empty) and an unindexed file whose messages are not in log-time
order."""


def _rosbags_refuses(bag: Path, err: CorruptBagError) -> str | None:
    """The note for an mcap bag ``rosbags`` refuses although it is intact, else ``None``."""
    why = [note for text, note in ROSBAGS_REFUSES.items() if text in err.reason]
    return why[0] if why and all(f.suffix == ".mcap" for f in storage_files(bag)) else None


def _record_by_record(bag: Path, wanted: set[str] | None, choose: Chooser, err: CorruptBagError) -> RawBag:
    """An intact mcap file ``rosbags`` will not read (:data:`ROSBAGS_REFUSES`), read record by record
    (:func:`.salvage.salvage`, no index needed); a note says why.  Damage found on the way is the
    bag's corruption as usual."""
    raw = salvage(bag, wanted, None, choose)
    raw.notes.append(f"read record by record (no index needed): {_rosbags_refuses(bag, err)}")
    return raw


def _sqlite_damage(bag: Path) -> CorruptBagError | None:
    for file in storage_files(bag):
        if file.suffix == ".db3":
            problem = sqlite_problem(file)
            if problem is not None:
                return CorruptBagError(f"sqlite database is malformed (PRAGMA quick_check: {problem})",
                                       path=file)
    return None


def _locate_crc_failure(bag: Path, err: CorruptBagError) -> CorruptBagError:
    """Name the mcap file and chunk behind a checksum failure reported by ``rosbags``."""
    if "checksum" not in err.reason.lower():
        return err
    for file in storage_files(bag):
        bad = mcap_bad_chunks(file) if file.suffix == ".mcap" else []
        if bad:
            number, first, last = bad[0]
            return CorruptBagError(f"mcap chunk #{number} (messages stamped {first}..{last} ns) fails its "
                                   f"CRC check ({err.reason})", path=file)
    return err


def _crc_note(bag: Path, report: BagReport) -> None:
    for file in storage_files(bag):
        if file.suffix == ".mcap":
            chunks, zero = mcap_chunks_without_crc(file)
            if zero:
                report.notes.append(f"{file.name}: {zero} of {chunks} mcap chunks carry no CRC; their bytes "
                                    "are not verified (decoded values are still checked finite)")


def read_bag(bag: Path, spec: ReaderSpec, on_error: OnError, report: BagReport,
             joint_orders: dict[str, tuple[str, ...]] | None = None) -> list[Episode]:
    """Read one bag (see :func:`read_episodes`); ``report`` is filled in.  A split bag without its
    metadata.yaml is read as one bag (:func:`.reindex.reindexed_view`); a sqlite3 bag with a
    journal left by a killed recorder is read as of its last commit, from a recovered copy
    (:func:`.journal.committed_view`); errors and notes still name ``bag``."""
    with reindexed_view(bag) as (indexed, index_notes), committed_view(indexed) as (readable, notes):
        report.notes.extend(index_notes + notes)
        try:
            return _read_view(bag, readable, spec, on_error, report, joint_orders)
        except BagError as err:
            if readable == bag:
                raise
            raise _renamed(err, readable, bag) from None


E = TypeVar("E", bound=BagError)


def _renamed(err: E, copy: Path, bag: Path) -> E:
    """``err`` naming the user's ``bag`` instead of its recovered ``copy``."""
    path = None if err.path is None else err.path.replace(str(copy), str(bag))
    return type(err)(err.reason, path=path, topic=err.topic, index=err.index, stamp=err.stamp)


def _read_view(bag: Path, readable: Path, spec: ReaderSpec, on_error: OnError, report: BagReport,
               joint_orders: dict[str, tuple[str, ...]] | None) -> list[Episode]:
    raw = read_raw(readable, spec, on_error)
    if raw.corrupt is not None:
        if readable != bag:
            raw.corrupt = _renamed(raw.corrupt, readable, bag)
        report.error = str(raw.corrupt)
        if not raw.types:  # e.g. an mcap file whose only chunk is cut: no topic, no message
            report.notes.append("nothing could be read before the damage (not even the bag's topics)")
            return []
    report.notes.extend(raw.notes)
    for topic, n in raw.repeats.counts.items():
        report.count(report.duplicates, topic, n)
    report.notes.extend(raw.repeats.notes())
    _crc_note(readable, report)
    ctx = BagContext(raw, spec, report, name=bag, joint_orders=joint_orders)
    topics = ctx.resolve_all()
    headed = [t for t in topics.used() if set(ctx.raw.topic_types(t)) == {layout.JOINT_STATE}]
    report.notes.extend(restamp_log(raw, readable, headed))  # clocks that step (reader.steps)
    decoded = decode_bag(ctx, topics, on_error)
    for topic in topics.used():
        report.messages[topic] = len(raw.topics[topic].stamps) if topic in raw.topics else 0
    if topics.sub and topics.labels != layout.LABELS_BOUNDARY and not report.messages.get(topics.sub):
        empty = NoEpisodeError(f"no message at all on the label topic (labels: {topics.labels}): no "
                               "label can be read; set labels: none to read the bag without labels",
                               path=bag, topic=topics.sub)
        if on_error == "raise":
            raise empty
        report.drop_episode("no labels", str(empty))
        return []
    episodes = bag_episodes(ctx, topics, decoded)
    if not episodes and on_error == "raise":
        raise NoEpisodeError(_no_episode_reason(report, topics.obs), path=bag)
    return episodes


def _no_episode_reason(report: BagReport, obs_topic: str) -> str:
    """Why a bag gave no episode, in one line."""
    parts = [f"{report.messages.get(obs_topic, 0)} observation(s) on '{obs_topic}'"]
    empty = sorted(topic for topic, n in report.messages.items() if n == 0)
    if empty:
        parts.append(f"no message at all on {empty}")
    if report.dropped:
        parts.append(f"dropped episodes {report.dropped}")
    for name in ("obs_dropped", "unattached", "missing"):
        table = getattr(report, name)
        if table:
            parts.append(f"{name} {table}")
    return ("no complete episode (" + "; ".join(parts) + "); check the reader spec's topics, "
            "tolerance and split (on_error='skip_tail' returns no episode instead)")


def read_episodes(
    paths: str | Path | Sequence[str | Path],
    *,
    spec: ReaderSpec | None = None,
    on_error: OnError = "raise",
    joint_orders: dict[str, tuple[str, ...]] | None = None,
) -> ReadResult:
    """Read the episodes of one or more bags.

    Args:
        paths: a storage file, a bag directory, a directory of bags, a glob, or a sequence of them.
        spec: topics/types/alignment; ``None`` = defaults (our topic names, types as in the bag).
        on_error: ``'raise'`` or ``'skip_tail'`` (keep episodes before a corrupt tail, report it).
        joint_orders: JointState topic -> joint order, filled by the first bag that fixes it (the
            order of a topic read without ``joint_names``: :func:`.joints.first_names_order`); pass
            the same dict to read further bags under one contract (one per call otherwise).

    Returns:
        ``ReadResult(episodes, report)``.
    """
    if on_error not in ("raise", "skip_tail"):
        raise ReaderSpecError(f"on_error must be 'raise' or 'skip_tail', got '{on_error}'")
    spec = spec or ReaderSpec()
    report = ReadReport()
    orders = {} if joint_orders is None else joint_orders
    episodes: list[Episode] = []
    for bag in resolve_bag_paths(paths):
        bag_report = BagReport(str(bag))
        report.bags.append(bag_report)
        episodes.extend(read_bag(bag, spec, on_error, bag_report, orders))
    return ReadResult(episodes, report)


def iter_raw_messages(bag: str | Path) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, stamp, raw)`` of every message (rosbags order); the baseline of the benchmark."""
    with Reader(Path(bag)) as reader:
        for conn, stamp, data in reader.messages():
            yield conn.topic, stamp, data
