"""LeRobot v3.0 datasets (local folders) as a source of Episodes, beside the bag reader.

``spec`` (which features are the observation, the action, the labels), ``layout`` (the dataset's
files and ``meta/info.json``), ``read`` (frame files -> :class:`DatasetEpisode`, one file at a time).
Writing subtasks back is ``app/lerobot_write.py``; the formats are in docs/lerobot.md.
"""

from .layout import DatasetLayout, pyarrow_modules
from .read import DatasetEpisode, DatasetFile, DatasetReader
from .spec import DatasetSpec

__all__ = ["DatasetEpisode", "DatasetFile", "DatasetLayout", "DatasetReader", "DatasetSpec",
           "pyarrow_modules"]
