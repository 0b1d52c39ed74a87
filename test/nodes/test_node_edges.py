"""ompn_node in process at two edges: a JointState whose joint count does not fit the checkpoint is
one clear error at the first message (naming the size, the source and the fix), then every such
message is skipped and counted, not a warning per message; and every episode ends with a final
boundary even when the detector published its last boundary before the episode closed."""

from __future__ import annotations

from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402

OBS_DIM = 6


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(tmp_path_factory, "size", seed=3,
                             obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=2, slot_size=8)


def _joints(n: int, t: int) -> JointState:
    msg = JointState(name=[f"j{i}" for i in range(n)], position=[0.1 * i for i in range(n)])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + t, 0
    return msg


def test_a_joint_count_mismatch_is_one_error_then_counted(ctx, ckpt: Path, capfd) -> None:
    overrides = [Parameter("checkpoint", value=str(ckpt)), Parameter("obs_source", value="joint_state"),
                 Parameter("max_stamp_lead", value=0.0), Parameter("warn_throttle", value=0.0)]
    node = OMPNNode(context=ctx, parameter_overrides=overrides)
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    capfd.readouterr()
    for t in range(20):  # a 4-joint arm for a 6-value model
        node.inputs.joint_states.on_joint_state(_joints(4, t))
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "values" in line and "obs_dim" in line]
    assert len(lines) == 1, err
    assert "[ERROR]" in lines[0] and "observation has 4 values, the model expects obs_dim=6" in lines[0]
    assert "'joint_states' fields ['position']" in lines[0] and "trained on this robot" in lines[0]
    assert node.counters()["rejected_wrong_length"] == 20
    node.inputs.joint_states.on_joint_state(_joints(6, 20))  # the right size is stepped
    assert node.counters()["accepted"] == 1
    node.destroy_node()


def test_an_episode_whose_last_boundary_came_early_ends_with_one_episode_end(ctx, ckpt: Path) -> None:
    """The detector published the boundary at the episode's last step before the end marker, so the
    episode's end closes no subtask: the node publishes one EPISODE_END (final, the subtask count, no
    id), never the last boundary again (docs/design.md#episode-end)."""
    from ompn_ros.data.messages import EPISODE_END, SUBTASK_END, decode_subtask_boundary
    from ompn_ros.detect.online import BoundaryEvent

    overrides = [Parameter("checkpoint", value=str(ckpt)), Parameter("max_stamp_lead", value=0.0)]
    node = OMPNNode(context=ctx, parameter_overrides=overrides)
    ok = TransitionCallbackReturn.SUCCESS
    assert node.trigger_configure() == ok and node.trigger_activate() == ok, node.last_error
    sent: list[bytes] = []
    node.outputs.pubs["boundary"].publish = sent.append
    for t in range(3):
        # the array path: three observations, stamps 1..3 s
        node.inputs.process_observation(torch.zeros(OBS_DIM).numpy(), (t + 1) * 10**9)
    early = BoundaryEvent(step=2, detected_at=2, subtask=0, score=0.9, level=1, stamp_ns=3 * 10**9)
    node.outputs.publish_boundary(early)  # as the detector does at the done step
    closing = BoundaryEvent(step=2, detected_at=2, subtask=1, score=0.0, level=0, stamp_ns=3 * 10**9,
                            final=True, episode_end=True)  # what the detector closes it with
    node.segmenter.end_episode = lambda last_step=None: [closing]
    node.stream.close_episode(None)
    got = [decode_subtask_boundary(raw) for raw in sent]
    assert [(b.step, b.subtask, b.subtask_id, b.final, b.kind, b.decided_stamp_ns) for b in got] == [
        (2, 0, -1, False, SUBTASK_END, 3 * 10**9), (2, 1, -1, True, EPISODE_END, 3 * 10**9)]
    node.destroy_node()
