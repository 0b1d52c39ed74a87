"""A bag assembled from several topics, optionally with a corrupt command, for the reader tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from joint_lab_bags import TYPES, _episode_messages, f64
from rosbags.rosbag2 import Writer

from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import storage_plugin


def _assemble_bag(path: Path, bad_command: int | None = None) -> None:
    """The lab bag of test_reader_assemble; command message ``bad_command`` has 4 elements, not 3."""
    rng = np.random.default_rng(5)
    truth: dict = {"obs": [], "act": [], "ids": [], "stale": 0, "wrong_size": 0}
    messages = []
    for ep in range(3):
        messages += _episode_messages(ep, 10**10 + ep * 4 * 10**9, rng, truth)
    messages.sort(key=lambda x: x[0])
    commands = [i for i, (_, topic, _) in enumerate(messages) if topic == "/lab/arm/command"]
    if bad_command is not None:
        stamp, topic, _ = messages[commands[bad_command]]
        messages[commands[bad_command]] = (stamp, topic, f64(np.zeros(4)))
    with Writer(path, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {t: w.add_connection(t, ty, typestore=m.typestore()) for t, ty in TYPES.items()}
        for stamp, topic, raw in messages:
            w.write(conns[topic], stamp, raw)
