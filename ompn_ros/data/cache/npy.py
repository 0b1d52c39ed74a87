"""Append rows to a ``.npy`` file whose row count is known only at the end (the episode cache's format).

The header (NumPy ``.npy`` format 1.0) is written first with room for any row count and rewritten,
with the same length, by :meth:`NpyAppender.close`; the result is a plain ``.npy`` file that
``np.load(path, mmap_mode='r')`` maps without reading it.  Complexity: O(bytes appended) time,
O(one appended block) memory.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..errors import NpyAppendError

_MAGIC = b"\x93NUMPY\x01\x00"
_PLACEHOLDER_ROWS = 10**17  # widest row count the placeholder header leaves room for
_ALIGN = 64  # NumPy aligns the data to 64 bytes


def npy_header(dtype: np.dtype, shape: tuple[int, ...], length: int | None = None) -> bytes:
    """The ``.npy`` 1.0 header of a C-ordered array; padded with spaces to ``length`` bytes if given."""
    descr = np.lib.format.dtype_to_descr(dtype)
    body = f"{{'descr': {descr!r}, 'fortran_order': False, 'shape': {tuple(int(n) for n in shape)!r}, }}"
    fixed = len(_MAGIC) + 2 + len(body) + 1  # + the closing newline
    total = length if length is not None else -(-fixed // _ALIGN) * _ALIGN
    if total < fixed or total - len(_MAGIC) - 2 > 0xFFFF:
        raise NpyAppendError(f"an .npy header for shape {shape} needs {fixed} bytes, not {total}")
    text = body + " " * (total - fixed) + "\n"
    return _MAGIC + struct.pack("<H", len(text)) + text.encode("latin1")


class NpyAppender:
    """Write ``rows`` blocks one after the other into ``path``; :meth:`close` fixes the header.

    ``dtype`` and ``tail`` (the shape of one row) come from the first block unless given; later
    blocks must have the same row shape and a dtype castable to it (``same_kind``).
    """

    def __init__(self, path: Path, dtype: np.dtype | type | None = None,
                 tail: tuple[int, ...] | None = None) -> None:
        self.path = path
        self.dtype = None if dtype is None else np.dtype(dtype)
        self.tail = tail
        self.rows = 0
        self._header_len = 0
        self._fh = open(path, "wb")  # closed by close() or abort()

    def append(self, rows: np.ndarray) -> None:
        """Append a block of rows (``rows.shape[1:] == tail``)."""
        rows = np.asarray(rows)
        if self.dtype is None:
            self.dtype = rows.dtype
        if self.tail is None:
            self.tail = tuple(rows.shape[1:])
        if tuple(rows.shape[1:]) != self.tail:
            raise NpyAppendError(f"{self.path.name}: rows of shape {rows.shape[1:]} after rows of shape "
                                 f"{self.tail}")
        if not np.can_cast(rows.dtype, self.dtype, "same_kind"):
            raise NpyAppendError(f"{self.path.name}: {rows.dtype} rows after {self.dtype} rows")
        if self._header_len == 0:
            header = npy_header(self.dtype, (_PLACEHOLDER_ROWS, *self.tail))
            self._fh.write(header)
            self._header_len = len(header)
        block = np.ascontiguousarray(rows, dtype=self.dtype)
        if block.size:
            self._fh.write(block.data)
        self.rows += len(block)

    def close(self) -> tuple[int, ...]:
        """Write the final header and close; returns the array's shape."""
        if self.dtype is None or self.tail is None:
            self.abort()
            raise NpyAppendError(f"{self.path.name}: no rows and no dtype/row shape given")
        shape = (self.rows, *self.tail)
        if self._header_len == 0:
            self._fh.write(npy_header(self.dtype, shape))
        else:
            self._fh.seek(0)
            self._fh.write(npy_header(self.dtype, shape, self._header_len))
        self._fh.close()
        return shape

    def abort(self) -> None:
        """Close and delete the file (a failed build)."""
        if not self._fh.closed:
            self._fh.close()
        if self.path.exists():
            os.unlink(self.path)
