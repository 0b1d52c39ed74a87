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
    from node_in_process import active_node

    node = active_node(ctx, ckpt, **PARAMS)
    now = [0]
    node.stream.clock = lambda: now[0]
    for raw, stamp in zip(raws, log.tolist(), strict=True):
        now[0] = stamp
        node.inputs.joint_states.on_joint_state(deserialize_message(raw, JointState))
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


# --- observation_spec with header stamps: the assembler's steps ------------------------------------
WRENCH_SPEC = ("{step_topic: joint_states, tolerance_s: 0.05, wait_s: 0.3, stamp: header, fields: ["
               "{topic: joint_states, type: sensor_msgs/msg/JointState, field: position, names: [a, b, c]},"
               "{topic: wrench, type: geometry_msgs/msg/WrenchStamped, field: wrench}]}")
GRIPPER_SPEC = ("{step_topic: joint_states, tolerance_s: 0.05, wait_s: 0.3, stamp: header, fields: ["
                "{topic: joint_states, type: sensor_msgs/msg/JointState, field: position, names: [a, b, c]},"
                "{topic: gripper, type: std_msgs/msg/Float32MultiArray, field: data, size: 2}]}")
LAG_NS = 150_000_000  # a partner that lags: more than STEP_NS, within wait_s


class NodeClock:
    """The node's clock (``get_clock()``), set by the test to each message's arrival."""

    def __init__(self) -> None:
        self.nanoseconds = 0

    def now(self) -> NodeClock:
        return self


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return {name: random_checkpoint(tmp_path_factory, f"clock_steps_{name}", seed=5, obs_dim=dim,
                                    action_type="continuous", action_dim=2, n_slots=3, slot_size=16)
            for name, dim in (("wrench", 9), ("gripper", 5))}


def spec_stream(partner: str, robot: ClockStep | None) -> tuple[list[tuple[int, str, bytes]], np.ndarray,
                                                               np.ndarray, np.ndarray]:
    """A JointState step topic on the robot's clock (25 Hz, 2 s pauses, ``robot``: its clock's step)
    with a partner: 'wrench' (WrenchStamped on the robot's clock, arriving 3 ms after its step, and
    :data:`LAG_NS` after it at the end of each demonstration and just before the step, the next ones
    behind it, so the assembler releases those steps late) or 'gripper' (Float32MultiArray stamped at
    reception, 5 ms before its step).  Returns the messages in arrival order (arrival, topic, CDR) and
    per step the observation, the header stamp and the arrival."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(8)
    arrivals: list[tuple[int, str, bytes]] = []
    rows, header, arrival = [], [], []
    t, k, last_wrench = 10**9, 0, 0
    for steps in LENGTHS:
        for i in range(steps + 1):
            true = t + i * 40_000_000
            head = true - 5_000_000 + (robot.size_ns if robot is not None and k >= robot.at else 0)
            pos = rng.standard_normal(3)
            arrivals.append((true, "/joint_states", m.serialize(m.joint_state(head, ["c", "a", "b"],
                                                                              [pos[2], pos[0], pos[1]], ()))))
            if partner == "wrench":
                w = WrenchStamped()
                w.header.stamp.sec, w.header.stamp.nanosec = divmod(head, 10**9)
                w.wrench.force.x, w.wrench.torque.z = float(k), -0.5 * k
                lag = LAG_NS if i == steps or (robot is not None and k == robot.at - 1) else 3_000_000
                last_wrench = max(true + lag, last_wrench + 1)  # a topic's messages arrive in order
                arrivals.append((last_wrench, "/wrench", serialize_message(w)))
                extra = [float(k), 0, 0, 0, 0, -0.5 * k]
            else:
                extra = [0.1 * k, -0.1 * k]
                arrivals.append((true - 5_000_000, "/gripper", m.serialize(m.float32_array(extra, "grip"))))
            rows.append(np.concatenate([pos, extra]))
            header.append(head)
            arrival.append(true)
            k += 1
        t += steps * 40_000_000 + 2_000_000_000
    arrivals.sort(key=lambda a: a[0])
    return arrivals, np.array(rows, np.float32), np.array(header, np.int64), np.array(arrival, np.int64)


def live_spec(ctx, ckpt: Path, spec: str,
              arrivals: list[tuple[int, str, bytes]]) -> tuple[list[tuple], np.ndarray, dict, Any]:
    """``ompn_node`` with ``observation_spec`` in process, its clock at each message's arrival."""
    from node_in_process import active_node

    node = active_node(ctx, ckpt, observation_spec=spec, max_stamp_lead=0.0, clock_jump_back=1.0,
                       episode_gap=0.5)
    clock = NodeClock()
    node.get_clock = lambda: clock  # type: ignore[method-assign]
    partners = {t: node.inputs.spec.partner_callback(t) for t in ("/wrench", "/gripper")}
    for at, topic, raw in arrivals:
        clock.nanoseconds = at
        node.inputs.spec.on_step(raw) if topic == "/joint_states" else partners[topic](raw)
    out = [(b.episode, b.step, b.subtask, b.final, b.stamp_ns, b.decided_stamp_ns, np.float32(b.score))
           for b in map(decode_subtask_boundary, node.outputs.pubs["boundary"].raws)]
    pis = np.array([m.parse_float32_array(raw) for raw in node.outputs.pubs["pi"].raws])
    counters, config = node.counters(), node.segmenter.detector_config
    node.destroy_node()
    return out, pis, counters, config


@pytest.mark.parametrize(("partner", "size"), [("gripper", -2_000_000_000), ("wrench", 5_000_000_000),
                                               ("wrench", 0)], ids=["back 2 s", "forward 5 s", "no step"])
def test_a_stepped_robot_clock_keeps_assembled_demonstrations_whole(ctx, ckpts: dict[str, Path],
                                                                   partner: str, size: int) -> None:
    """``observation_spec`` with ``stamp: header``: was a clock restart (back 2 s) or a pause (forward
    5 s) cutting the second demonstration.  Now one episode per demonstration, the step counted and
    warned once naming the step topic; a step the assembler released :data:`LAG_NS` late (its partner
    lagged) is judged at its arrival, so it is neither a clock step nor does it hide a pause."""
    arrivals, obs, header, arrival = spec_stream(partner, ClockStep(AT, size) if size else None)
    ckpt = ckpts[partner]
    boundaries, pis, counters, config = live_spec(
        ctx, ckpt, WRENCH_SPEC if partner == "wrench" else GRIPPER_SPEC, arrivals)
    limits = StreamLimits(clock_jump_back=1.0, episode_gap=0.5, header_topic="/joint_states")
    record = replay_stream(StreamingSegmenter(stepper_from_checkpoint(ckpt), config), obs, header, limits,
                           receive_ns=arrival)
    assert counters["episodes"] == record.events["episodes"] == len(LENGTHS)
    assert counters["clock_steps"] == record.events.get("clock_steps", 0) == int(size != 0)
    assert counters["clock_jumps"] == 0 and counters["episode_gaps"] == len(LENGTHS) - 1
    assert counters["rejected"] == 0 and counters["obs.kept"] == counters["obs.steps"] == len(obs)
    assert rows_per_episode(record) == [n + 1 for n in LENGTHS]
    if size:
        (line,) = record.warnings
        assert f"'/joint_states' steps {'back' if size < 0 else 'forward'} {abs(size) / 1e9:.3f} s" in line
    assert len(pis) == len(obs)
    assert boundaries == replayed(record)[0]
    np.testing.assert_array_equal(pis, replayed(record)[1])


# --- the node's own clock stamping at reception ------------------------------------------------------
def live_array(ctx, ckpt: Path, obs: np.ndarray, wall: np.ndarray, steady: np.ndarray | None,
               ) -> tuple[list[tuple], np.ndarray, dict, Any, list[str]]:
    """``ompn_node`` on Float32MultiArray observations stamped at reception: its wall clock at
    ``wall``, its steady clock at ``steady`` (``None``: none, as under ``use_sim_time``)."""
    from node_in_process import active_node

    node = active_node(ctx, ckpt, obs_source="array", executor="events", max_stamp_lead=0.0,
                       clock_jump_back=1.0, episode_gap=0.5)
    clock, mono = NodeClock(), [0]
    node.get_clock = lambda: clock  # type: ignore[method-assign]
    node.inputs.steady = None if steady is None else (lambda: mono[0])
    warned: list[str] = []
    node.outputs.warning = warned.append  # type: ignore[method-assign]
    for k, x in enumerate(obs):
        clock.nanoseconds = int(wall[k])
        mono[0] = 0 if steady is None else int(steady[k])
        node.inputs.on_array(m.serialize(m.float32_array(x, "obs")))
    out = [(b.episode, b.step, b.subtask, b.final, b.stamp_ns, b.decided_stamp_ns, np.float32(b.score))
           for b in map(decode_subtask_boundary, node.outputs.pubs["boundary"].raws)]
    pis = np.array([m.parse_float32_array(raw) for raw in node.outputs.pubs["pi"].raws])
    counters, config = node.counters(), node.segmenter.detector_config
    node.destroy_node()
    return out, pis, counters, config, warned


def reception_stamps(wall: np.ndarray) -> list[int]:
    """The node's stamps at reception: its clock, kept strictly increasing unless it went back further
    than ``clock_jump_back`` (1 s)."""
    out, last = [], 0
    for now in wall.tolist():
        last = now if now > last or last - now > 10**9 else last + 1
        out.append(last)
    return out


@pytest.mark.parametrize("size", [-2_000_000_000, -300_000_000, 5_000_000_000],
                         ids=["back 2 s", "back 0.3 s", "forward 5 s"])
def test_a_stepped_pc_clock_keeps_reception_stamped_demonstrations_whole(ctx, ckpt: Path, size: int) -> None:
    """Float32MultiArray observations stamped with the node's clock at reception: was a clock restart
    (back 2 s) or a pause (forward 5 s) cutting the second demonstration.  Now the step shows against
    the node's steady clock: one episode per demonstration, counted and warned once; the replay given
    the same wall and steady times gives the node's output, number for number."""
    _, obs, _, steady = arm_stream()
    wall = arm_stream(pc=ClockStep(AT, size))[3]
    boundaries, pis, counters, config, warned = live_array(ctx, ckpt, obs, wall, steady)
    beyond = size <= -10**9 or size >= 500_000_000
    assert counters["episodes"] == len(LENGTHS) and counters["clock_steps"] == int(beyond)
    assert counters["clock_jumps"] == 0 and counters["episode_gaps"] == len(LENGTHS) - 1
    assert counters["rejected"] == 0 and counters["accepted"] == len(obs)
    limits = StreamLimits(clock_jump_back=1.0, episode_gap=0.5)
    record = replay_stream(StreamingSegmenter(stepper_from_checkpoint(ckpt), config), obs,
                           reception_stamps(wall), limits, receive_ns=wall, steady_ns=steady)
    assert record.events["episodes"] == len(LENGTHS) and record.events.get("clock_steps", 0) == int(beyond)
    assert rows_per_episode(record) == [n + 1 for n in LENGTHS]
    steps = [w for w in warned if "steady clock" in w]
    assert len(steps) == int(beyond)
    if beyond:
        assert f"steps {'back' if size < 0 else 'forward'} {abs(size) / 1e9:.3f} s" in steps[0]
    assert boundaries == replayed(record)[0]
    np.testing.assert_array_equal(pis, replayed(record)[1])


def test_without_a_steady_clock_a_clock_going_back_is_a_restart(ctx, ckpt: Path) -> None:
    """Under ``use_sim_time`` (no steady clock beside the stamps) a clock going back 2 s is what a
    restarted simulation is: a new episode (``clock_jumps``), as before."""
    _, obs, _, _ = arm_stream()
    wall = arm_stream(pc=ClockStep(AT, -2_000_000_000))[3]
    counters = live_array(ctx, ckpt, obs, wall, None)[2]
    assert counters["clock_jumps"] == 1 and counters["clock_steps"] == 0
    assert counters["episodes"] == len(LENGTHS) + 1
