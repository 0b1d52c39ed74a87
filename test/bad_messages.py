"""Bags with undecodable messages on chosen topics at chosen indices."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from synthetic_episodes import make_episodes

from ompn_ros import layout
from ompn_ros.data import messages as m
from ompn_ros.data.recorder.bag_writer import EpisodeBagWriter


def _bag_with_bad_messages(path: Path, bad: dict[str, int]) -> list:
    """Craft bag (4 episodes of 6 steps) whose message #bad[topic] of each named topic is broken."""
    episodes = make_episodes("craft", 4, seed=11, min_steps=6, max_steps=6)
    with EpisodeBagWriter(path, layout.CRAFT) as writer:
        real = writer._write
        counter: dict[str, int] = {}

        def write(name: str, stamp: int, raw: bytes) -> None:
            i = counter.get(name, 0)
            counter[name] = i + 1
            if bad.get(name) == i:
                short = m.serialize(m.float32_array(np.zeros(100)))
                raw = short if name == layout.OBSERVATION else b"\x00\x01"
            real(name, stamp, raw)

        writer._write = write  # type: ignore[method-assign]
        for ep in episodes:
            writer.write_episode(ep)
    return episodes
