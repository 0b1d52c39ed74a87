"""In-process closed-loop evaluator: counts expert replays as successes, random play as failures."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ompn_ros.app.closed_loop import (
    EVAL_SEED_BASE,
    RandomAgent,
    ReplayAgent,
    eval_seeds,
    run_closed_loop,
    run_craft,
    run_dial,
)
from ompn_ros.app.errors import ClosedLoopError
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.load import build_stepper

torch.set_num_threads(1)


def test_eval_seeds_are_the_held_out_block() -> None:
    assert (
        eval_seeds(3) == [EVAL_SEED_BASE, EVAL_SEED_BASE + 1, EVAL_SEED_BASE + 2] == [10_000, 10_001, 10_002]
    )
    with pytest.raises(ClosedLoopError, match="positive"):
        eval_seeds(0)


def test_craft_expert_replay_succeeds_and_random_fails() -> None:
    from sim_nodes.craft import generate_episode

    demos = {
        task: [generate_episode(EVAL_SEED_BASE + i, task=task) for i in range(3)]
        for task in ("makebed", "makeaxe")
    }
    for task, eps in demos.items():
        replay = ReplayAgent([ep.actions for ep in eps], fallback=5)
        report = run_craft(replay, tasks=[task], seeds=[ep.seed for ep in eps])
        s = report.summary()
        assert s["success_rate"] == 1.0 and s["mean_return"] == 4.0, (task, report.episodes)
        assert [r.length for r in report.episodes] == [ep.length for ep in eps]
    # one replayed action sequence truncated by two steps can no longer reach the goal
    ep = demos["makebed"][0]
    short = run_craft(ReplayAgent([ep.actions[:-2]], fallback=5), tasks=["makebed"], seeds=[ep.seed])
    assert short.summary()["success_rate"] == 0.0 and short.episodes[0].length == 64
    assert short.episodes[0].subtasks_done == 3

    rand = run_craft(RandomAgent(n_actions=5, seed=1), episodes=4, tasks=["makebed", "makeaxe"])
    s = rand.summary()
    assert s["episodes"] == 8 and s["success_rate"] <= 0.25 and s["mean_return"] < 2.0
    assert all(r.length == 64 for r in rand.episodes if not r.success)


def test_dial_expert_replay_succeeds_and_random_scores_low() -> None:
    from sim_nodes.dial import generate_episode

    eps = [generate_episode(EVAL_SEED_BASE + i, noise=0.0) for i in range(2)]
    assert all(ep.success for ep in eps)
    replay = ReplayAgent([ep.actions for ep in eps], fallback=np.zeros(9, np.float32))
    report = run_dial(replay, seeds=[ep.seed for ep in eps], sketches=[ep.sketch for ep in eps])
    s = report.summary()
    assert s["success_rate"] == 1.0 and s["mean_return"] == 4.0, report.episodes
    rand = run_dial(RandomAgent(action_dim=9, seed=0), episodes=2, max_steps_per_subtask=60)
    r = rand.summary()
    assert r["success_rate"] == 0.0 and r["mean_return"] < 1.0 and r["mean_length"] == 60


@pytest.mark.parametrize("arch", ["ompn", "lstm"])
def test_trained_format_policies_run_in_the_loop(arch: str) -> None:
    cfg = OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5, n_slots=2, slot_size=16,
                     sketch_mode="sum", sketch_vocab=9, arch=arch)  # type: ignore[arg-type]  # fmt: skip
    stepper = build_stepper(build_policy(cfg))
    report = run_closed_loop("craft", stepper, episodes=2, tasks=["makebed"], record_actions=True)
    assert len(report.episodes) == 2
    for ep in report.episodes:
        assert ep.actions is not None and len(ep.actions) == ep.length
        assert all(0 <= a < 5 for a in ep.actions)  # DONE is never chosen in free run
    # sketch-free models are reset without a sketch
    cfg_none = OMPNConfig(
        obs_dim=1075, action_type="discrete", action_dim=5, n_slots=2, slot_size=16, arch=arch
    )  # type: ignore[arg-type]
    run_craft(build_stepper(build_policy(cfg_none)), episodes=1, tasks=["makeaxe"])


def test_bad_arguments() -> None:
    with pytest.raises(ClosedLoopError, match="domain"):
        run_closed_loop("chess", RandomAgent(n_actions=5), episodes=1)
    with pytest.raises(ClosedLoopError, match="unknown Craft tasks"):
        run_craft(RandomAgent(n_actions=5), episodes=1, tasks=["makepizza"])
    with pytest.raises(ClosedLoopError, match="sketches"):
        run_dial(RandomAgent(action_dim=9), seeds=[1, 2], sketches=[[1, 2, 3, 4]])


def test_cli_writes_json(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from ompn_ros.cli.closed_loop import main

    cfg = OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5, n_slots=2, slot_size=16,
                     sketch_mode="sum", sketch_vocab=9, arch="lstm")  # fmt: skip
    save_checkpoint(tmp_path / "ck", build_policy(cfg))
    out = tmp_path / "res.json"
    code = main(["--domain", "craft", "--checkpoint", str(tmp_path / "ck"), "--episodes", "2",
                 "--tasks", "makebed", "--json", str(out), "--baselines"])  # fmt: skip
    assert code == 0
    doc = json.loads(out.read_text())
    assert len(doc["results"]) == 2 and "random" in doc["results"]
    name = next(k for k in doc["results"] if k != "random")
    assert name.startswith("lstm:") and doc["models"][name]["config"]["arch"] == "lstm"
    assert doc["results"][name]["summary"]["episodes"] == 2
    assert doc["seeds"] == [10_000, 10_001]
    assert "success" in capsys.readouterr().out
    assert main(["--domain", "craft", "--checkpoint", str(tmp_path / "missing")]) == 2
