"""Shards: one dataset split over many machines (or array jobs), then merged into one output.

``ompn_segment --bags SOURCE --num-shards N --shard-index I`` runs the work items of ``SOURCE`` whose
shard is ``I``: :func:`shard_of` hashes an item's key (a bag's key is its path below the folder all
bags share, ``batch_bags.py``), so every machine that lists the same source computes the same
assignment, without talking to the others, and an item keeps its shard when others are added.  A
shard writes its items' records where an unsharded run would (``OUT/bags/<key>.json``, so a shard is
resumable and idempotent as a run is: a rerun skips its complete items) and, instead of the run's
table, a *manifest* (``OUT/shards/<I>-of-<N>/manifest.json``: its items with their position in the
whole listing, the settings, whether it finished) beside its own table and summary.  The shards of
a LeRobot dataset's episodes (kind ``episodes``, ``app/lerobot_shards.py``) write the same manifest;
their items are the frame files, each with the path of its record (``record``, below ``OUT``).

``ompn_segment aggregate OUT [OUT ...]`` reads the manifests under the given folders (one shared
folder, or one per machine), checks that they are shards of one run, and writes the table, summary
and metrics of the whole run, rows in the order of the listing (the table of an unsharded run, row
for row); a shard that is missing, did not finish, or lacks records is named.  Outputs that are more
than the table (one annotated dataset from the shards' parts) are merged by :data:`MERGERS`, per
kind of work item; the annotated copies of bags need no merge (one folder per bag).  Kinds whose
output cannot be partial (one annotated dataset) are merged only when every shard is complete
(:data:`PARTIAL`).

Cost: one hash per item; the aggregate reads every record once.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from ompn_ros.app import batch_bags as records
from ompn_ros.app import batch_table
from ompn_ros.app.errors import ReplayError
from ompn_ros.atomic import atomic_write_text

SHARDS = "shards"
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "ompn_ros.batch_shard"
Item = TypeVar("Item")
PARTIAL = frozenset({"bags"})
"""The kinds whose aggregate may hold the shards that finished only (a table of bags); the others
(one annotated dataset) are merged only when every shard is complete, and else nothing is written."""


def check_shard(count: int | None, index: int | None) -> None:
    """Refuse a shard option without its partner or out of range (one line naming the option)."""
    if (count is None) != (index is None):
        raise ReplayError("--num-shards and --shard-index go together (e.g. --num-shards 8 --shard-index 0)")
    if count is not None and index is not None and not (count >= 1 and 0 <= index < count):
        raise ReplayError(f"--shard-index must be in 0..{count - 1} and --num-shards at least 1, "
                          f"got --num-shards {count} --shard-index {index}")


def shard_of(key: str, count: int) -> int:
    """The shard of the work item ``key`` among ``count`` (the first 8 bytes of its SHA-256)."""
    return int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "big") % count


def select(items: Sequence[Item], key: Callable[[Item], str], count: int,
           index: int) -> list[tuple[int, Item]]:
    """``(position in items, item)`` of the items of shard ``index`` of ``count``, in order."""
    return [(position, item) for position, item in enumerate(items) if shard_of(key(item), count) == index]


def shard_dir(out: Path, count: int, index: int) -> Path:
    return out / SHARDS / f"{index}-of-{count}"


def write_manifest(out: Path, count: int, index: int, mine: Sequence[tuple[int, str]], total: int,
                   settings: dict[str, Any], status: str, kind: str = "bags",
                   record: Callable[[str], str] | None = None) -> Path:
    """The manifest of shard ``index``: its items ``(position, key)`` among ``total``, its settings
    and ``status`` ('running', 'complete' or 'interrupted'); written atomically.  ``record``: the path
    of an item's record below ``out`` (none: a bag's, ``OUT/bags/<key>.json``)."""
    path = shard_dir(out, count, index) / MANIFEST
    items = [{"position": p, "key": k, **({"record": record(k)} if record else {})} for p, k in mine]
    doc = {"format": MANIFEST_FORMAT, "kind": kind, "shards": count, "shard": index, "total": total,
           "status": status, "settings": settings, "items": items, "written": time.time()}
    atomic_write_text(path, json.dumps(doc))
    return path


@dataclass
class Aggregate:
    """What :func:`aggregate` found: the records in listing order, the shards complete, missing and
    failed (with the reason), and the settings of a complete shard."""

    docs: list[dict[str, Any]]
    count: int
    kind: str
    complete: list[int] = field(default_factory=list)
    missing: list[int] = field(default_factory=list)
    failed: dict[int, str] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)  # a complete shard's


def _manifests(folders: Sequence[Path]) -> list[tuple[Path, dict[str, Any]]]:
    found = []
    for folder in folders:
        for path in sorted((folder / SHARDS).glob(f"*/{MANIFEST}")):
            try:
                doc = json.loads(path.read_text())
            except (OSError, ValueError) as exc:
                raise ReplayError(f"cannot read the shard manifest {path}: {exc}") from exc
            if isinstance(doc, dict) and doc.get("format") == MANIFEST_FORMAT:
                found.append((folder, doc))
    if not found:
        raise ReplayError(f"no shard manifest (shards/<i>-of-<n>/{MANIFEST}) under "
                          f"{', '.join(map(str, folders))}: run the shards first (ompn_segment --bags or "
                          "--dataset ... --num-shards N --shard-index I)")
    return found


PORTABLE = {"bags": ("detector", "reader", "on_error", "annotate"),
            "episodes": ("detector", "spec", "boundaries", "subtasks", "format")}
"""Per kind, the settings every shard of one run shares (the checkpoint's path and file times, the
dataset's path may differ between machines)."""


def _one_run(found: list[tuple[Path, dict[str, Any]]]) -> tuple[int, str]:
    """The shard count and kind all manifests share (else one line naming the odd one)."""
    def signature(doc: dict[str, Any]) -> tuple[Any, ...]:
        settings = doc.get("settings") or {}
        kind = doc.get("kind", "bags")
        return (doc["shards"], kind, *(json.dumps(settings.get(k)) for k in PORTABLE.get(kind, ())))

    first = signature(found[0][1])
    for folder, doc in found:
        if signature(doc) != first:
            raise ReplayError(f"{folder}: shard {doc['shard']}-of-{doc['shards']} belongs to another run "
                              f"(shard count, kind, detector or reader differ from {found[0][0]}'s)")
    return int(found[0][1]["shards"]), str(found[0][1].get("kind", "bags"))


def aggregate(folders: Sequence[Path]) -> Aggregate:
    """Gather the shards' records under ``folders`` (see the module docstring)."""
    found = _manifests(folders)
    count, kind = _one_run(found)
    result = Aggregate(docs=[], count=count, kind=kind)
    placed: dict[tuple[int, int], dict[str, Any]] = {}
    seen: set[int] = set()
    for folder, doc in sorted(found, key=lambda pair: int(pair[1]["shard"])):
        index = int(doc["shard"])
        if index in seen:
            continue  # the same shard written twice (rerun elsewhere): its records are the same
        seen.add(index)
        lacking = []
        for item in doc["items"]:
            record = _read_item(folder, item)
            if record is None or record.get("settings") != doc["settings"]:
                lacking.append(item["key"])
            else:
                placed[int(item["position"]), index] = record
        if doc["status"] != "complete":
            result.failed[index] = f"did not finish ({doc['status']}); rerun it to complete it"
        elif lacking:
            result.failed[index] = f"{len(lacking)} record(s) missing, first {lacking[0]}; rerun it"
        else:
            result.complete.append(index)
            result.settings = result.settings or doc["settings"]
    result.missing = [i for i in range(count) if i not in seen]
    result.docs = [placed[p] for p in sorted(placed)]
    return result


def _read_item(folder: Path, item: dict[str, Any]) -> dict[str, Any] | None:
    """The record of a manifest's item (None when it is missing or unreadable)."""
    if "record" not in item:
        return records.read_record(folder, item["key"])
    try:
        doc = json.loads((folder / item["record"]).read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


@dataclass(frozen=True)
class MergeTarget:
    """Where :data:`MERGERS` write: ``out`` (the table, summary, metrics), ``annotate`` (an annotated
    dataset; none: ``out/dataset``) and ``source`` (where this machine has the input the shards read;
    none: the path they recorded)."""

    out: Path
    annotate: Path | None = None
    source: Path | None = None


Merger = Callable[[Aggregate, MergeTarget], dict[str, Any]]


def _merge_bags(result: Aggregate, target: MergeTarget) -> dict[str, Any]:
    """The table of the bags' records; the annotated copies need no merge (one folder per bag, on the
    machine that segmented it): the summary lists them (``annotated``: bag key and copy)."""
    seconds = sum(d.get("seconds", 0.0) for d in result.docs)
    summary = batch_table.write_outputs(target.out, result.docs, seconds)
    copies = [{"bag": d["key"], "copy": d["annotated"]} for d in result.docs if d.get("annotated")]
    if copies:
        summary["annotated"] = copies
    return summary


MERGERS: dict[str, Merger] = {"bags": _merge_bags}
"""Per kind of work item (the manifest's ``kind``): how the shards' records become the outputs of the
whole run, ``merger(aggregate, target) -> summary``.  ``app/lerobot_shards.py`` adds ``episodes``
(the table and the one annotated dataset) when it is imported."""


def merge_outputs(result: Aggregate, target: MergeTarget) -> dict[str, Any]:
    """Write the outputs of the whole run (:data:`MERGERS`); returns its summary."""
    merger = MERGERS.get(result.kind)
    if merger is None:
        raise ReplayError(f"shards of kind '{result.kind}' cannot be merged by this version")
    return merger(result, target)


def shard_lines(result: Aggregate) -> list[str]:
    """One line per shard that is missing or failed (empty: every shard complete)."""
    lines = [f"shard {i} of {result.count} is missing: run it with --num-shards {result.count} "
             f"--shard-index {i}" for i in result.missing]
    return lines + [f"shard {i} of {result.count} failed: {why}" for i, why in sorted(result.failed.items())]


__all__ = ["MERGERS", "PARTIAL", "Aggregate", "MergeTarget", "aggregate", "check_shard", "merge_outputs",
           "select", "shard_dir", "shard_lines", "shard_of", "write_manifest"]
