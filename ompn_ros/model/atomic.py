"""Temporary siblings for atomic writes, and removal of the ones a killed writer left behind.

A writer creates ``.<stem>.tmp-<pid>-<random>`` (or ``.old-``; a directory or a file) next to its
target and renames it into place.  A process killed in between leaves it behind;
:func:`remove_stale_temps` deletes such entries when their process no longer runs (names without a
process id, written by older versions, once they are older than :data:`LEGACY_STALE_SECONDS`).
Checkpoint saving and the training state call it on every save and when a run starts, so nothing
piles up under ``train_state/``.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Literal

TempKind = Literal["tmp", "old"]
TAGGED = re.compile(r"^\.(?P<stem>.+)\.(?:tmp|old)-(?P<pid>\d+)-[^/]+$")
LEGACY = re.compile(r"^\.(?P<stem>.+)\.(?:(?:tmp|old)-[A-Za-z0-9_]+|[A-Za-z0-9_]{8}(?:\.tmp)?)$")
LEGACY_STALE_SECONDS = 3600.0


def temp_prefix(stem: str, kind: TempKind = "tmp") -> str:
    """The name prefix of this process's temporaries for ``stem``: ``.<stem>.<kind>-<pid>-``."""
    return f".{stem}.{kind}-{os.getpid()}-"


def make_temp_dir(parent: Path, stem: str, kind: TempKind = "tmp") -> Path:
    """A new empty directory ``parent/.<stem>.<kind>-<pid>-<random>`` (mode 0700)."""
    parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=temp_prefix(stem, kind), dir=parent))


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def is_stale(entry: Path, now: float | None = None) -> bool:
    """True for a leftover temporary (directory or file) of a writer that no longer runs."""
    tagged = TAGGED.match(entry.name)
    if tagged:
        return not _alive(int(tagged.group("pid")))
    if LEGACY.match(entry.name):
        age = (time.time() if now is None else now) - entry.stat().st_mtime
        return age > LEGACY_STALE_SECONDS
    return False


def remove_stale_temps(parent: Path, stem: str | None = None) -> list[Path]:
    """Delete the stale temporary directories in ``parent`` (only those of ``stem`` when given).

    Returns what was removed.  O(entries of ``parent``).
    """
    if not parent.is_dir():
        return []
    removed = []
    for entry in sorted(parent.iterdir()):
        if not entry.name.startswith("."):
            continue
        if stem is not None and not entry.name.startswith(f".{stem}."):
            continue
        if is_stale(entry):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)
            removed.append(entry)
    return removed


__all__ = ["LEGACY_STALE_SECONDS", "is_stale", "make_temp_dir", "remove_stale_temps", "temp_prefix"]
