"""Errors of the data package: reading and writing rosbag2 files, reader and observation specs, the
episode cache and the recorder.

Every class derives from :class:`ompn_ros.errors.OMPNError`.  A bag error names what is at fault: the
bag file, the topic and the message index (0-based, counted per topic in stamp order), so a bad
recording can be found and fixed.
"""

from __future__ import annotations

from pathlib import Path

from ompn_ros.errors import OMPNError


class BagError(OMPNError):
    """Base class of every bag reading/writing error."""

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        topic: str | None = None,
        index: int | None = None,
        stamp: int | None = None,
    ) -> None:
        self.reason = message
        self.path = str(path) if path is not None else None
        self.topic = topic
        self.index = index
        self.stamp = stamp  # bag stamp (ns) of the offending message, when known
        super().__init__(self._format())

    def _format(self) -> str:
        where = []
        if self.path is not None:
            where.append(f"bag '{self.path}'")
        if self.topic is not None:
            where.append(f"topic '{self.topic}'")
        if self.index is not None:
            where.append(f"message #{self.index}")
        prefix = ", ".join(where)
        return f"{prefix}: {self.reason}" if prefix else self.reason


class BagNotFoundError(BagError, FileNotFoundError):
    """No bag at the given path (or the glob matched nothing)."""


class CorruptBagError(BagError):
    """The storage file cannot be read (truncated mcap, malformed sqlite database, bad CDR)."""


class NonFiniteValueError(CorruptBagError):
    """A decoded vector holds NaN or infinite values (damaged storage or a broken publisher)."""


class UnknownTypeError(BagError):
    """A message type the reader cannot decode (not in the Jazzy typestore or unsupported)."""


class TopicTypeError(BagError):
    """A topic carries a different message type than the reader spec expects."""


class MissingTopicError(BagError):
    """A topic required by the reader spec is not in the bag."""


class VectorLengthError(BagError):
    """A vector message has a different length than expected (or than the topic's first one)."""


class JointNamesError(BagError):
    """A JointState topic names other joints than its first message (a joint appears or vanishes)."""


class ClockStepError(BagError):
    """A clock the reader aligns on steps back or jumps forward within a bag."""


class AlignmentError(BagError):
    """Per-step messages do not line up with the observation clock (missing or duplicate partner)."""


class LabelError(BagError):
    """The subtask topic's values do not fit the label kind the reader spec names."""


class NoEpisodeError(BagError):
    """A bag holds no complete episode under the reader spec."""


class ReaderSpecError(OMPNError, ValueError):
    """A reader spec (YAML or dataclass) is invalid."""


class CacheFormatError(OMPNError, ValueError):
    """A cache entry that cannot be used (another format version, or missing/short files)."""


class CacheEntryError(CacheFormatError):
    """A cache entry whose key, checksums or offsets do not hold: damaged, edited or another bag's
    (the cache rebuilds it with a note)."""


class NpyAppendError(OMPNError, ValueError):
    """Rows that do not fit the file (another row shape, or a dtype that cannot be cast safely)."""


class EmptyEntryError(OMPNError, ValueError):
    """No episode could be read from the bags given (the message names them and says why)."""


class MixedBagsError(OMPNError, ValueError):
    """Bags whose episodes cannot share one cache entry (another observation size, action kind or
    extras than the bags before them); the message names the bag or entry."""


class ObservationSpecError(OMPNError, ValueError):
    """An invalid observation spec (the message names the entry at fault)."""


class NotEnoughSpace(OMPNError, OSError):
    """Too little free space to start recording (the message names the path and the space)."""


class DatasetError(OMPNError, ValueError):
    """A LeRobot dataset (a local folder, ``data/lerobot/``) that cannot be read or written as asked: the
    message names the folder, file, feature or episode at fault and the way out."""

    def __init__(self, message: str, *, path: str | Path | None = None) -> None:
        self.path = str(path) if path is not None else None
        super().__init__(f"dataset '{self.path}': {message}" if self.path is not None else message)


class DatasetSpecError(DatasetError):
    """A dataset spec (which features are the observation, the action, the labels) is invalid."""
