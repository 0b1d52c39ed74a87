"""A user's arm in a bag: 6 joints at 50 Hz from a driver that publishes all the time, velocity
commands, idle periods between 3 demonstrations, encoder noise (the idle rule's tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state

from ompn_ros.data import ReaderSpec

JOINTS = [f"joint_{k}" for k in range(1, 7)]
PERIOD = 20 * MS  # 50 Hz
DEMO_S, IDLE_S = 8.0, 5.0
POSITION_NOISE, VELOCITY_NOISE = 1e-4, 0.01  # rad, rad/s: an encoder and its differentiated velocity


def _arm_stream(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """(stamps, positions + velocities as the driver reports them, commands, each demonstration's first
    and last commanded stamp): idle, demo, idle, demo, idle, demo, idle (about 41 s)."""
    stamps, rows, commands, demos = [], [], [], []
    pos, t = rng.uniform(-1, 1, 6), 3 * S

    def tick(vel: np.ndarray) -> None:
        nonlocal pos, t
        seen = np.concatenate([pos + rng.normal(0, POSITION_NOISE, 6),
                               vel + rng.normal(0, VELOCITY_NOISE, 6)])
        stamps.append(t)
        rows.append(seen)
        commands.append(vel)
        pos = pos + vel * PERIOD / S
        t += PERIOD

    for _ in range(3):
        for _ in range(round(IDLE_S * S / PERIOD)):
            tick(np.zeros(6))
        amp, phase = rng.uniform(0.2, 0.5, 6), rng.uniform(0, np.pi, 6)
        steps = round(DEMO_S * S / PERIOD)
        first = t
        for k in range(steps):  # each joint sweeps out and back; the arm never rests mid-demonstration
            tick(amp * np.sin(2 * np.pi * k / steps + phase) * np.sin(np.pi * (k + 1) / (steps + 1)) ** 0.3)
        demos.append((first, t - PERIOD))
    for _ in range(round(2.0 * S / PERIOD)):
        tick(np.zeros(6))
    return np.asarray(stamps), np.asarray(rows), np.asarray(commands), demos


def _write(path: Path, stamps: np.ndarray, rows: np.ndarray, commands: np.ndarray) -> None:
    bag = BagWriter(path, "mcap")
    for t, row, cmd in zip(stamps, rows, commands, strict=True):
        state = joint_state(int(t), JOINTS, row[:6], row[6:])
        bag.add("/arm/joint_states", JOINT_STATE, int(t) + 2 * MS, state, BEST_EFFORT)
        bag.add("/arm/joint_command", JOINT_STATE, int(t) + 3 * MS, joint_state(int(t) + MS, JOINTS, (), cmd))
    bag.write()


def _spec(**changes: object) -> ReaderSpec:
    base = {"namespace": "/arm", "observation": {"topic": "joint_states", "type": JOINT_STATE,
                                                 "fields": ["position", "velocity"], "joint_names": JOINTS},
            "action": {"topic": "joint_command", "type": JOINT_STATE, "fields": ["velocity"],
                       "joint_names": JOINTS},
            "subtask": None, "sketch": None, "episode": None, "tolerance": 0.01, "stamp": "header",
            "split": "idle", "idle_s": 1.0, "final_observation": "duplicate"}
    return ReaderSpec.from_dict({**base, **changes})


@pytest.fixture(scope="module")
def arm_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[int, int]]]:
    stamps, rows, commands, demos = _arm_stream(np.random.default_rng(56))
    path = tmp_path_factory.mktemp("arm") / "bag"
    _write(path, stamps, rows, commands)
    return path, demos
