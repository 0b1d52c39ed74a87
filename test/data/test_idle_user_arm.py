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
from arm_bags import PERIOD, POSITION_NOISE, VELOCITY_NOISE, _arm_stream, _spec, arm_bag  # noqa: F401 (the fixture)
from driver_bags import S

from ompn_ros.data import read_episodes
from ompn_ros.data.cuts import SpeedElements, derive_idle_speed, idle_by_speed


def _covers(episodes: list, demos: list[tuple[int, int]]) -> None:
    """One episode per demonstration, each spanning at least 90 % of it and at most 0.2 s more."""
    assert len(episodes) == len(demos)
    for ep, (first, last) in zip(episodes, demos, strict=True):
        span = ep.length * PERIOD
        assert 0.9 * (last - first) <= span <= (last - first) + 0.2 * S, (span, last - first)


def test_idle_speed_is_a_joint_speed_in_rad_per_s(arm_bag: tuple[Path, list]) -> None:  # noqa: F811 (the imported fixture)
    """0.05 rad/s (the example spec's unit) finds the three demonstrations (was: one 41 s episode)."""
    path, demos = arm_bag
    result = read_episodes(path, spec=_spec(idle_speed=0.05))
    _covers(result.episodes, demos)
    assert "idle_speed 0.05 on joint position and velocity" in result.report.summary()


def test_idle_speed_auto_is_derived_from_the_bag_and_reported(arm_bag: tuple[Path, list]) -> None:  # noqa: F811 (the imported fixture)
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


def test_an_episode_the_idle_rule_ends_is_decided_idle_s_later(arm_bag: tuple[Path, list]) -> None:  # noqa: F811 (the imported fixture)
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
