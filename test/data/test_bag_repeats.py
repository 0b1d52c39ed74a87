"""A driver that publishes the same message twice (docs/bags.md): the repeat is dropped and counted,
in strict and non-strict reads; a partner that differs stays a strict error that names the fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from compat_corpus import CMD, SPEC, STATE, STEP_NS, check_episodes, demos, write_rosbags

from ompn_ros import layout
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data import messages as m
from ompn_ros.data.errors import AlignmentError

STRICT = ReaderSpec.from_dict({**SPEC.to_dict(), "strict": True})


def _repeated(seed: int, every: int, delay_ns: int) -> tuple[object, int, int]:
    """Three demonstrations where every ``every``-th state and command message goes out twice,
    ``delay_ns`` apart with the same bytes; returns (demo, repeated states, repeated commands)."""
    demo = demos([20, 25, 18], seed=seed)
    out, states, cmds = [], 0, 0
    for k, (stamp, topic, raw) in enumerate(demo.messages):
        out.append((stamp, topic, raw))
        if k % every == 0:
            out.append((stamp + delay_ns, topic, raw))
            states += topic == STATE
            cmds += topic == CMD
    demo.messages = sorted(out, key=lambda item: item[0])
    return demo, states, cmds


@pytest.mark.parametrize("spec", [STRICT, SPEC], ids=["strict", "lenient"])
@pytest.mark.parametrize("delay_ns", [0, 1, 3_000])
def test_repeated_messages_are_read_once(tmp_path: Path, spec: ReaderSpec, delay_ns: int) -> None:
    """Was: a repeated state left its first copy without a command (strict: 'no action partner'),
    a repeated command was a second partner (strict: '(duplicate)')."""
    demo, states, cmds = _repeated(3, 7, delay_ns)
    bag = write_rosbags(tmp_path / "bag", demo)  # type: ignore[arg-type]
    result = read_episodes(bag, spec=spec)
    check_episodes(result.episodes, demo)  # type: ignore[arg-type]
    report = result.report.bags[0]
    assert states and cmds and report.duplicates == {STATE: states, CMD: cmds}
    assert report.missing == {} and report.dropped_steps == 0
    assert any("repeated" in note and STATE in note for note in report.notes)


def test_identical_states_of_a_still_robot_are_steps(tmp_path: Path) -> None:
    """Two headerless states with the same bytes one step apart are two observations, not a repeat."""
    demo = demos([20], seed=4)
    same = m.serialize(m.float32_array(demo.observations[0][3], "state"))
    demo.observations[0][4] = demo.observations[0][3]
    demo.messages = [(t, topic, same if topic == STATE and t == 10**9 + 4 * STEP_NS else raw)
                     for t, topic, raw in demo.messages]
    result = read_episodes(write_rosbags(tmp_path / "bag", demo), spec=STRICT)
    check_episodes(result.episodes, demo)
    assert result.report.bags[0].duplicates == {}


def test_a_second_command_that_differs_names_the_fix(tmp_path: Path) -> None:
    """Not a repeat: strict stops with the observation, the topic and the way to read it anyway."""
    demo = demos([20], seed=5)
    other = m.serialize(m.float32_array([9.0, 9.0], "cmd"))
    demo.messages.append((10**9 + 5 * STEP_NS + 2_003_000, CMD, other))
    demo.messages.sort(key=lambda item: item[0])
    bag = write_rosbags(tmp_path / "bag", demo)
    with pytest.raises(AlignmentError) as info:
        read_episodes(bag, spec=STRICT)
    text = str(info.value)
    assert "second partner for observation #5" in text and f"'{CMD}'" in text and "strict: false" in text
    result = read_episodes(bag, spec=SPEC)  # the fix it names: the first partner is kept
    check_episodes(result.episodes, demo)
    assert result.report.bags[0].duplicates == {CMD: 1}


def test_a_jointstate_resent_with_its_header_stamp_is_a_repeat(tmp_path: Path) -> None:
    """A stamped message sent again later (same header stamp, same data) is the same sample."""
    from rosbags.rosbag2 import Writer

    spec = ReaderSpec.from_dict({
        "observation": {"topic": "/arm/joint_states", "type": layout.JOINT_STATE,
                        "fields": ["position"], "joint_names": ["a", "b"]},
        "action": {"topic": CMD, "type": layout.FLOAT32_ARRAY, "dim": 2},
        "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5,
        "strict": True, "stamp": "header",
    })
    rng = np.random.default_rng(6)
    pos = rng.standard_normal((11, 2))
    act = rng.standard_normal((10, 2)).astype(np.float32)
    with Writer(tmp_path / "bag", version=9) as w:
        js = w.add_connection("/arm/joint_states", layout.JOINT_STATE, typestore=m.typestore())
        cmd = w.add_connection(CMD, layout.FLOAT32_ARRAY, typestore=m.typestore())
        for k in range(11):
            t = 10**9 + k * STEP_NS
            state = m.serialize(m.joint_state(t, ["a", "b"], pos[k]))
            w.write(js, t + 1000, state)
            if k < 10:
                w.write(cmd, t + 2_000_000, m.serialize(m.float32_array(act[k], "cmd")))
            if k == 4:
                w.write(js, t + 5_000_000, state)  # the driver sends sample 4 again, 5 ms later
    result = read_episodes(tmp_path / "bag", spec=spec)
    (ep,) = result.episodes
    np.testing.assert_array_equal(ep.observations, pos.astype(np.float32))
    np.testing.assert_array_equal(ep.actions, act)
    assert result.report.bags[0].duplicates == {"/arm/joint_states": 1}
