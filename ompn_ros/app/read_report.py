"""What the bag reader kept and dropped, stored beside a training run or a replay.

``ompn_train`` and ``ompn_segment --bag`` write ``read_report.json`` (their report document) and
``read_report.txt`` (its ``summary``: the reader's human-readable report) into their output folder.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ompn_ros.atomic import atomic_write_text


def write_read_report(out: Path, doc: dict[str, Any]) -> None:
    """Write ``out/read_report.json`` (``doc``) and ``out/read_report.txt`` (``doc['summary']``), each
    whole or absent; under ``torchrun`` rank 0 alone writes (it checked that ``out`` was empty)."""
    if int(os.environ.get("RANK", "0")) != 0:
        return
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "read_report.json", json.dumps(doc, indent=1) + "\n")
    atomic_write_text(out / "read_report.txt", str(doc.get("summary", "")) + "\n")
