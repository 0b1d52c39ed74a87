"""``std_msgs/Float64MultiArray`` topics as float32 vectors (e.g. ros2_control effort commands).

Each message is parsed without building a message object (:func:`ompn_ros.data.messages.parse_float64_array`).
Cost: O(N · D) for N messages of D elements.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import CorruptBagError, VectorLengthError
from ..messages import parse_float64_array


def stack_float64_arrays(raws: Sequence[bytes], expected_dim: int | None, path: str, topic: str,
                         stamps: np.ndarray) -> np.ndarray:
    """``[N, D]`` float32 of N messages; every message must have ``expected_dim`` elements (``None``:
    those of the topic's first message).  An undecodable message raises :class:`CorruptBagError`, one of
    another length :class:`VectorLengthError`, both naming the topic and the message index."""
    if not raws:
        return np.zeros((0, expected_dim or 0), dtype=np.float32)
    dim = expected_dim
    out: np.ndarray | None = None
    for i, raw in enumerate(raws):
        try:
            vec = parse_float64_array(raw)  # without the layout.data_offset padding
        except Exception as err:  # struct/ValueError on bad CDR, rosbags errors in the fallback
            raise CorruptBagError(f"cannot decode Float64MultiArray: {err}", path=path, topic=topic,
                                  index=i, stamp=int(stamps[i])) from err
        if dim is None:
            dim = len(vec)
        if len(vec) != dim:
            why = "" if expected_dim is not None else " (the length of the topic's first message)"
            raise VectorLengthError(f"vector has {len(vec)} elements, expected {dim}{why}", path=path,
                                    topic=topic, index=i, stamp=int(stamps[i]))
        if out is None:
            out = np.empty((len(raws), dim), dtype=np.float32)
        out[i] = vec
    assert out is not None  # raws is not empty
    return out
