"""The episode cache: bags or a LeRobot dataset -> contiguous arrays on disk, memory-mapped for training.

Import it as ``ompn_ros.data.cache``; its modules are its own business:

* :mod:`.load`: :func:`load_arrays`, the way in for bags (one entry, per-bag entries, or no cache).
* :mod:`.dataset`: :func:`load_dataset_arrays`, the way in for a LeRobot dataset.
* :mod:`.arrays`: :class:`EpisodeArrays`, what both hand to training (episodes as views of the arrays).
* :mod:`.key`: an entry's identity, a BLAKE2b hash of the bytes it is read from: the bags (or frame
  files), the reader spec and the ``.msg`` files of its ``types:``; an edit always misses.
* :mod:`.build`, :mod:`.per_bag`: one entry for all the bags, or one per bag built in parallel.
* :mod:`.entry`: the entry on disk, a directory of ``.npy`` files and ``index.json`` (format
  :data:`CACHE_FORMAT`, the key, a checksum of each file, checked when opened: a damaged, edited or
  misplaced entry is rebuilt with a note in the read report), written whole or not at all.
* :mod:`.npy`: appending rows to a ``.npy`` file whose row count is known at the end.

An entry lives under ``cache_dir`` (default ``$OMPN_CACHE_DIR`` or ``~/.cache/ompn_ros``) and is
opened with ``np.load(mmap_mode='r')``: training reads from the page cache, so a dataset larger than
the process's memory can be trained on.  Nothing is pickled.
"""

from .arrays import EpisodeArrays
from .build import default_cache_dir
from .dataset import load_dataset_arrays
from .entry import CACHE_FORMAT, INDEX, EntryWriter, file_digest
from .key import content_key, dataset_key
from .load import load_arrays
from .npy import NpyAppender

__all__ = [
    "CACHE_FORMAT",
    "INDEX",
    "EntryWriter",
    "EpisodeArrays",
    "NpyAppender",
    "content_key",
    "dataset_key",
    "default_cache_dir",
    "file_digest",
    "load_arrays",
    "load_dataset_arrays",
]
