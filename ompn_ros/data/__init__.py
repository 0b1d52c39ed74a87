"""Episodes and their rosbag2 storage: writer, reader (with alignment report), cache, errors."""

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

__all__ = [
    "AlignmentError", "BagError", "BagNotFoundError", "BagReport", "CorruptBagError", "Episode",
    "EpisodeArrays", "EpisodeBagWriter", "LabelError", "MissingTopicError", "NoEpisodeError",
    "NonFiniteValueError", "ReadReport", "ReadResult",
    "ReaderSpec", "ReaderSpecError", "TopicTypeError", "UnknownTypeError", "VectorLengthError",
    "VectorSource", "load_arrays", "read_episodes", "write_episodes",
]
