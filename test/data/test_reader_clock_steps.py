"""Clocks that step (``ompn_ros.data.reader.steps``): the robot's header clock or the recording PC's
clock set back or forward by an NTP correction mid-bag never merges, splits, reorders or relabels a
demonstration: read as recorded with a note, or refused in one line naming the fix (docs/bags.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from compat_corpus import (
    ARM,
    ARM_SPEC,
    STEP_NS,
    ClockStep,
    arm_demos,
    check_arm,
    write_arm,
)

from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.errors import ClockStepError
from ompn_ros.data.reader.steps import lag_steps

LENGTHS = [20, 25, 18]
AT = 30  # the step comes before observation #30: in the middle of the second demonstration
SIZES = {"back 2 s": -2_000_000_000, "back 0.3 s": -300_000_000, "forward 5 s": 5_000_000_000,
         "forward 0.6 s": 600_000_000}
HEADER = ReaderSpec.from_dict({**ARM_SPEC.to_dict(), "stamp": "header"})


@pytest.mark.parametrize("size", SIZES.values(), ids=SIZES.keys())
def test_robot_clock_step_is_refused_with_stamp_log(tmp_path: Path, size: int) -> None:
    """The robot's header clock steps (was: 3 demonstrations merged into 1, 14 rows reordered, a
    demonstration split, labels shifted): refused naming topic, message, size and ``stamp: log``;
    read with ``stamp: log`` every demonstration comes back as written."""
    demo = arm_demos(LENGTHS, robot=ClockStep(AT, size))
    bag = write_arm(tmp_path / "bag", demo)
    for on_error in ("raise", "skip_tail"):
        with pytest.raises(ClockStepError) as info:
            read_episodes(bag, spec=HEADER, on_error=on_error)  # type: ignore[arg-type]
        text = str(info.value)
        way = "back" if size < 0 else "forward"
        assert f"'{ARM}'" in text and f"message #{AT}" in text and "stamp: log" in text
        assert f"header.stamp steps {way} {abs(size) / 1e9:.3f} s" in text and "\n" not in text
    check_arm(read_episodes(bag, spec=ARM_SPEC).episodes, demo)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("size", SIZES.values(), ids=SIZES.keys())
@pytest.mark.parametrize("stamp", ["log", "header"])
def test_pc_clock_step_is_read_as_recorded(tmp_path: Path, size: int, storage: str, stamp: str) -> None:
    """The recording PC's clock steps (its log stamps; ``rosbags`` hands them over sorted): read in
    recording order, value for value, labels included, with a note naming topic, place and size."""
    demo = arm_demos(LENGTHS, pc=ClockStep(AT, size))
    bag = write_arm(tmp_path / "bag", demo, storage=storage)
    spec = ARM_SPEC if stamp == "log" else HEADER
    result = read_episodes(bag, spec=spec)
    check_arm(result.episodes, demo)
    notes = [n for n in result.report.bags[0].notes if "recording PC clock steps" in n]
    way = "back" if size < 0 else "forward"
    assert len(notes) == 1 and f"'{ARM}' at message #{AT}" in notes[0]
    assert f"steps {way} {abs(size) / 1e9:.3f} s" in notes[0]


def test_steady_clocks_leave_no_note(tmp_path: Path) -> None:
    """Control: the same bag without a step reads alike on either clock, with no clock note."""
    demo = arm_demos(LENGTHS)
    bag = write_arm(tmp_path / "bag", demo)
    for spec in (ARM_SPEC, HEADER):
        result = read_episodes(bag, spec=spec)
        check_arm(result.episodes, demo)
        assert not [n for n in result.report.bags[0].notes if "clock" in n]


def test_late_message_is_no_step() -> None:
    """A message delivered 0.3 s late (its receive stamp only) and a pause seen on both clocks are no
    clock step; a lasting change of the lag is, on the clock whose interval left its period."""
    header = 10**9 + np.arange(40, dtype=np.int64) * STEP_NS
    header[20:] += 2_000_000_000  # a pause: both clocks
    log = header + 3_000_000
    late = log.copy()
    late[10] += 300_000_000
    assert lag_steps(ARM, late, header) == []
    assert lag_steps(ARM, log, header) == []
    assert lag_steps(ARM, log, np.zeros_like(header)) == []  # a header left unset: no clock to compare
    stepped = header.copy()
    stepped[30:] -= 700_000_000
    ((step, clock),) = lag_steps(ARM, log, stepped)
    assert (clock, step.index, step.size) == ("header", 30, -700_000_000)
