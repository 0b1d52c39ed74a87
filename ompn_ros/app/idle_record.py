"""The idle speed a checkpoint's training read used, recorded beside it.

``split: idle`` judges a step still when its speed is below ``idle_speed``, which the reader derives
from each bag's noise floor with ``auto`` (:mod:`ompn_ros.data.cuts.idle`) and keeps in the read's facts
(:class:`ompn_ros.data.reader.BagFacts`, which the cache keeps as data beside the summary text).
``ompn_train`` writes the value its read used into ``best/`` and ``last/`` as ``idle_speed.json`` (the
median over the bags read with the idle rule, at full precision, and what speed it is a
threshold of: a JointState's joint speed or every element's change), so
``ompn_node`` with ``idle_speed: auto`` ends episodes at the threshold the model was trained with
(:mod:`ompn_ros.nodes.ompn_node_idle`).  A read without the idle rule records nothing.
"""

from __future__ import annotations

import json
import statistics
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.reader import BagFacts
from ompn_ros.model.checkpoint_json import read_checkpoint_json
from ompn_ros.model.errors import CheckpointError

RECORD_FILE = "idle_speed.json"
FORMAT = "ompn_ros.idle_speed"


@dataclass(frozen=True)
class IdleRecord:
    """The threshold (``speed``), what speed it is a threshold of (``on``:
    :meth:`ompn_ros.data.cuts.idle.SpeedElements.describe`) and where it came from (``source``: one line)."""

    speed: float
    on: str
    source: str


def read_idle_speed(facts: Sequence[BagFacts]) -> IdleRecord | None:
    """The idle speed of a training read, from its facts (:meth:`ompn_ros.data.reader.ReadReport.facts`,
    as the cache keeps them): the median of the bags' thresholds, at full precision; ``None`` when no
    bag was read with the idle rule."""
    found = [(bag.idle_speed, bag.idle_on) for bag in facts if bag.idle_speed is not None]
    if not found:
        return None
    speed = float(statistics.median(value for value, _ in found))
    on = Counter(where for _, where in found).most_common(1)[0][0]
    source = f"the median of {len(found)} bags" if len(found) > 1 else "one bag"
    return IdleRecord(speed, on, f"{source}, on {on}" if on else source)


def record_idle_speed(checkpoint_dir: Path, record: IdleRecord) -> None:
    """Write ``checkpoint_dir/idle_speed.json``."""
    doc = {"format": FORMAT, "version": 1, "idle_speed": record.speed, "on": record.on,
           "source": record.source}
    atomic_write_text(checkpoint_dir / RECORD_FILE, json.dumps(doc, indent=1) + "\n")


def trained_idle_speed(checkpoint_dir: str | Path) -> IdleRecord | None:
    """The record beside the checkpoint, or ``None`` without one.

    Raises:
        CheckpointError: the record is not this format (one line naming the file).
    """
    path = Path(checkpoint_dir) / RECORD_FILE
    if not path.exists() and not path.is_symlink():
        return None
    doc = read_checkpoint_json(path, CheckpointError)
    speed = doc.get("idle_speed") if isinstance(doc, dict) else None
    on = doc.get("on") if isinstance(doc, dict) else None
    if (not isinstance(doc, dict) or doc.get("format") != FORMAT or isinstance(speed, bool)
            or not isinstance(speed, int | float) or not speed >= 0 or not isinstance(on, str)):
        raise CheckpointError(f"{path}: expected format {FORMAT!r} with an idle_speed >= 0 and what it is a "
                              "speed of ('on'); delete it to derive the speed live")
    return IdleRecord(float(speed), on, str(doc.get("source", "")))


__all__ = ["RECORD_FILE", "IdleRecord", "read_idle_speed", "record_idle_speed", "trained_idle_speed"]
