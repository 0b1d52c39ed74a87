"""sqlite3 bags left by a killed recorder: read them as of their last commit, without changing them.

A recorder killed inside a write transaction leaves a rollback journal (``<name>.db3-journal``) beside
the database; one that runs SQLite in WAL mode leaves ``<name>.db3-wal`` with committed transactions
not yet copied into the database.  SQLite applies either on the next read-write open (the journal is
rolled back, the WAL replayed; SQLite's "hot journal" recovery).  A read-only open cannot: it fails
with "attempt to write a readonly database", and ``rosbags`` opens sqlite3 bags ``immutable``, which
ignores both files.  A reader must not write to a user's recording, so :func:`committed_view` copies
each such database with its journal into a temporary directory and lets SQLite recover the copy.

Cost: one copy of the affected ``.db3`` files (disk and time linear in their size), only for bags
that have a journal left beside a database; every other bag is read in place.
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import CorruptBagError
from .paths import storage_files

JOURNAL_SUFFIXES = ("-journal", "-wal")
"""Files SQLite leaves beside ``<name>.db3`` (rollback journal, write-ahead log); ``-shm`` is only the
WAL's index, rebuilt from the WAL."""


JOURNAL_MAGIC = bytes.fromhex("d9d505f920a163d7")
"""First bytes of a rollback journal SQLite must apply; until it is synced the header is zeros and
SQLite ignores the file (SQLite file format, "The Rollback Journal")."""
WAL_HEADER_BYTES = 32
"""A write-ahead log no longer than its header holds no transaction (SQLite file format, "The WAL")."""


def _applies(journal: Path) -> bool:
    """Whether SQLite would apply ``journal`` on the next read-write open."""
    try:
        if journal.name.endswith("-wal"):
            return journal.stat().st_size > WAL_HEADER_BYTES
        with open(journal, "rb") as fh:
            return fh.read(len(JOURNAL_MAGIC)) == JOURNAL_MAGIC
    except OSError:
        return False


def leftover_journals(bag: Path) -> dict[Path, list[Path]]:
    """``{database: [journal files SQLite would apply]}`` for the bag's ``.db3`` files that have one.

    Cost: one ``stat`` and at most an 8-byte read per database."""
    out: dict[Path, list[Path]] = {}
    for file in storage_files(bag):
        if file.suffix != ".db3":
            continue
        found = [j for j in (file.with_name(file.name + s) for s in JOURNAL_SUFFIXES) if _applies(j)]
        if found:
            out[file] = found
    return out


def _recover(copy: Path, original: Path) -> None:
    """Open ``copy`` read-write so that SQLite applies the journal beside it, then close it."""
    try:
        con = sqlite3.connect(str(copy))
        try:
            con.execute("SELECT count(*) FROM sqlite_master").fetchall()
        finally:
            con.close()
    except sqlite3.Error as err:
        raise CorruptBagError(f"the journal left beside the database cannot be applied: {err}",
                              path=original) from err


@contextmanager
def committed_view(bag: Path) -> Iterator[tuple[Path, list[str]]]:
    """``(path to read, notes)``: ``bag`` itself, or a recovered copy while the context is open.

    The copy has the bag's layout (a directory with the same file names, or the single storage
    file); files other than the affected databases are linked, not copied.  Raises
    :class:`CorruptBagError` (naming the original file) when SQLite cannot apply a journal.
    """
    affected = leftover_journals(bag)
    if not affected:
        yield bag, []
        return
    with tempfile.TemporaryDirectory(prefix="ompn_sqlite_recovery_") as tmp:
        root = Path(tmp)
        target = root / bag.name
        if bag.is_dir():
            target.mkdir()
            skip = {p for db, journals in affected.items() for p in (db, *journals)}
            for item in bag.iterdir():
                if item not in skip and item.is_file():
                    (target / item.name).symlink_to(item.resolve())
            where = target
        else:
            where = root
        notes = []
        for db, journals in affected.items():
            for file in (db, *journals):
                shutil.copy2(file, where / file.name)
            _recover(where / db.name, db)
            left = ", ".join(j.name for j in journals)
            notes.append(f"{db.name}: the recording ended inside a write transaction ({left} left beside "
                         "it); read as of its last commit, recovered on a temporary copy (the bag itself "
                         "is unchanged)")
        yield target, notes


__all__ = ["JOURNAL_SUFFIXES", "committed_view", "leftover_journals"]
