"""Clocks that step, live: the robot's header clock or the node's own clock set back or forward by an
NTP correction mid-demonstration never splits or merges an episode in ``ompn_node`` (the bag reader's
contract, ``test_reader_clock_steps.py``), and the replay of the same messages with their receive
times (:func:`ompn_ros.stream.replay.replay_stream`) gives the node's output, number for number.

The demonstrations are a driver's arm of the reader's compatibility corpus (JointState on the robot's
clock, 25 Hz, 2 s pauses, the step just before observation #30, in the second demonstration), fed to
the node in the order recorded with the node's clock reading each message's log stamp."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from compat_corpus import ARM, ARM_SPEC, ClockStep, arm_demos, write_arm  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from ompn_ros.data import ReaderSpec, read_episodes  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.clock_steps import LiveClockSteps  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import StreamRecord, replay_stream  # noqa: E402
from ompn_ros.stream.rule import StreamLimits  # noqa: E402

LENGTHS = [20, 25, 18]
AT = 30
SIZES = {"back 2 s": -2_000_000_000, "back 0.3 s": -300_000_000, "forward 5 s": 5_000_000_000,
         "forward 0.6 s": 600_000_000}
PARAMS: dict[str, Any] = {"obs_source": "joint_state", "joint_fields": ["position"], "max_stamp_lead": 0.0,
                          "clock_jump_back": 1.0, "episode_gap": 0.5}
LIMITS = StreamLimits(clock_jump_back=1.0, episode_gap=0.5, header_topic="joint_states")
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "clock_steps", seed=3, obs_dim=3, action_type="continuous",
                             action_dim=2, n_slots=3, slot_size=16)


def arm_stream(**step: ClockStep) -> tuple[list[bytes], np.ndarray, np.ndarray, np.ndarray]:
    """The arm's JointState messages in the order recorded: CDR, positions, header and log stamps."""
    msgs = [(log, raw) for log, topic, raw in arm_demos(LENGTHS, **step).messages if topic == ARM]
    states = [m.deserialize(raw, "sensor_msgs/msg/JointState") for _, raw in msgs]
    obs = np.array([s.position for s in states], dtype=np.float32)
    header = np.array([s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states], dtype=np.int64)
    return [raw for _, raw in msgs], obs, header, np.array([log for log, _ in msgs], dtype=np.int64)


def live(ctx, ckpt: Path, raws: list[bytes], log: np.ndarray) -> tuple[list[tuple], np.ndarray, dict, Any]:
    """``ompn_node`` in process, its clock at each message's log stamp: ~/boundary, ~/pi, counters."""
    from test_node_poison import active_node

    node = active_node(ctx, ckpt, **PARAMS)
    now = [0]
    node.stream.clock = lambda: now[0]
    for raw, stamp in zip(raws, log.tolist(), strict=True):
        now[0] = stamp
        node.inputs.on_joint_state(deserialize_message(raw, JointState))
    out = []
    for raw in node.outputs.pubs["boundary"].raws:
        b = decode_subtask_boundary(raw)
        out.append((b.episode, b.step, b.subtask, b.final, b.stamp_ns, b.decided_stamp_ns,
                    np.float32(b.score)))
    pis = np.array([m.parse_float32_array(raw) for raw in node.outputs.pubs["pi"].raws])
    counters, config = node.counters(), node.segmenter.detector_config
    node.destroy_node()
    return out, pis, counters, config


def replayed(record: StreamRecord) -> tuple[list[tuple], np.ndarray]:
    boundaries = [(ep, e.step, e.subtask, e.final, e.stamp_ns, decided, np.float32(e.score))
                  for ep, decided, e in record.boundaries]
    pis = np.array([np.concatenate([np.asarray(out.step_output.pi, np.float32),
                                    np.float32([out.step_output.expected_position, out.step_output.pi_end])])
                    for _, _, out in record.steps])
    return boundaries, pis


def rows_per_episode(record: StreamRecord) -> list[int]:
    episodes = [ep for ep, _, _ in record.steps]
    return [episodes.count(k) for k in sorted(set(episodes))]


@pytest.mark.parametrize("size", SIZES.values(), ids=SIZES.keys())
def test_a_stepped_robot_clock_keeps_one_episode_per_demonstration(ctx, ckpt: Path, size: int) -> None:
    """Was: back 2 s, forward 5 s and forward 0.6 s each cut the second demonstration in two (a clock
    restart, a pause).  Now one episode per demonstration; a step beyond ``clock_jump_back`` or
    ``episode_gap`` is counted and warned once, naming topic, direction and size; a step back within
    ``clock_jump_back`` stays out-of-order rejections, as a late message would."""
    raws, obs, header, log = arm_stream(robot=ClockStep(AT, size))
    boundaries, pis, counters, config = live(ctx, ckpt, raws, log)
    record = replay_stream(StreamingSegmenter(stepper_from_checkpoint(ckpt), config), obs, header, LIMITS,
                           receive_ns=log)
    assert counters["episodes"] == record.events["episodes"] == len(LENGTHS)
    beyond = size <= -10**9 or size >= 500_000_000
    assert counters["clock_steps"] == record.events.get("clock_steps", 0) == int(beyond)
    assert counters["clock_jumps"] == counters["episode_gaps"] - (len(LENGTHS) - 1) == 0
    rejected = 0 if beyond else int(counters["rejected_out_of_order_stamp"])
    assert rows_per_episode(record) == [LENGTHS[0] + 1, LENGTHS[1] + 1 - rejected, LENGTHS[2] + 1]
    assert rejected == (0 if beyond else 7)  # the 0.3 s the robot's clock lived again (40 ms period)
    if beyond:
        way = "back" if size < 0 else "forward"
        (line,) = record.warnings
        assert f"'joint_states' steps {way} {abs(size) / 1e9:.3f} s" in line and "\n" not in line
    assert boundaries == replayed(record)[0]
    np.testing.assert_array_equal(pis, replayed(record)[1])


@pytest.mark.parametrize("size", [-2_000_000_000, 5_000_000_000], ids=["back 2 s", "forward 5 s"])
def test_a_stepped_pc_clock_reads_live_as_the_reader_and_the_replay_read_it(ctx, ckpt: Path, tmp_path: Path,
                                                                           size: int) -> None:
    """The node's own clock (the recording PC's) steps: the live node, the replay of the messages with
    their receive times and the bag reader all give the three demonstrations as written."""
    raws, obs, header, log = arm_stream(pc=ClockStep(AT, size))
    boundaries, pis, counters, config = live(ctx, ckpt, raws, log)
    record = replay_stream(StreamingSegmenter(stepper_from_checkpoint(ckpt), config), obs, header, LIMITS,
                           receive_ns=log)
    assert boundaries == replayed(record)[0]
    np.testing.assert_array_equal(pis, replayed(record)[1])
    assert counters["clock_steps"] == counters["clock_jumps"] == 0 and counters["rejected"] == 0
    read = read_episodes(write_arm(tmp_path / "bag", arm_demos(LENGTHS, pc=ClockStep(AT, size))),
                         spec=ReaderSpec.from_dict({**ARM_SPEC.to_dict(), "stamp": "header"})).episodes
    assert rows_per_episode(record) == [ep.length + 1 for ep in read] == [n + 1 for n in LENGTHS]
    np.testing.assert_array_equal(np.concatenate([ep.observations for ep in read]), obs)  # every row stepped


def test_the_live_form_tells_a_step_from_a_pause_and_a_restart() -> None:
    """One clock moving alone is a step; both moving alike (a pause, a sim restarting its clock with
    the node on sim time) is none; the node's clock moving alone is no step of the header clock."""
    period = 40_000_000

    def size(header_dt: int, receive_dt: int) -> int:
        steps = LiveClockSteps()
        for k in range(5):
            assert steps.step(10**9 + k * period, 5 * 10**9 + k * period) == 0
        return steps.step(10**9 + 4 * period + header_dt, 5 * 10**9 + 4 * period + receive_dt)

    assert size(-2 * 10**9 + period, period) == -2 * 10**9
    assert size(5 * 10**9 + period, period) == 5 * 10**9
    assert size(2 * 10**9, 2 * 10**9) == 0  # a pause
    assert size(-3 * 10**9, -3 * 10**9) == 0  # both clocks restarted
    assert size(period, -2 * 10**9) == size(period, 5 * 10**9) == 0  # the node's clock stepped
    assert LiveClockSteps().step(10**9, 0) == 0  # no receiver's clock yet: nothing to judge
