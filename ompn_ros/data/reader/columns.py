"""Decode while reading: the step topic's messages become rows of one preallocated array.

Keeping every raw message and decoding afterwards holds the bag twice (raw CDR, then the decoded
copy).  While the bag is read, each message of the step topic is decoded at once and its bytes
dropped:

* :class:`Float32Column`: a ``std_msgs/Float32MultiArray`` observation topic, or action topic of its
  own (about 1 µs a message more than in bulk, for less than half the reader's peak memory: the
  raw messages are never held beside their rows, docs/design.md#any-message-type).  A message whose CDR
  has the first message's length and layout prefix (always the case for one topic of a recorder) is
  copied into the next row.  Any other message (another length or layout, undecodable CDR, a first
  message of another size than the spec's) ends the streaming: the rows so far are turned back
  into their exact raw bytes (the prefix followed by the row's bytes) and the topic is kept raw, so
  the batch decoder reports the same error on the same message as without streaming.  A message of
  another type (a topic recorded under two types) ends it the same way (``TopicData.type_of``).
* :class:`AssemblySink`: ``ReaderSpec.assemble``; the messages of the spec's topics are fed to the
  live :class:`~ompn_ros.data.obs.ObservationAssembler` in record order (the order
  :func:`~ompn_ros.data.obs.assemble_stream` sees them in) and each step's row written in place.

Memory: ``capacity · D`` float32 (the topic's message count from the bag's index, grown by half when
the index undercounts), no raw bytes.  Time: O(bytes) per message, as the batch decoder.
"""

from __future__ import annotations

import numpy as np

from ompn_ros import layout

from .. import messages as m
from ..errors import ObservationSpecError
from ..obs import Drop, ObservationAssembler, ObservationSpec


def _grown(values: np.ndarray, rows: int) -> np.ndarray:
    """``values`` with room for at least ``rows`` rows (by half again, at least 16 more)."""
    if rows <= len(values):
        return values
    out = np.zeros((max(rows, len(values) * 3 // 2 + 16), *values.shape[1:]), dtype=values.dtype)
    out[: len(values)] = values
    return out


class Float32Column:
    """Rows of the ``Float32MultiArray`` messages of one topic, decoded as they are read."""

    def __init__(self, expected_dim: int | None, capacity: int) -> None:
        self.expected_dim = expected_dim
        self.capacity = max(int(capacity), 1)
        self.n = 0
        self._prefix = b""
        self._size = 0
        self._values: np.ndarray | None = None

    def add(self, raw: bytes | memoryview) -> bool:
        """Decode ``raw`` into the next row; ``False``: it does not fit (the caller keeps raw bytes)."""
        if self._values is None:
            return self._first(raw)
        if len(raw) != self._size or raw[: len(self._prefix)] != self._prefix:
            return False
        if self.n == len(self._values):
            self._values = _grown(self._values, self.n + 1)
        self._values[self.n] = np.frombuffer(raw, dtype="<f4", offset=len(self._prefix))
        self.n += 1
        return True

    def _first(self, raw: bytes | memoryview) -> bool:
        if not m.little_endian(raw):
            return False
        try:
            start, dim = m.multiarray_data(raw, 4, layout.FLOAT32_ARRAY)
        except m.CdrError:
            return False
        if ((self.expected_dim is not None and dim != self.expected_dim) or start % 4
                or start + 4 * dim != len(raw)):  # trailing bytes: the rows could not give them back
            return False
        self._prefix, self._size = bytes(raw[:start]), len(raw)
        self._values = np.empty((self.capacity, dim), dtype=np.float32)
        self._values[0] = np.frombuffer(raw, dtype="<f4", offset=start)
        self.n = 1
        return True

    @property
    def values(self) -> np.ndarray:
        """float32 ``[n, D]``: a view of the rows read so far."""
        if self._values is None:
            return np.zeros((0, self.expected_dim or 0), dtype=np.float32)
        return self._values[: self.n]

    def take(self, index: np.ndarray) -> None:
        """Keep rows ``index`` in that order (a reorder or a cut); a prefix keeps the buffer."""
        index = np.asarray(index, dtype=np.int64)
        if self._values is None:
            return
        if np.array_equal(index, np.arange(len(index))):
            self.n = len(index)
            return
        self._values = self._values[: self.n][index]
        self.n = len(index)

    def to_raws(self) -> list[bytes]:
        """The exact CDR bytes of every row read so far (the prefix, then the row's elements)."""
        return [self._prefix + row.astype("<f4").tobytes() for row in self.values]


class AssemblySink:
    """The assembler's step rows of ``spec`` (bag topic names), written in place as steps arrive.

    Rows the rule dropped stay zero with ``kept`` False, as in :func:`~ompn_ros.data.obs.assemble_stream`.
    """

    def __init__(self, spec: ObservationSpec, capacity: int) -> None:
        self.spec = spec
        self.asm = ObservationAssembler(spec)
        self.capacity = max(int(capacity), 1)
        self.n = 0
        self.kept: list[bool] = []
        self.step_stamps: list[int] = []
        self._values: np.ndarray | None = None
        self._types = spec.topics
        self._declared: set[str] = set()
        self.unfit = False

    def add(self, topic: str, stamp: int, raw: bytes | memoryview, msgtype: str | None = None) -> None:
        """Feed one message of a topic of the spec (record order); ``msgtype``: its own type (a topic
        recorded under several types is read per connection).  A type that cannot give the spec's
        fields sets ``unfit`` (the bag's read then refuses the spec in one line: ``TypeChecks``)."""
        if msgtype is not None and msgtype != self._types[topic] and msgtype not in self._declared:
            try:
                self.asm.for_type(topic, msgtype)
            except ObservationSpecError:
                self.unfit = True
            self._declared.add(msgtype)
        if self.unfit:
            return
        if topic != self.spec.step_topic:
            self.asm.offer(topic, stamp, raw, msgtype)
            return
        result = self.asm.step(stamp, raw, msgtype)
        self.step_stamps.append(int(stamp))
        self.kept.append(not isinstance(result, Drop))
        if not isinstance(result, Drop):
            if self._values is None:
                self._values = np.zeros((max(self.capacity, self.n + 1), len(result)), dtype=np.float32)
            self._values = _grown(self._values, self.n + 1)
            self._values[self.n] = result
        self.n += 1

    @property
    def values(self) -> np.ndarray:
        """float32 ``[steps, D]`` (zeros on dropped steps): a view."""
        if self._values is None:
            return np.zeros((self.n, self.asm.dim or 0), dtype=np.float32)
        if len(self._values) < self.n:  # steps dropped after the last kept one
            self._values = _grown(self._values, self.n)
        return self._values[: self.n]
