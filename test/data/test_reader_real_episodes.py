"""Episodes the way real data has them: a driver publishing joint states while the robot idles
(``split: idle``), one bag per demonstration (``split: bag``), a recording on/off topic (``split: topic``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state, scalar

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.cuts import Cut, IdleSplitter, idle_by_speed, idle_windows
from ompn_ros.data.errors import ReaderSpecError

JOINTS = ["shoulder", "elbow", "wrist"]
DEMOS = (20, 25, 18)
PERIOD = 20 * MS  # the driver's 50 Hz


def _demo_bag(path: Path, rng: np.random.Generator, storage: str = "mcap", idle_s: float = 2.0,
              switch: str | None = None) -> list[dict]:
    """Joint states at 50 Hz throughout; velocity commands only during the three demonstrations; the
    robot idles ``idle_s`` before, between and after them.  Header stamps are the robot's clock, the
    bag's receive stamps lag them by 1-3 ms."""
    bag = BagWriter(path, storage)
    truth: list[dict] = []
    pos, t = rng.standard_normal(3), 7 * S

    def state(head: int, velocity: np.ndarray) -> None:
        noise = rng.normal(scale=1e-7, size=3)  # encoder noise while still
        bag.add("/arm/joint_states", JOINT_STATE, head + int(rng.integers(1, 3)) * MS,
                joint_state(head, JOINTS, pos + noise, velocity), BEST_EFFORT)

    def idle(seconds: float) -> int:
        nonlocal t
        for _ in range(round(seconds * S / PERIOD)):
            state(t, np.zeros(3))
            t += PERIOD
        return t

    for d, n in enumerate(DEMOS):
        if d == 0:
            idle(idle_s)
        if switch is not None:  # the operator presses record just before the first command
            bag.add("/arm/recording", switch, t - 5 * MS, scalar(switch, _on(switch)))
        rows, actions = [], []
        for _ in range(n):
            vel = rng.uniform(-1, 1, 3)
            rows.append(np.concatenate([pos, vel]))
            state(t, vel)  # the driver's measured velocity
            bag.add("/arm/joint_command", JOINT_STATE, t + 4 * MS, joint_state(t + 3 * MS, JOINTS, (), vel))
            actions.append(vel)
            pos = pos + vel * PERIOD / S
            t += PERIOD
        rows.append(np.concatenate([pos, np.zeros(3)]))  # the state after the last command
        if switch is not None:
            bag.add("/arm/recording", switch, t + 5 * MS, scalar(switch, _off(switch)))
        idle(idle_s)
        truth.append({"observations": np.asarray(rows), "actions": np.asarray(actions)})
    bag.write()
    return truth


def _on(msgtype: str) -> object:
    return {"std_msgs/msg/Bool": True, "std_msgs/msg/String": "start"}.get(msgtype, 1)


def _off(msgtype: str) -> object:
    return {"std_msgs/msg/Bool": False, "std_msgs/msg/String": "stop"}.get(msgtype, 0)


def _spec(**changes: object) -> ReaderSpec:
    base = {"namespace": "/arm", "observation": {"topic": "joint_states", "type": JOINT_STATE,
                                                 "fields": ["position", "velocity"], "joint_names": JOINTS},
            "action": {"topic": "joint_command", "type": JOINT_STATE, "fields": ["velocity"],
                       "joint_names": JOINTS},
            "subtask": None, "sketch": None, "episode": None, "tolerance": 0.01, "stamp": "header",
            "time_gap": 1.0}
    return ReaderSpec.from_dict({**base, **changes})


def _check(episodes: list, truth: list[dict]) -> None:
    assert [e.length for e in episodes] == list(DEMOS)
    for got, want in zip(episodes, truth, strict=True):
        np.testing.assert_allclose(got.observations, want["observations"].astype(np.float32), atol=1e-6)
        np.testing.assert_allclose(got.actions, want["actions"].astype(np.float32))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_idle_between_demonstrations_splits_and_is_trimmed(tmp_path: Path, storage: str) -> None:
    truth = _demo_bag(tmp_path / "bag", np.random.default_rng(0), storage)
    merged = read_episodes(tmp_path / "bag", spec=_spec(split="gaps"))  # no silence: one long episode
    assert len(merged.episodes) == 1
    result = read_episodes(tmp_path / "bag", spec=_spec(split="idle", idle_s=0.5))
    _check(result.episodes, truth)
    report = result.report.bags[0]
    assert report.split == "idle" and report.missing == {} and report.adjusted == {}
    n_states = report.messages["/arm/joint_states"]
    assert report.idle_trimmed == n_states - sum(n + 1 for n in DEMOS)


def test_idle_by_speed_when_the_action_is_on_the_state_topic(tmp_path: Path) -> None:
    """Action = the measured velocity of the observation's own message: every step has a command, so
    stillness comes from ``idle_speed`` (the observation changed by less than 0.01 per second).  The
    velocity jumps at the first commanded step, the position stops changing one step after the last:
    that still step is row T, the step before it (velocity 0) the last action step."""
    truth = _demo_bag(tmp_path / "bag", np.random.default_rng(1))
    spec = _spec(split="idle", idle_s=0.5, idle_speed=0.01, final_observation="drop_last_step", action={
        "topic": "joint_states", "type": JOINT_STATE, "fields": ["velocity"], "joint_names": JOINTS})
    result = read_episodes(tmp_path / "bag", spec=spec)
    assert [e.length for e in result.episodes] == [n + 1 for n in DEMOS]
    for got, want in zip(result.episodes, truth, strict=True):
        rows, actions = want["observations"], np.vstack([want["actions"], np.zeros((1, 3))])
        want_obs = np.vstack([rows, rows[-1:]]).astype(np.float32)
        np.testing.assert_allclose(got.observations, want_obs, atol=1e-6)
        np.testing.assert_allclose(got.actions, actions.astype(np.float32))


def test_one_bag_per_demonstration(tmp_path: Path) -> None:
    """A folder of bags, each one demonstration with the robot idling around it: ``split: bag`` makes
    each bag one episode however the robot idled (the whole recording, commands attached)."""
    rng = np.random.default_rng(2)
    for k in range(3):
        _demo_bag(tmp_path / "demos" / f"demo_{k}", rng, idle_s=0.2)
    result = read_episodes(tmp_path / "demos", spec=_spec(split="bag", final_observation="require"))
    assert len(result.episodes) == 3
    assert [b.split for b in result.report.bags] == ["bag"] * 3
    for e, b in zip(result.episodes, result.report.bags, strict=True):
        assert e.length + 1 == b.messages["/arm/joint_states"] - b.missing.get("/arm/joint_command", 0)


@pytest.mark.parametrize("switch", ["std_msgs/msg/Bool", "std_msgs/msg/String", "std_msgs/msg/UInt8"])
@pytest.mark.parametrize("same_topic", [False, True])
def test_recording_switch_topic_marks_episodes(tmp_path: Path, switch: str, same_topic: bool) -> None:
    """A Bool / String / integer topic switching recording on and off: 'on' starts an episode, 'off' ends
    it; while off, steps are not used even when they carry an action (the measured velocity)."""
    truth = _demo_bag(tmp_path / "bag", np.random.default_rng(3), switch=switch)
    action = {"topic": "joint_states", "type": JOINT_STATE, "fields": ["velocity"], "joint_names": JOINTS}
    spec = _spec(split="topic", split_topic="recording",
                 **({"action": action, "final_observation": "drop_last_step"} if same_topic else {}))
    result = read_episodes(tmp_path / "bag", spec=spec)
    _check(result.episodes, truth)
    report = result.report.bags[0]
    assert report.split == "topic" and report.missing == {} and report.dropped == {}


def test_idle_spec_is_validated(tmp_path: Path) -> None:
    with pytest.raises(ReaderSpecError, match="idle_s"):
        _spec(split="idle", idle_s=0.0)
    _demo_bag(tmp_path / "bag", np.random.default_rng(4))
    action = {"topic": "joint_states", "type": JOINT_STATE, "fields": ["velocity"], "joint_names": JOINTS}
    result = read_episodes(tmp_path / "bag", spec=_spec(split="idle", action=action, idle_speed=0))
    assert len(result.episodes) == 1 and any("set idle_speed" in n for n in result.report.bags[0].notes)
    with pytest.raises(ReaderSpecError, match="idle_speed must be 'auto'"):
        _spec(split="idle", idle_speed="fast")
    # the default, idle_speed: auto, sees the robot still from the bag's own noise floor
    result = read_episodes(tmp_path / "bag", spec=_spec(split="idle", action=action,
                                                        final_observation="drop_last_step"))
    assert [e.length for e in result.episodes] == [n + 1 for n in DEMOS]
    assert "idle_speed auto -> " in result.report.summary()


def test_splitter_holds_a_short_pause_and_trims_a_long_one() -> None:
    ms = MS
    splitter = IdleSplitter(100 * ms)
    pushes = [(0, True), (10, False), (20, False), (30, True), (40, True), (50, False),  # short pause
              (60, True), (100, True), (160, True), (170, True), (180, False)]
    cuts = [c for t, still in pushes for c in splitter.push(t * ms, still)]
    assert cuts == [Cut("start", 1), Cut("step", 2), Cut("step", 3), Cut("step", 4), Cut("step", 5),
                    Cut("end", 6), Cut("start", 10)]
    assert splitter.trimmed == 1 + 2 + 1  # 0 ms; 100 and 160 ms (after the final 60 ms); 170 ms
    assert splitter.finish() == [Cut("end", 10)]
    stamps = np.asarray([t for t, _ in pushes], np.int64) * ms
    windows, _ = idle_windows(stamps, np.asarray([s for _, s in pushes]), 0.1)
    assert windows == [(1, 7), (10, 11)]


def test_silence_longer_than_idle_ends_the_episode() -> None:
    splitter = IdleSplitter(100 * MS)
    assert splitter.push(0, False) == [Cut("start", 0)]
    assert splitter.push(10 * MS, False) == [Cut("step", 1)]
    assert splitter.push(500 * MS, False) == [Cut("end", 1), Cut("start", 2)]


def test_idle_by_speed() -> None:
    stamps = np.asarray([0, 100, 200, 300], np.int64) * MS
    values = np.asarray([[0.0, 0.0], [0.0005, 0.0], [0.0005, 0.01], [0.0005, 0.01]])
    assert idle_by_speed(stamps, values, 0.01).tolist() == [True, True, False, True]
