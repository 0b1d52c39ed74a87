"""A sqlite3 bag whose writer was killed inside a transaction: read as of its last commit, unchanged.

The kill is made deterministic: a child process opens the finished bag, deletes and inserts rows in
one transaction with a one-page cache (so SQLite spills uncommitted pages into the database file
and syncs a hot rollback journal), and kills itself with SIGKILL before the commit.
"""

from __future__ import annotations

import hashlib
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros.data import BagError, ReaderSpec, read_episodes, write_episodes
from ompn_ros.data.reader.journal import JOURNAL_MAGIC, committed_view, leftover_journals

_KILL_INSIDE_TRANSACTION = """
import os, signal, sqlite3, sys
con = sqlite3.connect(sys.argv[1], isolation_level=None)
con.execute("PRAGMA cache_size=1")
con.execute("BEGIN")
con.execute("DELETE FROM messages WHERE id % 2 = 0")
con.execute("INSERT INTO messages (topic_id, timestamp, data) "
            "SELECT topic_id, timestamp + 1, data FROM messages")
os.kill(os.getpid(), signal.SIGKILL)
"""


def _killed_bag(tmp_path: Path) -> tuple[Path, list, Path]:
    episodes = make_episodes("craft", 4, seed=3, min_steps=20, max_steps=30)
    bag = tmp_path / "bag"
    write_episodes(bag, episodes, "craft", storage="sqlite3")
    db = next(bag.glob("*.db3"))
    done = subprocess.run([sys.executable, "-c", _KILL_INSIDE_TRANSACTION, str(db)], capture_output=True)
    assert done.returncode == -signal.SIGKILL, done.stderr
    return bag, episodes, db


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_killed_transaction_is_rolled_back_on_a_copy(tmp_path: Path) -> None:
    bag, episodes, db = _killed_bag(tmp_path)
    journal = db.with_name(db.name + "-journal")
    assert journal.read_bytes()[:8] == JOURNAL_MAGIC  # a hot journal: SQLite must roll it back
    with pytest.raises(sqlite3.OperationalError):  # what a read-only open does with it
        sqlite3.connect(f"file:{db}?mode=ro", uri=True).execute("SELECT count(*) FROM messages").fetchone()
    immutable = sqlite3.connect(f"file:{db}?immutable=1", uri=True)
    try:  # the database file itself holds uncommitted pages (or is inconsistent without the journal)
        torn = immutable.execute("SELECT count(*) FROM messages").fetchone()[0]
    except sqlite3.DatabaseError:
        torn = -1
    finally:
        immutable.close()
    before = _digest(bag)
    result = read_episodes(bag, spec=ReaderSpec.for_domain("craft"))
    assert _digest(bag) == before  # the user's bag is not written to
    assert len(result.episodes) == len(episodes)
    for got, want in zip(result.episodes, episodes, strict=True):
        assert_same_episode(got, want)
    notes = result.report.bags[0].notes
    assert any("write transaction" in n and journal.name in n for n in notes), notes
    with committed_view(bag) as (copy, _):
        con = sqlite3.connect(str(next(copy.glob("*.db3"))))
        committed = con.execute("SELECT count(*) FROM messages").fetchone()[0]
        con.close()
    assert committed != torn  # the recovery changed what is read


def test_only_journals_sqlite_would_apply_trigger_a_copy(tmp_path: Path) -> None:
    episodes = make_episodes("craft", 2, seed=4, min_steps=20, max_steps=20)
    bag = tmp_path / "bag"
    write_episodes(bag, episodes, "craft", storage="sqlite3")
    db = next(bag.glob("*.db3"))
    journal = db.with_name(db.name + "-journal")
    journal.write_bytes(bytes(512))  # header not synced yet: SQLite ignores the file
    assert leftover_journals(bag) == {}
    with committed_view(bag) as (path, notes):
        assert path == bag and notes == []
    assert len(read_episodes(bag, spec=ReaderSpec.for_domain("craft")).episodes) == 2
    wal = db.with_name(db.name + "-wal")
    wal.write_bytes(bytes(32))  # a write-ahead log with its header only holds no transaction
    assert leftover_journals(bag) == {}


def test_a_damaged_journal_is_reported_against_the_bag_not_the_copy(tmp_path: Path) -> None:
    bag, _, db = _killed_bag(tmp_path)
    journal = db.with_name(db.name + "-journal")
    data = bytearray(journal.read_bytes())
    data[8:] = os.urandom(len(data) - 8)  # a hot header, garbage page records
    journal.write_bytes(bytes(data))
    try:
        result = read_episodes(bag, spec=ReaderSpec.for_domain("craft"))
    except BagError as err:  # whatever SQLite made of it, the error names the user's bag
        assert str(bag) in str(err) and "ompn_sqlite_recovery" not in str(err), err
    else:
        report = result.report.bags[0]
        assert "ompn_sqlite_recovery" not in " ".join([*report.notes, report.error or ""])
