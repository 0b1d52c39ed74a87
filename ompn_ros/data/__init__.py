"""Episodes and their rosbag2 storage: writer, reader (with alignment report), cache, errors."""

from typing import TYPE_CHECKING

from ompn_ros.lazy import lazy_names

if TYPE_CHECKING:  # the names below load on first use (PEP 562): importing a submodule stays light
    from .cache import EpisodeArrays, load_arrays
    from .episode import Episode
    from .errors import (
        AlignmentError,
        BagError,
        BagNotFoundError,
        CorruptBagError,
        LabelError,
        MissingTopicError,
        NoEpisodeError,
        NonFiniteValueError,
        ReaderSpecError,
        TopicTypeError,
        UnknownTypeError,
        VectorLengthError,
    )
    from .reader import BagReport, ReaderSpec, ReadReport, ReadResult, VectorSource, read_episodes
    from .recorder.bag_writer import EpisodeBagWriter, write_episodes


_LAZY = {
    "EpisodeArrays": "ompn_ros.data.cache",
    "load_arrays": "ompn_ros.data.cache",
    "Episode": "ompn_ros.data.episode",
    "AlignmentError": "ompn_ros.data.errors",
    "BagError": "ompn_ros.data.errors",
    "BagNotFoundError": "ompn_ros.data.errors",
    "CorruptBagError": "ompn_ros.data.errors",
    "LabelError": "ompn_ros.data.errors",
    "MissingTopicError": "ompn_ros.data.errors",
    "NoEpisodeError": "ompn_ros.data.errors",
    "NonFiniteValueError": "ompn_ros.data.errors",
    "ReaderSpecError": "ompn_ros.data.errors",
    "TopicTypeError": "ompn_ros.data.errors",
    "UnknownTypeError": "ompn_ros.data.errors",
    "VectorLengthError": "ompn_ros.data.errors",
    "BagReport": "ompn_ros.data.reader",
    "ReaderSpec": "ompn_ros.data.reader",
    "ReadReport": "ompn_ros.data.reader",
    "ReadResult": "ompn_ros.data.reader",
    "VectorSource": "ompn_ros.data.reader",
    "read_episodes": "ompn_ros.data.reader",
    "EpisodeBagWriter": "ompn_ros.data.recorder.bag_writer",
    "write_episodes": "ompn_ros.data.recorder.bag_writer",
}

__all__ = [
    "AlignmentError", "BagError", "BagNotFoundError", "BagReport", "CorruptBagError", "Episode",
    "EpisodeArrays", "EpisodeBagWriter", "LabelError", "MissingTopicError", "NoEpisodeError",
    "NonFiniteValueError", "ReadReport", "ReadResult",
    "ReaderSpec", "ReaderSpecError", "TopicTypeError", "UnknownTypeError", "VectorLengthError",
    "VectorSource", "load_arrays", "read_episodes", "write_episodes",
]


__getattr__ = lazy_names(__name__, globals(), _LAZY)
