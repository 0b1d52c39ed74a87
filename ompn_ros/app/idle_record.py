"""The idle speed a checkpoint's training read used, recorded beside it.

``split: idle`` judges a step still when its speed is below ``idle_speed``, which the reader derives
from each bag's noise floor with ``auto`` (:mod:`ompn_ros.data.idle`) and names in the read summary.
``ompn_train`` writes the value its read used into ``best/`` and ``last/`` as ``idle_speed.json`` (the
median over the bags read with the idle rule, and the observation fields it was measured on), so
``ompn_node`` with ``idle_speed: auto`` ends episodes at the threshold the model was trained with
(:mod:`ompn_ros.nodes.ompn_node_idle`).  A read without the idle rule records nothing.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ompn_ros.atomic import atomic_write_text
from ompn_ros.data.idle import SpeedElements
from ompn_ros.model.checkpoint_json import read_checkpoint_json
from ompn_ros.model.errors import CheckpointError

RECORD_FILE = "idle_speed.json"
FORMAT = "ompn_ros.idle_speed"


@dataclass(frozen=True)
class IdleRecord:
    """The threshold (``speed``), the JointState fields it was measured on (``None``: every element of
    the observation) and where it came from (``source``: one line)."""

    speed: float
    fields: tuple[str, ...] | None
    source: str

    def describe(self) -> str:
        return SpeedElements(self.fields).describe()


def read_idle_speed(report: Mapping[str, Any]) -> IdleRecord | None:
    """The idle speed of a read report (``ReadReport.to_dict()``): the median of the bags' thresholds,
    ``None`` when no bag was read with the idle rule."""
    bags = [b for b in report.get("bags", []) if b.get("idle_speed") is not None]
    if not bags:
        return None
    speed = float(statistics.median(float(b["idle_speed"]) for b in bags))
    fields = bags[0].get("idle_fields")
    where = f"median of {len(bags)} bags" if len(bags) > 1 else bags[0].get("idle_rule", "one bag")
    return IdleRecord(speed, None if fields is None else tuple(fields), where)


def record_idle_speed(checkpoint_dir: Path, record: IdleRecord) -> None:
    """Write ``checkpoint_dir/idle_speed.json``."""
    doc = {"format": FORMAT, "version": 1, "idle_speed": record.speed,
           "fields": None if record.fields is None else list(record.fields), "source": record.source}
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
    fields = doc.get("fields") if isinstance(doc, dict) else None
    names = fields is None or (isinstance(fields, list) and all(isinstance(f, str) for f in fields))
    if (not isinstance(doc, dict) or doc.get("format") != FORMAT or isinstance(speed, bool)
            or not isinstance(speed, int | float) or not speed >= 0 or not names):
        raise CheckpointError(f"{path}: expected format {FORMAT!r} with an idle_speed >= 0 and the fields it "
                              "was measured on (null or a list of names); delete it to derive the speed live")
    return IdleRecord(float(speed), None if fields is None else tuple(fields), str(doc.get("source", "")))


__all__ = ["RECORD_FILE", "IdleRecord", "read_idle_speed", "record_idle_speed", "trained_idle_speed"]
