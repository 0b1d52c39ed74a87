"""Checks of what storage cannot vouch for: sqlite page structure, mcap chunk CRCs, finite values.

* sqlite3: ``PRAGMA quick_check`` (b-tree and overflow-chain structure, O(pages)) on open; the
  database is opened read-only and immutable, so reading never writes beside the user's bag.
* mcap: ``rosbags`` checks a chunk's CRC when the writer set it (non-zero); :func:`mcap_bad_chunks`
  locates the failing chunk for the error message, :func:`mcap_chunks_without_crc` counts the
  chunks whose bytes nothing can verify (the report notes them).
* decoded vectors: every value finite (a flipped exponent byte or a garbage page shows as NaN/inf
  with high probability, never silently in training); checked in blocks, O(block) extra memory.
"""

from __future__ import annotations

import sqlite3
import struct
from pathlib import Path
from urllib.request import pathname2url

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import CRCValidationError, StreamReader, get_chunk_data_stream

_CHUNK_CRC_OFFSET = 9 + 24  # opcode + length, then start/end time and uncompressed size


def open_readonly(file: Path) -> sqlite3.Connection:
    """``file`` opened read-only and ``immutable`` (as ``rosbags`` opens it): SQLite creates no
    ``-shm``/``-wal`` file beside a WAL-mode database and needs no write access to its directory.
    A journal left with committed data is applied on a copy first (:mod:`.journal`)."""
    return sqlite3.connect(f"file:{pathname2url(str(file.resolve()))}?mode=ro&immutable=1", uri=True)


def sqlite_problem(file: Path) -> str | None:
    """The first problem ``PRAGMA quick_check`` reports for ``file``, ``None`` when it is sound."""
    try:
        con = open_readonly(file)
    except sqlite3.Error as err:
        return f"cannot open: {err}"
    try:
        rows = con.execute("PRAGMA quick_check(1)").fetchall()
    except sqlite3.DatabaseError as err:
        return str(err)
    finally:
        con.close()
    text = str(rows[0][0]) if rows else "quick_check returned nothing"
    return None if text == "ok" else text


def mcap_chunks_without_crc(file: Path) -> tuple[int, int]:
    """``(chunks, chunks whose CRC is 0)`` from the summary; ``(0, 0)`` when there is none."""
    try:
        with open(file, "rb") as fh:
            summary = make_reader(fh).get_summary()
            if summary is None:
                return 0, 0
            zero = 0
            for index in summary.chunk_indexes:
                fh.seek(index.chunk_start_offset + _CHUNK_CRC_OFFSET)
                (crc,) = struct.unpack("<I", fh.read(4))
                zero += crc == 0
            return len(summary.chunk_indexes), zero
    except (OSError, McapError, struct.error, ValueError):
        return 0, 0


def mcap_bad_chunks(file: Path) -> list[tuple[int, int, int]]:
    """``(chunk number, first, last message stamp)`` of every chunk failing its (non-zero) CRC."""
    bad: list[tuple[int, int, int]] = []
    number = 0
    try:
        with open(file, "rb") as fh:
            for rec in StreamReader(fh, emit_chunks=True, record_size_limit=1 << 30).records:
                if not isinstance(rec, Chunk):
                    continue
                try:
                    get_chunk_data_stream(rec, validate_crc=True)
                except CRCValidationError:
                    bad.append((number, rec.message_start_time, rec.message_end_time))
                number += 1
    except Exception:  # a broken stream ends the scan; what was found so far stands
        pass
    return bad


def nonfinite_rows(values: np.ndarray, block_bytes: int = 1 << 22) -> np.ndarray:
    """Indices of the rows of ``values`` holding NaN or inf (integers are always finite).

    Checked in blocks of about ``block_bytes`` of ``values``, so the temporary mask stays small
    whatever the size of the array."""
    if values.size == 0 or values.dtype.kind != "f":
        return np.zeros(0, dtype=np.int64)
    flat = values.reshape(len(values), -1)
    step = max(1, block_bytes // max(1, flat.shape[1] * flat.itemsize))
    found = [np.flatnonzero(~np.isfinite(flat[a: a + step]).all(axis=1)) + a
             for a in range(0, len(flat), step)]
    return np.concatenate(found).astype(np.int64)
