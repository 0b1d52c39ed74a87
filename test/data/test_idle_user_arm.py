"""``split: idle`` and ``idle_s`` on a bag like a user's arm: 6 joints at 50 Hz from a driver that publishes
all the time, a teleoperation that publishes velocity commands all the time (zeros while the arm waits),
idle periods between 3 demonstrations, encoder noise on positions and velocities.

Was: ``idle_speed`` was compared with the change per second of every observation element, velocities
included (an acceleration, in rad/s²), so 0.05 rad/s read the whole bag as one episode; nothing derived
the threshold; and an episode the idle rule ended claimed one step of lag though the rule waited
``idle_s``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.cuts import SpeedElements, derive_idle_speed, idle_by_speed

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


def _covers(episodes: list, demos: list[tuple[int, int]]) -> None:
    """One episode per demonstration, each spanning at least 90 % of it and at most 0.2 s more."""
    assert len(episodes) == len(demos)
    for ep, (first, last) in zip(episodes, demos, strict=True):
        span = ep.length * PERIOD
        assert 0.9 * (last - first) <= span <= (last - first) + 0.2 * S, (span, last - first)


def test_idle_speed_is_a_joint_speed_in_rad_per_s(arm_bag: tuple[Path, list]) -> None:
    """0.05 rad/s (the example spec's unit) finds the three demonstrations (was: one 41 s episode)."""
    path, demos = arm_bag
    result = read_episodes(path, spec=_spec(idle_speed=0.05))
    _covers(result.episodes, demos)
    assert "idle_speed 0.05 on joint position and velocity" in result.report.summary()


def test_idle_speed_auto_is_derived_from_the_bag_and_reported(arm_bag: tuple[Path, list]) -> None:
    path, demos = arm_bag
    result = read_episodes(path, spec=_spec())  # idle_speed: auto, the default
    _covers(result.episodes, demos)
    summary = result.report.summary()
    assert "idle_speed auto -> " in summary and "noise floor" in summary


def test_the_derived_threshold_sits_between_a_held_arm_and_a_moving_one() -> None:
    stamps, rows, commands, _ = _arm_stream(np.random.default_rng(7))
    elements = SpeedElements(("position", "velocity"))
    derived = derive_idle_speed(stamps, rows, elements)
    held = ~np.any(commands != 0, axis=1)
    still = idle_by_speed(stamps, rows, derived.speed, elements)
    assert still[held].mean() > 0.99  # a held arm is still (noise stays below the threshold)
    assert still[~held].mean() < 0.05  # a moving one is not
    assert derived.velocity_noise == pytest.approx(VELOCITY_NOISE, rel=0.3)
    assert derived.position_noise == pytest.approx(POSITION_NOISE * np.sqrt(2) * S / PERIOD, rel=0.3)


def test_an_episode_the_idle_rule_ends_is_decided_idle_s_later(arm_bag: tuple[Path, list]) -> None:
    """The stream rule (``ompn_node``'s ``idle_s``) on the same stream: the end boundary of each
    demonstration is decided at the observation that completed ``idle_s`` of stillness, its stamp about
    1 s after the final observation, and its decided step as many rows later."""
    torch = pytest.importorskip("torch")
    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.model.load import build_stepper
    from ompn_ros.model.policy import OMPNPolicy
    from ompn_ros.segmenter import StreamingSegmenter
    from ompn_ros.stream.replay import replay_stream
    from ompn_ros.stream.rule import StreamLimits

    torch.manual_seed(0)
    config = OMPNConfig(obs_dim=12, action_type="continuous", action_dim=6, n_slots=3, slot_size=16)
    policy = OMPNPolicy(config)
    seg = StreamingSegmenter(build_stepper(policy), DetectorConfig(high=0.99, low=0.99))
    stamps, rows, _, demos = _arm_stream(np.random.default_rng(56))
    limits = StreamLimits(idle_s=1.0, idle_speed=0.05, idle_elements=SpeedElements(("position", "velocity")))
    record = replay_stream(seg, list(rows.astype(np.float32)), list(stamps), limits)
    closing = {}
    for episode, decided, event in record.boundaries:  # each episode's last boundary: the one that closed it
        closing[episode] = (decided, event)
    assert len(closing) == len(demos)
    for decided, event in closing.values():
        lag_s = (decided - event.stamp_ns) / S
        assert 0.95 <= lag_s <= 1.3, lag_s
        assert event.detected_at - event.step >= round(0.95 * S / PERIOD)
