"""Temporary siblings for atomic writes, and removal of the ones a killed writer left behind.

A writer creates ``.<stem>.tmp-<pid>-<random>`` (or ``.old-``; a directory or a file) next to its
target and renames it into place.  A process killed in between leaves it behind;
:func:`remove_stale_temps` deletes such entries when their process no longer runs.
Checkpoint saving and the training state call it on every save and when a run starts, so nothing
piles up under ``train_state/``.

:func:`atomic_write` writes one file that way (a full or read-only disk leaves the old file, or
none, never a truncated one) and turns a failed write into one :class:`WriteFailure` line naming the
file and the space left on its filesystem.  ``mkstemp`` and ``mkdtemp`` create owner-only
temporaries; what is published gets the mode a plain ``open()`` or ``mkdir()`` would give it, the
process's umask applied (:func:`umask_mode`), so tables, summaries and records are as readable as any
other file the user writes.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, Literal

from ompn_ros.errors import WriteFailure

TempKind = Literal["tmp", "old"]
TAGGED = re.compile(r"^\.(?P<stem>.+)\.(?:tmp|old)-(?P<pid>\d+)-[^/]+$")


def temp_prefix(stem: str, kind: TempKind = "tmp") -> str:
    """The name prefix of this process's temporaries for ``stem``: ``.<stem>.<kind>-<pid>-``."""
    return f".{stem}.{kind}-{os.getpid()}-"


def make_temp_dir(parent: Path, stem: str, kind: TempKind = "tmp") -> Path:
    """A new empty directory ``parent/.<stem>.<kind>-<pid>-<random>`` (mode 0700)."""
    parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=temp_prefix(stem, kind), dir=parent))


def current_umask() -> int:
    """The process's umask (read from ``/proc/self/status`` where Linux offers it, so no thread ever
    sees it changed; elsewhere set and restored at once)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def umask_mode(directory: bool = False) -> int:
    """The mode a new file (``0o666``) or directory (``0o777``) gets under the process's umask."""
    return (0o777 if directory else 0o666) & ~current_umask()


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


def is_stale(entry: Path) -> bool:
    """True for a leftover temporary (directory or file) of a writer that no longer runs."""
    tagged = TAGGED.match(entry.name)
    return tagged is not None and not _alive(int(tagged.group("pid")))


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


def free_space(path: Path) -> str:
    """The space left on the filesystem that holds ``path`` (its nearest existing parent)."""
    probe = Path(path).absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        usage = shutil.disk_usage(probe)
    except OSError:
        return "free space unknown"
    return f"{usage.free / 1e6:.1f} MB free" if usage.free >= 1e6 else f"{usage.free // 1024} KiB free"


def write_failure(path: Path, exc: BaseException, note: str = "") -> WriteFailure:
    """The one-line error of a failed write of ``path`` (the reason, the space left and ``note``)."""
    reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else f"{type(exc).__name__}: {exc}"
    return WriteFailure(f"cannot write '{path}': {reason} ({free_space(path)}){note}")


def atomic_write(path: Path, write: Callable[[BinaryIO], object], durable: bool = True) -> None:
    """Write ``path`` with ``write(handle)`` into a temporary sibling, synced, then renamed into place.

    ``durable=False`` skips the sync (about 10 ms on a disk, serial across processes): the rename is
    still atomic for a process that is killed, but after a power loss the file may be missing or
    empty.  Only for files whose reader treats that as absent and redoes the work (a batch's
    per-bag records, docs/scale.md).

    Raises :class:`WriteFailure` (an ``OSError``) naming ``path`` when the filesystem refuses; the
    temporary is removed and an existing ``path`` is left as it was."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp: str | None = None
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temp_prefix(path.name))
        os.fchmod(fd, umask_mode())  # mkstemp's 0600 would make every output owner-only
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            if durable:
                os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise write_failure(path, exc, "; nothing partial was left") from exc
    except BaseException:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str, durable: bool = True) -> None:
    """:func:`atomic_write` of ``text`` (UTF-8)."""
    atomic_write(path, lambda handle: handle.write(text.encode("utf-8")), durable)


__all__ = [
    "atomic_write",
    "atomic_write_text",
    "current_umask",
    "free_space",
    "is_stale",
    "make_temp_dir",
    "remove_stale_temps",
    "temp_prefix",
    "umask_mode",
    "write_failure",
]
