"""Durable rosbag2 storage: chunk CRCs for mcap and a bounded loss window for both storages.

``rosbags`` (pinned 0.11.9) writes rosbag2 v9 bags but leaves every mcap chunk CRC at 0 (a flipped
byte then reads without error) and keeps everything since the bag opened in one place that a killed
process loses: the open sqlite3 transaction, or the pending 1 MiB mcap chunk in memory.
:class:`DurableWriter` is its ``Writer`` with two storage plugins that fix both:

* :class:`CrcMcapWriter` writes the CRC-32 of the uncompressed records into every chunk (the field
  the MCAP specification defines for it; the ``mcap`` package and ``rosbags`` verify it on read);
* :meth:`DurableWriter.checkpoint` (at least every ``commit_period`` seconds while messages arrive,
  and whenever the caller asks) commits the sqlite3 transaction, or closes the pending mcap chunk
  and flushes the file.  A process killed with SIGKILL therefore loses at most the last period:
  sqlite3 keeps every committed row, and the mcap data section up to the last chunk stays readable
  record by record (the bag reader's salvage path).  The live recorder checkpoints itself
  (``commit_period=None`` here) at the points :mod:`ompn_ros.data.recorder.step_commits` chooses.

Its metadata (``metadata.yaml`` and the copy inside the storage file) says ``ros_distro: jazzy``, as
``ros2 bag record`` on Jazzy writes it, and each topic's ``offered_qos_profiles`` lists the QoS its
publishers offered (:func:`offered_qos`; ``ros2 bag play`` replays a topic with them, so a best-effort
sensor is not replayed as reliable).

Used by the live recorder (``bag_recorder``) and by ``ompn_collect`` (``EpisodeBagWriter``).
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

from ompn_ros.layout import OutputQos

# Chunk record: opcode (1) + record length (8) + message_start_time, message_end_time,
# uncompressed_size (3 x 8), then uncompressed_crc (4): MCAP specification, "Chunk (op=0x06)".
_CHUNK_CRC_OFFSET = 1 + 8 + 3 * 8


ROS_DISTRO = "jazzy"
"""``ros_distro`` of the bags written here (``rosbags`` would write its own name)."""
_DISTRO_LINE = ("ros_distro: rosbags", f"ros_distro: {ROS_DISTRO}")


def _jazzy(metadata: str) -> str:
    """rosbag2 metadata text with ``ros_distro: jazzy``."""
    return metadata.replace(*_DISTRO_LINE)


def _qos_time(duration: Any) -> QosTime:
    ns = int(getattr(duration, "nanoseconds", 0))
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def offered_qos(profiles: Iterable[Any]) -> list[Qos]:
    """The ``offered_qos_profiles`` of a topic from its publishers' QoS profiles (``rclpy`` QoSProfile
    objects, as ``Node.get_publishers_info_by_topic`` gives them; their policies carry the rmw enum
    values that rosbag2 metadata uses).  An unknown policy value becomes ``UNKNOWN``."""
    def enum(kind: Any, value: Any) -> Any:
        try:
            return kind(int(value))
        except (TypeError, ValueError):
            return kind.UNKNOWN

    return [Qos(history=enum(QosHistory, p.history), depth=int(p.depth),
                reliability=enum(QosReliability, p.reliability), durability=enum(QosDurability, p.durability),
                deadline=_qos_time(p.deadline), lifespan=_qos_time(p.lifespan),
                liveliness=enum(QosLiveliness, p.liveliness),
                liveliness_lease_duration=_qos_time(p.liveliness_lease_duration),
                avoid_ros_namespace_conventions=bool(p.avoid_ros_namespace_conventions))
            for p in profiles]


def output_qos(qos: OutputQos) -> Qos:
    """The ``offered_qos_profiles`` entry of a topic ``ompn_node`` publishes with ``qos``
    (:class:`~ompn_ros.layout.OutputQos`: RELIABLE, KEEP_LAST, TRANSIENT_LOCAL or VOLATILE)."""
    never = QosTime(0, 0)  # rosbag2's "default" (infinite) deadline, lifespan and lease
    return Qos(history=QosHistory.KEEP_LAST, depth=int(qos.depth), reliability=QosReliability.RELIABLE,
               durability=QosDurability.TRANSIENT_LOCAL if qos.transient_local else QosDurability.VOLATILE,
               deadline=never, lifespan=never, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=never, avoid_ros_namespace_conventions=False)


class CrcMcapWriter(McapWriter):
    """``rosbags`` mcap storage writer that fills in each chunk's ``uncompressed_crc``."""

    def close_chunk(self) -> None:
        """Write the pending chunk, then patch its CRC field in place (O(chunk size))."""
        crc = zlib.crc32(self.chunk.bio.getbuffer())
        start = self.bio.tell()
        super().close_chunk()
        end = self.bio.tell()
        self.bio.seek(start + _CHUNK_CRC_OFFSET)
        self.bio.write(crc.to_bytes(4, "little"))
        self.bio.seek(end)

    def checkpoint(self) -> None:
        """Put every message written so far into the file (a short chunk if needed)."""
        if self.chunk.msgs:
            self.close_chunk()
        self.bio.flush()

    def close(self, version: int, metadata: str) -> None:
        """Close the file; its embedded rosbag2 metadata says ``ros_distro: jazzy``."""
        super().close(version, _jazzy(metadata))


class CommittingSqlite3Writer(Sqlite3Writer):
    """``rosbags`` sqlite3 storage writer whose open transaction can be committed on demand."""

    def checkpoint(self) -> None:
        """Commit the rows inserted so far (one sqlite3 COMMIT)."""
        self.conn.commit()

    def close(self, version: int, metadata: str) -> None:
        """Close the database; its embedded rosbag2 metadata says ``ros_distro: jazzy``."""
        super().close(version, _jazzy(metadata))


class DurableWriter(Writer):
    """``rosbags.rosbag2.Writer`` with CRC'd mcap chunks and periodic commits (module docstring).

    Args:
        path: bag directory to create.
        version: rosbag2 metadata version (8 or 9).
        storage_plugin: ``StoragePlugin.MCAP`` or ``StoragePlugin.SQLITE3``.
        commit_period: seconds between automatic checkpoints while messages are written
            (``None``: only explicit :meth:`checkpoint` calls and :meth:`close`).
    """

    STORAGE_PLUGINS = {  # noqa: RUF012 (the base class's plugin table, same shape)
        StoragePlugin.SQLITE3: CommittingSqlite3Writer,
        StoragePlugin.MCAP: CrcMcapWriter,
    }

    def __init__(self, path: Path | str, *, version: int = 9,
                 storage_plugin: StoragePlugin = StoragePlugin.MCAP,
                 commit_period: float | None = 1.0) -> None:
        super().__init__(path, version=version, storage_plugin=storage_plugin)  # type: ignore[arg-type]
        if commit_period is not None and not commit_period > 0:
            raise ValueError(f"commit_period must be > 0 seconds or None, got {commit_period}")
        self.commit_period = commit_period
        self.checkpoints = 0
        self._last_checkpoint = time.monotonic()

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        """Write one message; checkpoints when ``commit_period`` has passed since the last one."""
        super().write(connection, timestamp, data)
        if self.commit_period is not None and time.monotonic() - self._last_checkpoint >= self.commit_period:
            self.checkpoint()

    def since_checkpoint(self) -> float:
        """Seconds since the last checkpoint (or since the writer was created)."""
        return time.monotonic() - self._last_checkpoint

    def close(self) -> None:
        """Close the storage and write metadata.yaml (``ros_distro: jazzy``, replaced atomically)."""
        super().close()
        text = self.metapath.read_text(encoding="utf-8")
        if _DISTRO_LINE[0] in text:
            tmp = self.metapath.with_suffix(".yaml.tmp")
            tmp.write_text(_jazzy(text), encoding="utf-8")
            tmp.replace(self.metapath)

    def checkpoint(self) -> None:
        """Make everything written so far survive a killed process (sqlite3 COMMIT / mcap chunk flush)."""
        storage: Any = self.storage
        if storage is not None:
            storage.checkpoint()
            self.checkpoints += 1
        self._last_checkpoint = time.monotonic()


def _chunks(data: bytes, path: str | Path) -> list[tuple[int, int, int]]:
    """``(crc_offset, records_start, records_end)`` of every uncompressed chunk, record by record."""
    magic = b"\x89MCAP0\r\n"
    if not data.startswith(magic):
        raise ValueError(f"{path}: not an mcap file (bad magic)")
    pos = len(magic)
    out = []
    while pos + 9 <= len(data):
        op = data[pos]
        length = int.from_bytes(data[pos + 1:pos + 9], "little")
        if pos + 9 + length > len(data):
            raise ValueError(f"{path}: record at byte {pos} is cut short")
        if op == 0x06:  # Chunk: 3 x u64, u32 crc, string compression, u64 records length, records
            body = pos + 9
            comp_len = int.from_bytes(data[body + 28:body + 32], "little")
            compression = data[body + 32:body + 32 + comp_len].decode()
            if compression:
                raise ValueError(f"{path}: chunk at byte {pos} is '{compression}'-compressed")
            at = body + 32 + comp_len
            size = int.from_bytes(data[at:at + 8], "little")
            out.append((body + 24, at + 8, at + 8 + size))
        pos += 9 + length
        if op == 0x02:  # Footer
            break
    return out


def chunk_crcs(path: str | Path) -> list[tuple[int, int]]:
    """``(stored, computed)`` CRC-32 of every chunk of an mcap file (a stored 0 = "not computed").

    Raises ``ValueError`` on a file that is not mcap or whose records are cut short.  O(file size).
    """
    data = Path(path).read_bytes()
    return [(int.from_bytes(data[crc:crc + 4], "little"), zlib.crc32(data[a:b]))
            for crc, a, b in _chunks(data, path)]


def refresh_chunk_crcs(path: str | Path, *, clear: bool = False) -> int:
    """Rewrite every chunk CRC of an mcap file to match its records (after a deliberate edit, e.g. in
    a test), or with ``clear`` to 0 ("not computed", what writers without CRCs leave); returns how
    many changed.  O(file size)."""
    data = bytearray(Path(path).read_bytes())
    changed = 0
    for crc, a, b in _chunks(bytes(data), path):
        new = bytes(4) if clear else zlib.crc32(data[a:b]).to_bytes(4, "little")
        if data[crc:crc + 4] != new:
            data[crc:crc + 4] = new
            changed += 1
    if changed:
        Path(path).write_bytes(bytes(data))
    return changed


__all__ = ["CommittingSqlite3Writer", "CrcMcapWriter", "DurableWriter", "chunk_crcs", "offered_qos",
           "output_qos", "refresh_chunk_crcs"]
