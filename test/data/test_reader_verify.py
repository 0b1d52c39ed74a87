"""Damage storage cannot report: a flipped byte in an mcap chunk, a garbage page in sqlite3.

The property: a damaged episode is never passed on silently.  ``on_error='raise'`` raises a
CorruptBagError naming the storage file (or bag, topic and message); ``'skip_tail'`` returns only
episodes identical to what was written and records the damage in the report.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, make_episodes

from ompn_ros.data import CorruptBagError, Episode, ReaderSpec, read_episodes, write_episodes
from ompn_ros.data.recorder.storage import refresh_chunk_crcs

MAGIC = b"\x89MCAP0\r\n"
CHUNK, FOOTER = 0x06, 0x02


def _storage(bag: Path, suffix: str) -> Path:
    return next(bag.glob(f"*{suffix}"))


def _chunks(data: bytes) -> list[tuple[int, int, int]]:
    """``(crc offset, records offset, records length)`` of every uncompressed chunk."""
    out, pos = [], len(MAGIC)
    while pos < len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == FOOTER:
            break
        if op == CHUNK:
            body = pos + 9
            (comp_len,) = struct.unpack_from("<I", data, body + 28)
            assert comp_len == 0, "the test expects uncompressed chunks"
            records = body + 32 + comp_len + 8
            (size,) = struct.unpack_from("<Q", data, body + 32 + comp_len)
            out.append((body + 24, records, size))
        pos += 9 + length
    return out


def _set_chunk_crcs(file: Path) -> None:
    """Write the CRC of every chunk (as a writer that computes them does)."""
    data = bytearray(file.read_bytes())
    for crc_at, start, size in _chunks(bytes(data)):
        struct.pack_into("<I", data, crc_at, zlib.crc32(data[start:start + size]))
    file.write_bytes(bytes(data))


def _flip_in_middle_chunk(file: Path, value: int | None = None) -> None:
    """Change one byte in the middle of the middle chunk (xor 0x01, or set to ``value``)."""
    data = bytearray(file.read_bytes())
    chunks = _chunks(bytes(data))
    _, start, size = chunks[len(chunks) // 2]
    at = start + size // 2
    data[at] = value if value is not None else data[at] ^ 0x01
    file.write_bytes(bytes(data))


def _assert_only_true_episodes(written: list[Episode], got: list[Episode]) -> None:
    by_seed = {e.seed: e for e in written}
    for episode in got:
        assert_same_episode(by_seed[episode.seed], episode)


def test_flipped_byte_in_a_chunk_with_crc(tmp_path: Path) -> None:
    episodes = make_episodes("craft", 25, seed=5, min_steps=30, max_steps=30)
    write_episodes(tmp_path / "bag", episodes, "craft", storage="mcap")
    file = _storage(tmp_path / "bag", ".mcap")
    _set_chunk_crcs(file)
    assert len(read_episodes(tmp_path / "bag", spec=ReaderSpec.for_domain("craft")).episodes) == 25
    _flip_in_middle_chunk(file)
    spec = ReaderSpec.for_domain("craft")
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert str(file) in str(info.value) and "CRC" in str(info.value) and "chunk #" in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert 1 <= len(result.episodes) < 25
    _assert_only_true_episodes(episodes, result.episodes)
    report = result.report.bags[0]
    assert report.error and "CRC" in report.error and report.dropped_episodes >= 1
    assert "CRC" in result.report.summary()
    assert json.loads(json.dumps(result.report.to_dict()))["errors"] == [report.error]


def test_chunks_without_crc_are_noted_and_nan_is_caught(tmp_path: Path) -> None:
    """Without CRCs a flipped exponent byte shows as a non-finite value: named, then dropped."""
    episodes = make_episodes("dial", 40, seed=6, min_steps=50, max_steps=50)
    write_episodes(tmp_path / "bag", episodes, "dial", storage="mcap")
    file = _storage(tmp_path / "bag", ".mcap")
    data = bytearray(file.read_bytes())
    needle = np.asarray(episodes[20].observations[3], dtype="<f4").tobytes()
    at = bytes(data).find(needle)
    assert at > 0 and np.frombuffer(needle, "<f4")[0] != 0
    data[at + 3] = 0x7F  # the high byte of a float32 whose exponent's low bit is set: inf or NaN
    data[at + 2] |= 0x80
    file.write_bytes(bytes(data))
    assert refresh_chunk_crcs(file, clear=True) > 0  # as a writer without CRCs leaves them
    spec = ReaderSpec.for_domain("dial")
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    err = info.value
    assert err.topic == "/observation" and err.index == sum(e.length + 1 for e in episodes[:20]) + 3
    assert "NaN or infinite" in str(err) and str(tmp_path / "bag") in str(err)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert len(result.episodes) == 39
    _assert_only_true_episodes(episodes, result.episodes)
    report = result.report.bags[0]
    assert report.dropped == {"non-finite values": 1}
    assert any("carry no CRC" in note for note in report.notes)
    assert "1 non-finite values" in result.report.summary()


@pytest.mark.parametrize("where", [0.3, 0.5, 0.7, 0.85])
def test_garbage_page_in_sqlite(tmp_path: Path, where: float) -> None:
    episodes = make_episodes("craft", 12, seed=9, min_steps=20, max_steps=20)
    write_episodes(tmp_path / "bag", episodes, "craft", storage="sqlite3")
    file = _storage(tmp_path / "bag", ".db3")
    page = int(file.stat().st_size // 4096 * where)
    with open(file, "r+b") as fh:
        fh.seek(page * 4096)
        fh.write(np.random.default_rng(page).bytes(4096))
    spec = ReaderSpec.for_domain("craft")
    with pytest.raises(CorruptBagError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert str(tmp_path / "bag") in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    assert len(result.episodes) < 12
    _assert_only_true_episodes(episodes, result.episodes)
    report = result.report.bags[0]
    assert report.dropped_episodes >= 1 and (report.error or report.dropped)
