"""The outputs of a whole batch run, rebuilt from the bags' records (``batch_bags.py``).

* ``segments.csv`` (and ``segments.parquet`` when ``pyarrow`` is installed): one row per online
  segment, :data:`COLUMNS`: the bag, its episode, first and last step and their observation stamps
  (ns; empty when the bag's observations carry none), the ordinal of the subtask that ended and its
  sketch id when the episode has a sketch, the detector's score at the last step and its mode;
* ``summary.json``: bags read, segmented, skipped as complete, refused with their one-line reason,
  episodes, steps, bytes and seconds of the bags segmented in this run;
* ``metrics.json``: when every segmented episode has labels, the online detector's F1 at tolerance 0
  and 1 (mean over episodes) and alignment (over steps), as ``detect/tune.score_predictions``.

Every file is written to a temporary sibling and renamed into place.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ompn_ros.atomic import atomic_write

COLUMNS = ("bag", "episode", "task", "start_step", "end_step", "start_stamp_ns", "end_stamp_ns", "subtask",
           "subtask_id", "score", "detector")
TABLE = "segments.csv"
SUMMARY = "summary.json"
METRICS = "metrics.json"


def _write_atomic(path: Path, data: bytes) -> None:
    atomic_write(path, lambda handle: handle.write(data))


def table_rows(docs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The segment rows of every segmented bag, in bag order."""
    return [{"bag": doc["bag"], **row} for doc in docs if doc.get("status") == "segmented"
            for row in doc.get("rows", [])]


def write_table(out: Path, rows: Sequence[dict[str, Any]]) -> list[Path]:
    """``segments.csv`` (and ``segments.parquet`` with pyarrow) in ``out``; returns the files."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: ("" if row.get(k) is None else row[k]) for k in COLUMNS} for row in rows)
    _write_atomic(out / TABLE, text.getvalue().encode())
    written = [out / TABLE]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pylist([{k: row.get(k) for k in COLUMNS} for row in rows]), sink)
    _write_atomic(out / "segments.parquet", sink.getvalue().to_pybytes())
    return [*written, out / "segments.parquet"]


def batch_metrics(docs: Sequence[dict[str, Any]]) -> dict[str, float] | None:
    """The online detector's scores over every segmented episode; None unless all have labels."""
    done = [doc for doc in docs if doc.get("status") == "segmented"]
    if not done or any(doc.get("scores") is None for doc in done):
        return None
    merged: dict[str, list[float]] = {}
    for doc in done:
        for key, values in doc["scores"].items():
            merged.setdefault(key, []).extend(values)
    steps = sum(merged["steps"])
    return {"episodes": len(merged["f1_tol1"]),
            "f1_tol0": sum(merged["f1_tol0"]) / len(merged["f1_tol0"]),
            "f1_tol1": sum(merged["f1_tol1"]) / len(merged["f1_tol1"]),
            "align": sum(merged["align"]) / steps, "align_strict": sum(merged["align_strict"]) / steps}


def summarize(docs: Sequence[dict[str, Any]], seconds: float) -> dict[str, Any]:
    """What the run did: counts over all bags, and the throughput of the bags segmented now."""
    now = [doc for doc in docs if doc.get("status") == "segmented" and not doc.get("skipped")]
    episodes = sum(doc.get("episodes", 0) for doc in now)
    size = sum(doc.get("bytes", 0) for doc in now)
    return {
        "bags": len(docs), "read": sum(bool(doc.get("read")) for doc in docs),
        "segmented": sum(doc.get("status") == "segmented" for doc in docs),
        "skipped": sum(bool(doc.get("skipped")) for doc in docs),
        "refused": [{"bag": doc["bag"], "reason": doc.get("reason", "")} for doc in docs
                    if doc.get("status") != "segmented"],
        "segments": len(table_rows(docs)),
        "this_run": {"bags": len(now), "episodes": episodes, "steps": sum(doc.get("steps", 0) for doc in now),
                     "bytes": size, "seconds": seconds,
                     "episodes_per_s": episodes / seconds if seconds > 0 else None,
                     "mb_per_s": size / 1e6 / seconds if seconds > 0 else None},
    }


def write_outputs(out: Path, docs: Sequence[dict[str, Any]], seconds: float) -> dict[str, Any]:
    """Write the table, ``summary.json`` and (with labels) ``metrics.json``; returns the summary."""
    summary = summarize(docs, seconds)
    summary["table"] = [str(p) for p in write_table(out, table_rows(docs))]
    metrics = batch_metrics(docs)
    if metrics is not None:
        summary["metrics"] = metrics
        _write_atomic(out / METRICS, (json.dumps(metrics, indent=1) + "\n").encode())
    write_summary(out, summary)
    return summary


def write_summary(out: Path, summary: dict[str, Any]) -> None:
    """``summary.json`` in ``out`` (atomically)."""
    _write_atomic(out / SUMMARY, (json.dumps(summary, indent=1) + "\n").encode())


def status_line(doc: dict[str, Any], done: int, total: int, elapsed: float | None = None) -> str:
    """The progress line of one finished bag (with the time left at this pace when ``elapsed`` is given)."""
    eta = f" eta {elapsed / done * (total - done):.0f} s" if elapsed is not None and done else ""
    head = f"[{done}/{total} {100 * done // max(total, 1)}%{eta}] {doc['key']}: "
    if doc.get("skipped"):
        return head + "complete, skipped"
    if doc.get("status") == "segmented":
        return head + (f"segmented, {doc['episodes']} episodes, {len(doc['rows'])} segments, "
                       f"{doc.get('seconds', 0.0):.1f} s")
    return head + f"refused: {doc.get('reason', '')}"


def summary_line(summary: dict[str, Any]) -> str:
    """One line: how many bags were read, segmented, skipped and refused."""
    refused = summary["refused"]
    text = (f"{summary['bags']} bags: {summary['read']} read, {summary['segmented']} segmented "
            f"({summary['skipped']} already complete), {len(refused)} refused; "
            f"{summary['segments']} segments")
    return text + "".join(f"\n  refused {item['bag']}: {item['reason']}" for item in refused)


__all__ = ["COLUMNS", "batch_metrics", "status_line", "summarize", "summary_line", "table_rows",
           "write_outputs", "write_summary", "write_table"]
