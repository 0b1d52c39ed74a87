"""The messages of ``ompn_interfaces`` without ROS: field values, CDR encoders and the typestore entry.

``ompn_node`` publishes ``ompn_interfaces/msg/SubtaskBoundary`` on ``~/boundary`` and
``ompn_interfaces/msg/SubtaskState`` on ``~/state``; the sims publish
``ompn_interfaces/msg/EpisodeMarker`` on ``episode_marker`` (:func:`encode_typed_marker`, read back by
:func:`parse_typed_marker` into the key/value form of the deprecated ``DiagnosticArray`` marker, so one
code path reads both); ``ompn_segment --annotate`` writes the same types into annotated bags (the
fields: ``ompn_interfaces/msg/*.msg``). Both sides build the CDR here, so a consumer reads live and
recorded events alike. The encoders write the little-endian CDR layout of the ``.msg`` files directly
(the boundary is the node's latency-critical output); rclpy and the ``rosbags`` typestore decode their
bytes to the fields they were built from (tested). Decoding here goes through the ``rosbags`` typestore,
with the definitions read from the package's ``.msg`` files (:func:`register_interfaces`).
"""

from __future__ import annotations

import os
import struct
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np

from .cdr import (
    CDR_LE_HEADER,
    STAMP,
    U32,
    deserialize,
    msg_class,
    serialize,
    split_stamp,
    stamp_to_ns,
    typestore,
)

INTERFACES_PACKAGE: Final = "ompn_interfaces"
SUBTASK_BOUNDARY: Final = f"{INTERFACES_PACKAGE}/msg/SubtaskBoundary"
SUBTASK_STATE: Final = f"{INTERFACES_PACKAGE}/msg/SubtaskState"
EPISODE_MARKER: Final = f"{INTERFACES_PACKAGE}/msg/EpisodeMarker"
INTERFACE_MESSAGES: Final = (SUBTASK_BOUNDARY, SUBTASK_STATE, EPISODE_MARKER)
MARKER_KINDS: Final = ("start", "end")
"""``EpisodeMarker.kind`` 0 and 1 by name (``layout.EPISODE_START``, ``layout.EPISODE_END``)."""
SUBTASK_ID_UNKNOWN: Final = -1
SUBTASK_END: Final = 0
"""``SubtaskBoundary.kind``: the message reports the end of a subtask."""
EPISODE_END: Final = 1
"""``SubtaskBoundary.kind``: the episode ended and no subtask with it (docs/design.md#episode-end)."""

_BOUNDARY_MIDDLE = struct.Struct("<IIIifB3x")  # episode, step, subtask, subtask_id, score, level, pad
_BOUNDARY_TAIL = struct.Struct("<IiIBB")  # decided_step, decided_stamp, final, kind
_STATE_COUNTS = struct.Struct("<III")  # episode, step, len(pi)
_ZEROS = (b"", b"\0", b"\0\0", b"\0\0\0")


class DetectedBoundary(Protocol):
    """What a boundary message takes from a detector's event (``ompn_ros.detect.online.BoundaryEvent``):
    the boundary's step, the step it was decided at, the subtask it ends, its score and memory level,
    the step's stamp, whether it closes the episode and whether it is the episode end (no subtask)."""

    @property
    def step(self) -> int: ...
    @property
    def detected_at(self) -> int: ...
    @property
    def subtask(self) -> int: ...
    @property
    def score(self) -> float: ...
    @property
    def level(self) -> int: ...
    @property
    def stamp_ns(self) -> int: ...
    @property
    def final(self) -> bool: ...
    @property
    def episode_end(self) -> bool: ...


@dataclass(frozen=True)
class SubtaskBoundary:
    """The fields of one ``SubtaskBoundary`` (see ``ompn_interfaces/msg/SubtaskBoundary.msg``)."""

    stamp_ns: int
    frame_id: str
    node: str
    episode: int
    step: int
    subtask: int
    subtask_id: int
    score: float
    memory_level: int
    decided_step: int
    decided_stamp_ns: int
    final: bool
    kind: int = SUBTASK_END

    @classmethod
    def from_event(cls, event: DetectedBoundary, *, node: str, episode: int, frame_id: str = "",
                   sketch: np.ndarray | None = None, decided_stamp_ns: int = 0,
                   stamp_ns: int | None = None) -> SubtaskBoundary:
        """The message of ``event``: ``stamp_ns`` defaults to the event's, ``subtask_id`` is
        ``sketch[event.subtask]`` when the sketch has that entry (unknown for the episode end)."""
        end = bool(event.episode_end)
        known = sketch is not None and 0 <= event.subtask < len(sketch) and not end
        return cls(
            stamp_ns=event.stamp_ns if stamp_ns is None else stamp_ns, frame_id=frame_id, node=node,
            episode=episode, step=event.step, subtask=event.subtask,
            subtask_id=int(sketch[event.subtask]) if known and sketch is not None else SUBTASK_ID_UNKNOWN,
            score=event.score, memory_level=min(max(event.level, 0), 255), decided_step=event.detected_at,
            decided_stamp_ns=decided_stamp_ns, final=event.final, kind=EPISODE_END if end else SUBTASK_END,
        )  # fmt: skip


def _string(text: str, size: int) -> tuple[bytes, int]:
    """CDR of a string starting at body offset ``size`` (already 4-aligned); the new offset."""
    data = text.encode() + b"\0"
    end = size + 4 + len(data)
    pad = -end % 4
    return U32.pack(len(data)) + data + _ZEROS[pad], end + pad


@lru_cache(maxsize=64)
def _boundary_strings(frame_id: str, node: str) -> bytes:
    """``frame_id`` and ``node`` after the 8 stamp bytes, padded to the next 4-byte field."""
    first, size = _string(frame_id, 8)
    second, _ = _string(node, size)
    return first + second


def encode_subtask_boundary(msg: SubtaskBoundary) -> bytes:
    """CDR of ``msg``; raises :class:`~.cdr.StampRangeError` for a stamp out of
    range.  O(1) beyond the two strings (encoded once per frame id and node)."""
    return b"".join((
        CDR_LE_HEADER, STAMP.pack(*split_stamp(msg.stamp_ns)), _boundary_strings(msg.frame_id, msg.node),
        _BOUNDARY_MIDDLE.pack(msg.episode, msg.step, msg.subtask, msg.subtask_id, msg.score,
                              msg.memory_level),
        _BOUNDARY_TAIL.pack(msg.decided_step, *split_stamp(msg.decided_stamp_ns), msg.final, msg.kind),
    ))  # fmt: skip


def encode_subtask_state(stamp_ns: int, frame_id: str, episode: int, step: int, pi: np.ndarray,
                         expected_position: float, pi_end: float) -> bytes:
    """CDR of a ``SubtaskState`` (``pi``: the slot probabilities, lowest slot first)."""
    head, _ = _string(frame_id, 8)
    values = np.ascontiguousarray(pi, dtype="<f4").reshape(-1)
    return b"".join((
        CDR_LE_HEADER, STAMP.pack(*split_stamp(stamp_ns)), head,
        _STATE_COUNTS.pack(episode, step, values.size), values.tobytes(),
        struct.pack("<ff", expected_position, pi_end),
    ))  # fmt: skip


# --- episode markers ------------------------------------------------------------------------------
def encode_typed_marker(kind: str, stamp_ns: int, values: Mapping[str, object]) -> bytes:
    """CDR of an ``EpisodeMarker``: ``kind`` ``'start'`` or ``'end'``, ``values`` the marker's keys
    (``layout.KEY_*``: episode, task, seed, sketch at the start, steps and success at the end; missing
    ones take the message's 'not known' values)."""
    register_interfaces()
    sketch = np.asarray(values.get("sketch", []), dtype=np.int32).reshape(-1)
    msg = msg_class(EPISODE_MARKER)(
        header=msg_class("std_msgs/msg/Header")(
            stamp=msg_class("builtin_interfaces/msg/Time")(*split_stamp(stamp_ns)), frame_id=""),
        kind=MARKER_KINDS.index(kind), episode=int(values.get("episode", 0)),  # type: ignore[call-overload]
        task=str(values.get("task", "")), seed=int(values.get("seed", -1)),  # type: ignore[call-overload]
        sketch=sketch, steps=int(values.get("steps", 0)),  # type: ignore[call-overload]
        success=bool(values.get("success", False)),
    )  # fmt: skip
    return serialize(msg)


def parse_typed_marker(raw: bytes | memoryview) -> tuple[str, dict[str, str]]:
    """An ``EpisodeMarker`` CDR as ``(kind, values)``: the key/value strings the ``DiagnosticArray``
    marker carries (the start's episode, task, seed, sketch; the end's episode, task, seed, steps,
    success).  :class:`~.cdr.CdrError` on bytes that are not one, ``ValueError`` on an unknown kind."""
    register_interfaces()
    msg = deserialize(raw, EPISODE_MARKER)
    if msg.kind >= len(MARKER_KINDS):
        raise ValueError(f"EpisodeMarker kind {msg.kind} is neither START (0) nor END (1)")
    kind = MARKER_KINDS[msg.kind]
    values = {"episode": str(msg.episode), "task": str(msg.task), "seed": str(msg.seed)}
    if kind == "start":
        values["sketch"] = ",".join(str(int(v)) for v in msg.sketch)
    else:
        values.update(steps=str(msg.steps), success="true" if msg.success else "false")
    return kind, values


# --- the typestore entry --------------------------------------------------------------------------
def _msg_dirs() -> list[Path]:
    """Where the ``.msg`` files may be: this repository's ``ompn_interfaces/msg``, then
    ``share/ompn_interfaces/msg`` under ``sys.prefix`` and every ``AMENT_PREFIX_PATH`` entry."""
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    return [Path(__file__).resolve().parents[3] / INTERFACES_PACKAGE / "msg",
            *(Path(p) / "share" / INTERFACES_PACKAGE / "msg" for p in prefixes if p)]


def register_interfaces(store: Any | None = None) -> Any:
    """Register the ``ompn_interfaces`` messages with ``store`` (default: the shared Jazzy typestore
    of :func:`~.cdr.typestore`) once; returns the store.  ``FileNotFoundError``
    names the places searched when no ``.msg`` file is found."""
    from rosbags.typesys import get_types_from_msg

    store = typestore() if store is None else store
    if all(name in store.types for name in INTERFACE_MESSAGES):
        return store
    for folder in _msg_dirs():
        if all((folder / f"{name.rsplit('/', 1)[1]}.msg").is_file() for name in INTERFACE_MESSAGES):
            types: dict[str, Any] = {}
            for name in INTERFACE_MESSAGES:
                text = (folder / f"{name.rsplit('/', 1)[1]}.msg").read_text()
                types.update(get_types_from_msg(text, name))
            store.register(types)
            return store
    raise FileNotFoundError(f"the {INTERFACES_PACKAGE} message definitions are in none of "
                            f"{[str(d) for d in _msg_dirs()]}; build and install {INTERFACES_PACKAGE} "
                            "(make setup)")


def decode_subtask_boundary(raw: bytes | memoryview) -> SubtaskBoundary:
    """The fields of a ``SubtaskBoundary`` CDR (through the typestore: exact; :class:`~.cdr.CdrError`
    on bytes that are not one)."""
    register_interfaces()
    msg = deserialize(raw, SUBTASK_BOUNDARY)
    return SubtaskBoundary(
        stamp_ns=stamp_to_ns(msg.header.stamp), frame_id=msg.header.frame_id, node=msg.node,
        episode=msg.episode, step=msg.step, subtask=msg.subtask, subtask_id=msg.subtask_id,
        score=float(msg.score), memory_level=msg.memory_level, decided_step=msg.decided_step,
        decided_stamp_ns=stamp_to_ns(msg.decided_stamp), final=bool(msg.final), kind=int(msg.kind),
    )  # fmt: skip
