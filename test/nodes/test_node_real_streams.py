"""ompn_node on streams the way real drivers publish them, in process, against the bag reader's rules:
joint states published while the robot idles (``idle_s``), an arm and a gripper driver on one
``joint_states`` (``joint_names`` + ``joint_merge``), a driver that leaves ``velocity`` empty."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from driver_bags import BEST_EFFORT, JOINT_STATE, MS, BagWriter, S, joint_state

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from driver_streams import ARM, GRIPPER, NOW_S, ckpts, events, idle_bag, msg, replay, stream_pos  # noqa: E402, F401
from node_in_process import active_node  # noqa: E402 (publishers that record)

from ompn_ros.data import ReaderSpec, read_episodes  # noqa: E402
from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.nodes.ompn_node_obs import JointInput  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

torch.set_num_threads(1)


def test_idle_rule_live_cuts_where_the_reader_cuts(ctx, ckpts: dict[int, Path], tmp_path: Path) -> None:  # noqa: F811 (the imported fixture)
    stream, offline = idle_bag(tmp_path, 0)
    assert len(offline.episodes) == 2
    node = active_node(ctx, ckpts[3], obs_source="joint_state", idle_s=0.5, idle_speed=0.01,
                       max_stamp_lead=0.0)
    for head, pos, vel in stream:
        node.inputs.joint_states.on_joint_state(msg(head, ARM, pos, vel))
    want, start = [], 0
    stamps = np.asarray([h for h, _, _ in stream])
    positions = stream_pos(stream)
    for e in offline.episodes:  # the episode's rows in the stream: from its first (moving) row on
        first = int(np.flatnonzero(np.all(positions == e.observations[0], axis=1))[0])
        rows = np.arange(first, first + len(e.observations))
        np.testing.assert_array_equal(positions[rows], e.observations)
        assert first > start
        start = rows[-1]
        want += replay(ckpts[3], e.observations, stamps[rows])
    assert events(node) == want
    counters = node.counters()
    assert counters["episodes"] == 2 and counters["episodes_ended"] == 2 and counters["rejected"] == 0
    assert counters["idle_trimmed"] == offline.report.bags[0].idle_trimmed
    node.destroy_node()


def test_two_publishers_merge_live_like_the_reader(ctx, ckpts: dict[int, Path], tmp_path: Path) -> None:  # noqa: F811 (the imported fixture)
    """Arm at 100 Hz, gripper at 25 Hz (from 0.1 s on) on one joint_states, in arrival order."""
    rng = np.random.default_rng(1)
    arrivals = []
    for k in range(80):
        head = NOW_S * S + k * 10 * MS
        arrivals.append((head + MS, head, ARM, rng.normal(size=3)))
        if k >= 10 and k % 4 == 2:
            arrivals.append((head + 3 * MS, head + 1_500_000, GRIPPER, rng.uniform(0, 0.04, 1)))
    arrivals.sort(key=lambda a: a[0])
    bag = BagWriter(tmp_path / "bag")
    for receive, head, names, pos in arrivals:
        bag.add("/joint_states", JOINT_STATE, receive, joint_state(head, names, pos), BEST_EFFORT)
    bag.write()
    spec = ReaderSpec.from_dict({
        "observation": {"topic": "/joint_states", "type": JOINT_STATE, "joint_names": ARM + GRIPPER,
                        "merge_s": 0.05},
        "action": {"topic": "/joint_states", "type": JOINT_STATE, "fields": ["position"],
                   "joint_names": ARM},
        "subtask": None, "sketch": None, "episode": None, "stamp": "header", "split": "bag",
        "final_observation": "drop_last_step"})
    offline = read_episodes(tmp_path / "bag", spec=spec)
    (episode,) = offline.episodes
    node = active_node(ctx, ckpts[4], obs_source="joint_state", joint_names=ARM + GRIPPER, joint_merge=0.05,
                       max_stamp_lead=0.0)
    for _, head, names, pos in arrivals:
        node.inputs.joint_states.on_joint_state(msg(head, names, pos))
    counters = node.counters()
    assert counters["accepted"] == len(episode.observations) and counters["rejected"] == 0
    assert counters["joint_missing"] == offline.report.bags[0].missing["/joint_states[finger]"] == 11
    pis = np.array([m.parse_float32_array(r) for r in node.outputs.pubs["pi"].raws])
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpts[4]), DetectorConfig(high=0.3, low=0.3))
    seg.reset(None)
    want = [seg.step(x, None).step_output.pi for x in episode.observations]
    np.testing.assert_allclose(pis[:, :3], np.asarray(want), atol=1e-6)
    node.destroy_node()


def test_empty_velocity_is_one_line_live(ctx, ckpts: dict[int, Path]) -> None:  # noqa: F811 (the imported fixture)
    node = active_node(ctx, ckpts[3], obs_source="joint_state", joint_fields=["position", "velocity"],
                       max_stamp_lead=0.0)
    warnings: list[str] = []
    node.outputs.warn_throttled = lambda text, with_total=True: warnings.append(text)  # type: ignore[method-assign]
    # positions only
    node.inputs.joint_states.on_joint_state(msg(NOW_S * S, ARM[:1] + ARM[1:], [0.1, 0.2, 0.3]))
    counters = node.counters()
    assert counters["accepted"] == 0 and counters["rejected_malformed"] == 1
    assert len(warnings) == 1 and "velocity is empty" in warnings[0] and "remove 'velocity'" in warnings[0]
    node.destroy_node()


def test_joint_input_rules() -> None:
    plain = JointInput(["position"], ARM[::-1], None)
    values = {"position": np.array([1.0, 2.0, 3.0]), "velocity": np.zeros(0), "effort": np.zeros(0)}
    assert plain.observation(0, ARM, values).tolist() == [3.0, 2.0, 1.0]
    assert "lacks joints ['j1']" in plain.observation(0, ["j2", "j3", "x"], values)
    with pytest.raises(ValueError, match="joint_names"):
        JointInput(["position"], None, 10)
