"""Read rosbag2 files (mcap or sqlite3) into Episodes.

Inputs: a storage file (``.mcap``/``.db3``), a bag directory (with ``metadata.yaml``), a directory
holding bag directories (searched recursively), a glob, or a sequence of those.  Bags are read in
sorted path order and their episodes concatenated.

Alignment rule
--------------
* The **observation topic is the step clock**: its messages, sorted by stamp, are the steps.
* A message on another per-step topic (action, subtask, joint states) **attaches to the latest
  observation stamped at or before it**, if it is at most ``tolerance`` seconds after that
  observation.  Messages attaching to no observation are counted as *unattached* per topic.
* An observation lacking a partner on a per-step topic is counted as *missing* for that topic, and
  a second partner for the same observation is counted as a *duplicate* (the first one is kept).
  Nothing is ever shifted to a neighbouring step.  With ``strict`` (our presets) a missing or
  duplicate partner raises :class:`AlignmentError`; otherwise a step without an action is dropped
  (observation included), a missing subtask becomes ``-1`` and a missing joint state ``NaN``, and
  everything is counted in the :class:`ReadReport`.
* In bags written by ``ompn_collect`` alignment is exact: partners follow their observation by
  ``k * TOPIC_OFFSET_NS``.  Live sims publish ``subtask_t``/``action_t`` one tick after
  ``observation_t`` (just before ``observation_{t+1}``; in policy mode after the policy's reply),
  so the default ``tolerance`` is a generous 5 s: the episode markers and the "latest observation
  at or before" rule do the alignment, the tolerance only rejects strays.
* Stamps are the bag's log stamps (``stamp: log``); ``stamp: header`` uses ``header.stamp`` of
  JointState topics instead.  A clock that steps within the bag (an NTP correction) never reshapes
  a demonstration: the recording PC's clock is read around in recording order, a header clock read
  with ``stamp: header`` is refused naming ``stamp: log`` (:mod:`.steps`).
* Without ``joint_names`` the first JointState message's names fix the joint order (the first
  bag's, across the bags of a read); other orders are reordered by name, other joints refused.

Episodes
--------
``split`` (:class:`ReaderSpec`) chooses how episodes are delimited.  Episode start/end markers
(``DiagnosticArray`` on the episode topic, keys in ``layout.py``) delimit them when present
(``auto``) or required (``markers``); observations outside a start/end pair are not used (a
recording started or stopped mid-episode) and an unfinished episode is dropped and reported.
Otherwise (``gaps``) episodes are split where consecutive observations are more than ``time_gap``
seconds apart, or (``topic``) at every message of ``split_topic``.

Within an episode the last observation without an action becomes row ``T`` (the final observation
of the step contract).  If every observation has an action (the observation after the last command
was not recorded), ``final_observation`` decides: duplicate the last observation (``s_{T+1} = s_T``,
default), drop the last action step or refuse; the report lists the episodes concerned.  The
sketch is the sketch message of the episode (between its start marker and first observation, or,
without markers, the latest one before the first observation), else the start marker's ``sketch``
key.

Labels
------
``labels`` says what the subtask topic holds: per-step ordinals (ours), per-step skill ids (another
lab's; ordinals follow from changes, the ids stay in ``Episode.extras['subtask_id']``), boundary
events, or nothing.  ``Episode.subtask`` always holds ordinals.

Verification
------------
sqlite3 files pass ``PRAGMA quick_check`` before reading; mcap chunks are checked against their
CRC when the writer set one (the report notes chunks without); decoded observations and actions
must be finite.  What fails is raised (``on_error='raise'``) naming the file or the bag, topic and
message, or its episode is dropped and the reason recorded in the :class:`ReadReport`.

Errors
------
``on_error='raise'`` raises the first :class:`BagError`, including :class:`NoEpisodeError` for a
bag that yields no complete episode.  ``on_error='skip_tail'`` keeps the episodes completed before
a corrupt tail (unreadable storage, undecodable or wrong-length message; the data from the first
bad message on is discarded), drops episodes holding non-finite values, and reports what was
dropped.  A wrong message type, a missing required topic, labels that do not fit their kind and
(with ``strict``) a missing or duplicate partner always raise: they are not corruption.

Modules
-------
``spec`` (what to read), ``paths`` (where the bags are), ``raw`` / ``salvage`` (undecoded
messages), ``plan`` / ``columns`` (the step and action topics decoded while the bag is read, bytes dropped),
``context`` (topic resolution and type checks), ``decode`` / ``joints`` / ``vectors``
(arrays, corrupt tail), ``observe`` (observations from several topics, ``ReaderSpec.assemble``),
``align`` (partners, episode windows), ``assemble`` (episodes), ``report`` (what was used), ``read``
(entry points), ``steps`` (clocks that step).
"""

from __future__ import annotations

from .paths import STORAGE_SUFFIXES, BagListing, list_bag_paths, resolve_bag_paths, storage_files
from .read import iter_raw_messages, read_bag, read_episodes
from .report import BagFacts, BagReport, ReadReport, ReadResult, final_row_guessed
from .spec import (
    ACTION_TYPES,
    VECTOR_TYPES,
    FinalObservation,
    LabelKind,
    OnError,
    ReaderSpec,
    Split,
    VectorSource,
)

__all__ = [
    "ACTION_TYPES",
    "STORAGE_SUFFIXES",
    "VECTOR_TYPES",
    "BagFacts",
    "BagListing",
    "BagReport",
    "FinalObservation",
    "LabelKind",
    "OnError",
    "ReadReport",
    "ReadResult",
    "ReaderSpec",
    "Split",
    "VectorSource",
    "final_row_guessed",
    "iter_raw_messages",
    "list_bag_paths",
    "read_bag",
    "read_episodes",
    "resolve_bag_paths",
    "storage_files",
]
