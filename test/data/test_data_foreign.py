"""A foreign robot bag: JointState topics only, jittered stamps, no markers, missing partners."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import NoEpisodeError
from ompn_ros.data.reader import final_row_guessed
from ompn_ros.data.reader.assemble import EXTRAPOLATED_LAST

SPEC_FILE = Path(__file__).resolve().parents[2] / "config" / "reader_jointstate_example.yaml"
JOINTS = ["shoulder", "elbow", "wrist"]
MSG_ORDER = [2, 0, 1]  # the robot publishes wrist, shoulder, elbow


def _write_foreign_bag(path: Path, rng: np.random.Generator, storage: str) -> dict:
    from rosbags.rosbag2 import Writer

    from ompn_ros.data.recorder.bag_writer import storage_plugin

    truth: dict = {"episodes": [], "dropped": 0, "duplicates": 0}
    names = [JOINTS[k] for k in MSG_ORDER]
    t = 5_000_000_000
    with Writer(path, version=9, storage_plugin=storage_plugin(storage)) as w:
        js = w.add_connection("/arm/joint_states", layout.JOINT_STATE, typestore=m.typestore())
        cmd = w.add_connection("/arm/joint_command", layout.JOINT_STATE, typestore=m.typestore())
        for ep in range(3):
            n = 12 + 3 * ep
            pos = rng.standard_normal((n, 3))
            vel = rng.standard_normal((n, 3))
            act = rng.standard_normal((n, 3))
            keep = np.ones(n, dtype=bool)
            if ep != 1:
                keep[4] = False  # a lost command
            messages = []
            for k in range(n):
                head = t + k * 40_000_000  # the robot's clock: exact 25 Hz
                jitter = int(rng.integers(-3_000_000, 3_000_000))
                state = m.joint_state(head, names, pos[k][MSG_ORDER], vel[k][MSG_ORDER])
                messages.append((head + jitter, js, state))
                if keep[k]:
                    cmd_head = head + 10_000_000
                    messages.append((cmd_head + int(rng.integers(-3_000_000, 3_000_000)), cmd,
                                     m.joint_state(cmd_head, names, (), act[k][MSG_ORDER])))
                if ep == 1 and k == 6:  # a duplicate command for step 6
                    messages.append((head + 20_000_000, cmd, m.joint_state(head + 20_000_000, names, (),
                                                                           np.full(3, 99.0))))
                    truth["duplicates"] += 1
            for stamp, conn, msg in sorted(messages, key=lambda x: x[0]):
                w.write(conn, stamp, m.serialize(msg))
            steps = np.flatnonzero(keep)
            truth["dropped"] += int((~keep).sum())
            truth["episodes"].append({
                "observations": np.concatenate([np.hstack([pos, vel])[steps], np.hstack([pos, vel])[n - 1:]]),
                "actions": act[steps],
            })
            t += n * 40_000_000 + 3_000_000_000  # 3 s of silence between episodes
    return truth


@pytest.mark.parametrize(("storage", "stamp", "final"), [("mcap", "header", "duplicate"),
                                                         ("sqlite3", "log", "duplicate"),
                                                         ("mcap", "log", "drop_last_step"),
                                                         ("mcap", "header", "blank"),
                                                         ("sqlite3", "header", "extrapolate")])
def test_jointstate_only_bag(tmp_path: Path, storage: str, stamp: str, final: str) -> None:
    """No observation after the last command: row T duplicated, blank or extrapolated, or the last step
    dropped."""
    truth = _write_foreign_bag(tmp_path / "bag", np.random.default_rng(3), storage)
    spec = ReaderSpec.from_dict({**ReaderSpec.from_yaml(SPEC_FILE).to_dict(), "stamp": stamp,
                                 "final_observation": final})
    result = read_episodes(tmp_path / "bag", spec=spec)
    report = result.report.bags[0]
    assert report.split == "time_gap"
    assert len(result.episodes) == 3
    assert report.missing == {"/arm/joint_command": truth["dropped"]}
    assert report.duplicates == {"/arm/joint_command": truth["duplicates"]}
    assert report.dropped_steps == truth["dropped"]
    duplicate = final == "duplicate"
    assert report.final_duplicated == (3 if duplicate else 0)
    assert any("s_{T+1} = s_T" in note for note in report.notes) == duplicate
    adjusted = {"duplicate": "last observation duplicated as row T",
                "drop_last_step": "last step dropped (no final observation)",
                "blank": "row T left blank (zeros; no final observation)",
                "extrapolate": EXTRAPOLATED_LAST}[final]
    assert report.adjusted == {adjusted: [0, 1, 2]}
    assert ("row T = zeros (final_observation: blank)" in report.guessed) == (final == "blank")
    for want, got in zip(truth["episodes"], result.episodes):
        want_obs, want_act = want["observations"], want["actions"]
        if final == "drop_last_step":  # the last recorded observation is row T, its action is dropped
            want_obs, want_act = want_obs[:-1], want_act[:-1]
        if final == "blank":  # every action kept, row T all zeros
            want_obs = np.vstack([want_obs[:-1], np.zeros_like(want_obs[-1:])])
        if final == "extrapolate":  # every action kept, row T = 2 s_T - s_{T-1}
            f32 = want_obs.astype(np.float32)  # the reader computes it in float32
            want_obs = np.vstack([f32[:-1], 2 * f32[-2:-1] - f32[-3:-2]])
        np.testing.assert_allclose(got.observations, want_obs.astype(np.float32))
        np.testing.assert_allclose(got.actions, want_act.astype(np.float32))
        assert np.array_equal(got.observations[-1], got.observations[-2]) == duplicate  # s_{T+1} = s_T
        assert got.subtask is None and got.sketch is None and got.task == "arm_demo"
    assert "missing" in result.report.summary()
    # what ompn_train reads to train more candidates on such bags (train.candidates_no_final)
    assert final_row_guessed(result.report.facts()) == (final != "drop_last_step")


def test_tight_tolerance_reports_unattached(tmp_path: Path) -> None:
    _write_foreign_bag(tmp_path / "bag", np.random.default_rng(4), "mcap")
    spec = ReaderSpec.from_dict({**ReaderSpec.from_yaml(SPEC_FILE).to_dict(), "tolerance": 0.005})
    with pytest.raises(NoEpisodeError) as info:
        read_episodes(tmp_path / "bag", spec=spec)
    assert str(tmp_path / "bag") in str(info.value) and "no complete episode" in str(info.value)
    assert "'/arm/joint_command'" in str(info.value) and "no action" in str(info.value)
    result = read_episodes(tmp_path / "bag", spec=spec, on_error="skip_tail")
    report = result.report.bags[0]
    n_cmd = report.messages["/arm/joint_command"]
    assert report.unattached["/arm/joint_command"] == n_cmd  # commands lag by 10 ms > 5 ms
    assert result.episodes == [] and report.dropped_episodes == 3 and report.dropped == {"no action": 3}


def test_action_from_the_observation_topic_with_reordered_stamps(tmp_path: Path) -> None:
    """Observation = JointState.position, action = velocity of the same message; header stamps
    order the steps even when the bag's log stamps are out of order."""
    from rosbags.rosbag2 import Writer

    rng = np.random.default_rng(5)
    pos = rng.standard_normal((20, 3))
    vel = rng.standard_normal((20, 3))
    with Writer(tmp_path / "bag", version=9) as w:
        conn = w.add_connection("/js", layout.JOINT_STATE, typestore=m.typestore())
        stamps = []
        for k in range(20):
            head = 10**9 + k * 40_000_000 + (0 if k < 10 else 5 * 10**9)  # two episodes
            log = head + (50_000_000 if k % 4 == 1 else 0)  # these land after their successor
            stamps.append((log, m.serialize(m.joint_state(head, JOINTS, pos[k], vel[k]))))
        for log, raw in sorted(stamps):
            w.write(conn, log, raw)
    spec = ReaderSpec.from_dict({
        "observation": {"topic": "js", "type": layout.JOINT_STATE, "fields": ["position"]},
        "action": {"topic": "js", "type": layout.JOINT_STATE, "fields": ["velocity"]},
        "subtask": None, "sketch": None, "episode": None, "stamp": "header", "time_gap": 1.0,
        "final_observation": "drop_last_step",
    })
    result = read_episodes(tmp_path / "bag", spec=spec)
    assert [e.length for e in result.episodes] == [9, 9]  # final_observation: drop_last_step
    for i, ep in enumerate(result.episodes):
        rows = slice(10 * i, 10 * i + 10)
        np.testing.assert_array_equal(ep.observations, pos[rows].astype(np.float32))
        np.testing.assert_array_equal(ep.actions, vel[rows][:9].astype(np.float32))
    assert result.report.bags[0].final_duplicated == 0
    assert result.report.bags[0].adjusted == {"last step dropped (no final observation)": [0, 1]}
