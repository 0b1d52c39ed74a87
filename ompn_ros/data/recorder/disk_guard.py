"""Disk space for a bag being recorded: a check at start, a warning when it runs low, and a reserve
that lets a recorder close its bag properly on a disk that filled up.

Closing a bag writes more bytes: the pending mcap chunk, the summary section and footer, or the last
sqlite3 COMMIT, and ``metadata.yaml``.  On a full disk those writes fail too and the bag then opens
only with ``skip_tail`` (or not at all).  :class:`DiskGuard` keeps a reserve file of
``reserve_bytes`` beside the bag (named like a temporary of :mod:`ompn_ros.atomic`, so one left
by a killed recorder is removed by the next start); :meth:`DiskGuard.release` deletes it when a write
fails, which gives the close the room it needs.  ROS-free; O(1) per call (one ``statvfs``).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from ompn_ros.atomic import remove_stale_temps, temp_prefix
from ompn_ros.data.errors import NotEnoughSpace

__all__ = ["DiskGuard", "free_bytes"]


def free_bytes(path: Path) -> int:
    """Free bytes on the filesystem of ``path`` (its nearest existing parent)."""
    probe = Path(path).absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return int(shutil.disk_usage(probe).free)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


class DiskGuard:
    """Free-space checks and the close reserve of the bag directory ``bag`` (not created here)."""

    def __init__(self, bag: Path, min_free_bytes: int, reserve_bytes: int) -> None:
        self.bag = Path(bag)
        self.min_free = int(min_free_bytes)
        self.reserve_bytes = int(reserve_bytes)
        self.reserve: Path | None = None
        self._warned = False

    def free_text(self) -> str:
        return f"{_mb(free_bytes(self.bag))} free on the disk of '{self.bag}'"

    def start(self) -> None:
        """Check the space (at least ``min_free_bytes`` besides the reserve) and write the reserve.

        Raises :class:`NotEnoughSpace` (one line: the path, the space, the parameter) otherwise."""
        parent = self.bag.parent
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(parent, self.bag.name)
        free = free_bytes(parent)
        if free < self.min_free + self.reserve_bytes:
            raise NotEnoughSpace(
                f"only {_mb(free)} free on the disk of '{self.bag}', less than min_free_mb "
                f"({_mb(self.min_free)}) + {_mb(self.reserve_bytes)} kept to close the bag: free some "
                "space or record elsewhere (-o)"
            )
        if self.reserve_bytes > 0:
            reserve = parent / f"{temp_prefix(self.bag.name)}reserve"
            try:
                with open(reserve, "wb") as fh:
                    fh.write(b"\0" * self.reserve_bytes)  # real blocks: a sparse file frees nothing
                    fh.flush()
                    os.fsync(fh.fileno())
            except OSError as err:
                reserve.unlink(missing_ok=True)
                raise NotEnoughSpace(f"cannot reserve space beside '{self.bag}': {err}") from err
            self.reserve = reserve

    def low(self) -> str | None:
        """Once, when the free space (the reserve aside) fell below ``min_free_bytes``: the warning."""
        if self._warned or self.min_free <= 0 or free_bytes(self.bag) >= self.min_free:
            return None
        self._warned = True
        return f"disk space is running low: {self.free_text()} (min_free_mb {_mb(self.min_free)})"

    def release(self) -> None:
        """Delete the reserve (before closing a bag on a full disk, and after every close)."""
        if self.reserve is not None:
            self.reserve.unlink(missing_ok=True)
            self.reserve = None
