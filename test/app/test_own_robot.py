"""examples/own_robot.py, all five steps at test size: dial_sim profile:=robot recorded by bag_recorder,
read with config/reader_dial_robot.yaml, ompn_train, ompn_segment on a held-out bag, then ompn_node live
on the sim's JointState stream (episodes split by pauses), scored against the sim's skill ids."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("sim_nodes.dial.node")

from ompn_ros.data import ReaderSpec, read_episodes
from sim_nodes import derive_seed

ROOT = Path(__file__).resolve().parents[2]


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("own_robot", ROOT / "examples" / "own_robot.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules["own_robot"] = module  # dataclasses resolve the module by name
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # trains; parts run fast: test_annotate_any_bag, test_idle_user_arm, test_node_idle_auto
def test_own_robot_flow(tmp_path: Path, ros_env: dict[str, str]) -> None:
    from sim_nodes.dial import generate_episode

    own = _example()
    summary = own.run(own.Flow(tmp_path, episodes=2, heldout=2, iterations=2, seed=5, timeout_s=300,
                                threads=1, live_rate=50.0))
    assert (summary["train_episodes"], summary["heldout_episodes"]) == (2, 2)
    assert (summary["obs_dim"], summary["action_dim"]) == (18, 9)
    names = summary["obs_names"]
    assert len(names) == 18 and names[0].endswith("position/jaco_joint_1") and "velocity" in names[9]
    # the recorded episodes are the sim's demonstrations: joints, efforts and skill ids, nothing lost
    eps = read_episodes(tmp_path / "bags" / "train", spec=ReaderSpec.from_yaml(own.READER)).episodes
    for i, ep in enumerate(eps):
        demo = generate_episode(derive_seed(5, i))
        assert ep.length == demo.length
        assert np.allclose(ep.observations[:, :9], demo.extras["joint_position"], atol=1e-5)
        assert np.allclose(ep.observations[:, 9:], demo.extras["joint_velocity"], atol=1e-4)
        assert np.allclose(ep.actions, demo.extras["joint_effort"][1:], rtol=1e-5, atol=1e-4)
        ids = ep.extras["subtask_id"]
        assert [int(d) for k, d in enumerate(ids) if k == 0 or d != ids[k - 1]] == demo.sketch.tolist()
        assert np.array_equal(ep.subtask, demo.subtask)
    # held-out metrics of the online and offline detectors, all in [0, 1]
    head = summary["headline"]
    assert {"online.f1_tol1", "online.align"} <= set(head)
    assert all(0.0 <= v <= 1.0 for v in head.values()), head
    # step 5: the node ended every live episode at its pause, and its boundaries are those of the offline
    # replay of the same recording (same messages, same detector: deterministic)
    live = summary["live"]
    assert live["episodes"] == 2 and len(live["boundaries"]) == 2
    live_eps = read_episodes(tmp_path / "bags" / "live", spec=ReaderSpec.from_yaml(own.READER)).episodes
    for i, (ep, steps) in enumerate(zip(live_eps, live["boundaries"], strict=True)):
        demo = generate_episode(derive_seed(5 + own.HELDOUT_SEED, i))
        assert np.array_equal(ep.subtask, demo.subtask)  # the ground truth is the sim's
        assert steps and steps[-1] >= ep.length - 1  # the final boundary closes the episode
    assert live["agree_with_replay"] == 1.0, live["differ_from_replay"]
    assert {"f1_tol1", "align"} <= set(live["metrics"])
    assert all(0.0 <= live["metrics"][k] <= 1.0 for k in ("f1_tol1", "align"))


def test_live_and_replay_compared_on_boundaries_decided_from_the_same_steps() -> None:
    own = _example()
    # an episode of 10 steps: the replay takes steps 0..9, the node 0..10 (the final observation)
    live = [(3, 4), (7, 8), (8, 10), (10, 10)]  # (8, 10) decided once the node saw the final observation
    replay = [(3, 4), (7, 8), (9, 9)]
    assert own.decided_alike(live, 10) == own.decided_alike(replay, 10) == [3, 7]
    assert own.as_replayed([s for s, _ in live], 10) == [3, 7, 8, 9]
    assert own.decided_alike([(2, 4), (7, 8)], 10) != own.decided_alike(replay, 10)  # a real difference shows
