"""MultiArray CDR with data_offset padding, as some drivers write it."""

from __future__ import annotations

import numpy as np

from ompn_ros import layout


def _padded(typename: str, values: np.ndarray, pad: int, dims: int = 1) -> bytes:
    """A MultiArray of ``values`` after ``pad`` padding elements (``layout.data_offset = pad``),
    with a 2-D layout when ``dims`` is 2, written with the ``rosbags`` typestore (not this package's
    encoder)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    dim_t = ts.types["std_msgs/msg/MultiArrayDimension"]
    n = len(values)
    shape = [dim_t(label="all", size=n, stride=n)] if dims == 1 else [
        dim_t(label="rows", size=2, stride=n), dim_t(label="cols", size=n // 2, stride=n // 2)]
    lay = ts.types["std_msgs/msg/MultiArrayLayout"](dim=shape, data_offset=pad)
    dtype = np.float32 if typename == layout.FLOAT32_ARRAY else np.float64
    data = np.concatenate([np.full(pad, 1e6), values]).astype(dtype)
    return bytes(ts.serialize_cdr(ts.types[typename](layout=lay, data=data), typename))
