"""A JointState whose joint count does not fit the checkpoint: one clear error at the first message
(naming the size, the source and the fix), then every such message skipped and counted, not a
warning per message."""

from __future__ import annotations

from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402
from ompn_ros.nodes.ompn_node import OMPNNode  # noqa: E402

OBS_DIM = 6


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(3)
    cfg = OMPNConfig(obs_dim=OBS_DIM, action_type="discrete", action_dim=3, n_slots=2, slot_size=8)
    path = tmp_path_factory.mktemp("size") / "ckpt"
    save_checkpoint(path, OMPNPolicy(cfg))
    return path


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
        node._on_joint_state(_joints(4, t))
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "values" in line and "obs_dim" in line]
    assert len(lines) == 1, err
    assert "[ERROR]" in lines[0] and "observation has 4 values, the model expects obs_dim=6" in lines[0]
    assert "'joint_states' fields ['position']" in lines[0] and "trained on this robot" in lines[0]
    assert node.counters()["rejected_wrong_length"] == 20
    node._on_joint_state(_joints(6, 20))  # the right size is stepped
    assert node.counters()["accepted"] == 1
    node.destroy_node()
