"""Copies of bags without each episode's final observation: the bags a robot logs when nothing
is recorded after the last command (docs/experiments.md, "Bags as robots log them").

Within every episode (start to end marker on the ``episode`` topic) the observation and joint-state
messages stamped after the episode's last action are left out; every other message is copied
unchanged.  The reader then meets episodes whose last observation has an action and applies
``ReaderSpec.final_observation`` (``drop_last_step`` or ``duplicate``).  Cost: O(messages) with one
episode's messages held in memory.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.errors import BagError
from ompn_ros.data.reader.paths import resolve_bag_paths
from ompn_ros.data.recorder.bag_writer import storage_plugin
from ompn_ros.data.recorder.storage import DurableWriter
from ompn_ros.layout import resolve_topic

Message = tuple[Any, int, bytes]


class StripError(BagError):
    """A bag that cannot be stripped (not a bag, output exists, no episode markers)."""


@dataclass
class StripStats:
    """What :func:`strip_final_observations` copied and left out."""

    episodes: int = 0
    copied: int = 0
    removed: int = 0


def _episodes(reader: Any, episode_topic: str) -> Iterator[tuple[list[Message], bool]]:
    """The bag's messages in time order, grouped: (an episode's messages, True) from its start
    marker to its end marker, (messages between episodes, False) otherwise."""
    group: list[Message] = []
    inside = False
    for conn, stamp, raw in reader.messages():
        if conn.topic == episode_topic:
            marker = m.parse_marker(raw, conn.msgtype)
            kind = marker[0] if marker else ""
            if kind == layout.EPISODE_START and not inside:
                if group:
                    yield group, False
                group, inside = [], True
            group.append((conn, stamp, bytes(raw)))
            if kind == layout.EPISODE_END and inside:
                yield group, True
                group, inside = [], False
            continue
        group.append((conn, stamp, bytes(raw)))
    if group:
        yield group, False


def _without_final(group: list[Message], action: str, dropped: set[str]) -> list[Message]:
    stamps = [stamp for conn, stamp, _ in group if conn.topic == action]
    if not stamps:
        return group
    last = max(stamps)
    return [msg for msg in group if not (msg[0].topic in dropped and msg[1] > last)]


def strip_final_observations(
    src: str | Path, out: str | Path, *, namespace: str = "/", storage: str = "mcap"
) -> StripStats:
    """Write a copy of the bag ``src`` into the new directory ``out`` without each episode's
    observation (and joint state) after its last action.  The layout's topics under ``namespace``."""
    src, out = Path(src), Path(out)
    if out.exists():
        raise StripError("output exists; the stripping tool never overwrites a bag", path=out)
    action = resolve_topic(layout.ACTION, namespace)
    dropped = {resolve_topic(layout.OBSERVATION, namespace), resolve_topic(layout.JOINT_STATES, namespace)}
    stats = StripStats()
    ts = m.register_interfaces()  # EpisodeMarker
    with Reader(src) as reader:
        # the typed markers, or in older bags the deprecated DiagnosticArray ones
        topics = {c.topic for c in reader.connections}
        names = [resolve_topic(name, namespace) for name in (layout.EPISODE_MARKER, layout.EPISODE)]
        episode_topic = next((name for name in names if name in topics), "")
        if not episode_topic:
            raise StripError(f"no {names[0]} topic: episodes cannot be delimited", path=src)
        writer = DurableWriter(out, version=9, storage_plugin=storage_plugin(storage))
        writer.open()
        try:
            conns = {
                c.id: writer.add_connection(c.topic, c.msgtype, typestore=ts) for c in reader.connections
            }
            for group, is_episode in _episodes(reader, episode_topic):
                kept = _without_final(group, action, dropped) if is_episode else group
                stats.episodes += int(is_episode)
                stats.removed += len(group) - len(kept)
                for conn, stamp, raw in kept:
                    writer.write(conns[conn.id], stamp, raw)
                stats.copied += len(kept)
        finally:
            writer.close()
    return stats


def strip_bags(src: str | Path, out: str | Path, *, namespace: str = "/") -> StripStats:
    """:func:`strip_final_observations` on every bag under ``src`` (a bag or a directory of bags),
    each written to the same relative place under ``out``.  Returns the summed statistics."""
    src, out = Path(src), Path(out)
    total = StripStats()
    for bag in resolve_bag_paths(src):
        bag_dir = bag if bag.is_dir() else bag.parent
        rel = bag_dir.relative_to(src) if bag_dir != src else Path(".")
        target = out / rel if rel != Path(".") else out
        target.parent.mkdir(parents=True, exist_ok=True)
        stats = strip_final_observations(bag_dir, target, namespace=namespace)
        total.episodes += stats.episodes
        total.copied += stats.copied
        total.removed += stats.removed
    return total


__all__ = ["StripError", "StripStats", "strip_bags", "strip_final_observations"]
