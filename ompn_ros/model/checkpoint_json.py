"""Every JSON file of a checkpoint, read one way: bounded in size and depth, strict UTF-8, one error.

A checkpoint directory is input like any other: it may come from another lab, a download or a disk
that failed.  ``config.json``, ``meta.json``, ``detector.json``, ``ensemble.json`` and the training
record beside them are read by :func:`read_checkpoint_json`, which refuses, in one line naming the
file, what the plain ``json`` module turns into a traceback or a hang:

* anything but a regular file (a FIFO would block the reader, a device never ends);
* more than :data:`MAX_JSON_BYTES` bytes (the largest shipped file is a few kB);
* bytes that are not UTF-8;
* nesting deeper than :data:`MAX_JSON_DEPTH` (``json`` recurses once per level and a deep enough
  file raises ``RecursionError``; no checkpoint file nests more than a few levels);
* text that is not JSON.

The depth is measured on the text before parsing, with the strings blanked out: O(size).
"""

from __future__ import annotations

import json
import os
import re
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

from ompn_ros.model.errors import CheckpointError

MAX_JSON_BYTES: Final = 16 * 1024 * 1024
MAX_JSON_DEPTH: Final = 64
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_BRACKETS = re.compile(r"[\[\]{}]")


def json_depth(text: str) -> int:
    """The deepest nesting of ``[`` and ``{`` in JSON ``text`` (brackets inside strings ignored)."""
    depth = deepest = 0
    for bracket in _BRACKETS.findall(_STRING.sub('""', text)):
        if bracket in "[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest


def read_checkpoint_json(file: str | Path, error: Callable[[str], Exception] = CheckpointError) -> Any:
    """The parsed JSON of ``file``; ``error(line)`` (default :class:`CheckpointError`) naming the file
    and the fault when it is not a regular file, too large, not UTF-8, too deep or not JSON."""
    path = Path(file)
    try:  # opened without blocking (a FIFO), then judged by what was opened (no race with a rename)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as handle:
            info = os.fstat(handle.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise error(f"{path}: not a regular file; a checkpoint's JSON files are plain files")
            if info.st_size > MAX_JSON_BYTES:
                raise error(f"{path}: {info.st_size} bytes, more than the {MAX_JSON_BYTES} a checkpoint's "
                            "JSON file may have")
            data = handle.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise error(f"{path}: cannot be read: {exc.strerror or exc}") from None
    if len(data) > MAX_JSON_BYTES:
        raise error(f"{path}: more than the {MAX_JSON_BYTES} bytes a checkpoint's JSON file may have")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}); is this file from a checkpoint?") from None
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise error(f"{path}: nested {depth} levels deep, more than the {MAX_JSON_DEPTH} a checkpoint's "
                    "JSON file may have")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None


__all__ = ["MAX_JSON_BYTES", "MAX_JSON_DEPTH", "json_depth", "read_checkpoint_json"]
