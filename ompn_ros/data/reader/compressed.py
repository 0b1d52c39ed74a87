"""Messages of rosbag2's message compression read where ``rosbags`` does not decompress them.

With ``compression_mode: message`` every message of the storage file is one zstd frame; ``rosbags``
decompresses them only when a metadata.yaml says so.  A storage file read on its own (passed as a
file, or a split bag whose metadata.yaml was never written) and the salvage path (which reads the
storage record by record) see the frames themselves.  A CDR message starts with its encapsulation
header (``00 00``/``00 01``), never with the zstd frame magic, so a message starting with the magic
is a compressed one.  Cost: one 4-byte comparison per message; decompression O(message size).
"""

from __future__ import annotations

import sys

if sys.version_info >= (3, 14):
    from compression import zstd
else:  # the zstd module rosbags itself uses before Python 3.14
    from backports import zstd

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
"""First bytes of a zstd frame (RFC 8878, section 3.1.1)."""
NOTE = ("messages are zstd-compressed (rosbag2 message compression) and no metadata.yaml says so: "
        "decompressed while reading")


def is_compressed(data: bytes | memoryview) -> bool:
    """Whether ``data`` is a zstd frame rather than a CDR message."""
    return bytes(data[:4]) == ZSTD_MAGIC


def decompress(data: bytes | memoryview) -> bytes:
    """The CDR message inside one zstd frame."""
    return bytes(zstd.decompress(bytes(data)))
