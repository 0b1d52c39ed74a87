"""Offline replay (ompn_segment), online-vs-offline comparison and detector tuning."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("ompn_ros.model.streaming")
trainer = pytest.importorskip("ompn_ros.train.trainer")
synthetic = pytest.importorskip("ompn_ros.train.synthetic")

from ompn_ros.app import replay as cli  # noqa: E402
from ompn_ros.cli import segment as segment_cli  # noqa: E402
from ompn_ros.detect import params_file, tune  # noqa: E402
from ompn_ros.detect.online import BoundaryEvent, DetectorConfig  # noqa: E402
from ompn_ros.model.streaming import StreamingPolicy  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def ckpt(synthetic_checkpoint: Path) -> Path:
    return synthetic_checkpoint


@pytest.fixture(scope="module")
def episodes():
    return synthetic.make_dataset("discrete", 12, seed=500)


def test_compare_detectors_reports_every_metric(ckpt: Path, episodes) -> None:
    policy = StreamingPolicy.from_checkpoint(ckpt)
    # fixed-range scores of this model peak near 1/3 (middle-slot expansions): threshold below that
    online = {"fall": DetectorConfig(high=0.2), "rise": DetectorConfig(high=0.2, mode="rising_edge")}
    res = cli.compare_detectors(policy, episodes, online)
    assert {"fall", "rise", "offline_topk", "offline_auto", "offline_thr0.5"} <= set(res)
    for metrics in res.values():
        assert {
            "f1_tol0",
            "f1_tol1",
            "align",
            "align_strict",
            "delay_mean",
            "delay_max",
            "false_alarms_per_episode",
        } <= set(metrics)
        assert 0.0 <= metrics["f1_tol1"] <= 1.0
    # the trained model segments the task: both the offline Top-K and the online detector find it
    assert res["offline_topk"]["f1_tol1"] > 0.8
    assert res["fall"]["f1_tol1"] > 0.8
    # falling-edge commits come >= 1 step after the boundary step; rising-edge ones no later
    assert res["fall"]["delay_mean"] >= res["rise"]["delay_mean"]
    # offline detectors can only answer at the episode end
    assert res["offline_topk"]["delay_mean"] > res["fall"]["delay_mean"]


def test_delay_stats_by_hand() -> None:
    gt = [np.array([3, 7, 11])]
    events = [
        [
            BoundaryEvent(3, 4, 0, 0.9, 3, 0),
            BoundaryEvent(9, 10, 1, 0.9, 3, 0),
            BoundaryEvent(5, 6, 2, 0.9, 3, 0),
            BoundaryEvent(11, 11, 3, 0.9, 3, 0, final=True),
        ]
    ]
    stats = tune.delay_stats(events, gt)
    # 3 -> detected at 4 (delay 1); 7 -> step 9 or 5 within 2, first commit at 6 (delay -1)
    assert stats["delay_mean"] == pytest.approx(0.0) and stats["delay_max"] == 1
    assert stats["false_alarms_per_episode"] == 2  # 9 and 5 are > 1 step from any boundary


def _choose(policy: StreamingPolicy, episodes, grid: list[DetectorConfig], objective: str = "f1"):
    """Replay once, then grid-search the online detector on the replays (the lab's tuning)."""
    replays = cli.replay_all(policy, episodes, grid[0])
    cli.check_finite(replays, episodes)
    return tune.choose_on_replays(replays, episodes, grid, objective)


def test_choose_detector_and_write_config(ckpt: Path, episodes, tmp_path: Path) -> None:
    policy = StreamingPolicy.from_checkpoint(ckpt)
    grid = [DetectorConfig(high=h, mode=m) for h in (0.2, 0.5, 0.95) for m in ("falling_edge", "rising_edge")]
    best, metrics, comparison = _choose(policy, episodes, grid)
    assert best in grid and best.high != 0.95  # nothing crosses 0.95: only the episode end is found
    assert metrics["align_strict"] == comparison["online"]["align_strict"]
    path = params_file.write_node_config(tmp_path / "node.yaml", "craft", best, comparison, "test")
    assert params_file.load_detector_yaml(path) == best
    import yaml

    params = yaml.safe_load(path.read_text())["/**/ompn_node"]["ros__parameters"]
    assert params["domain"] == "craft" and params["detector_high"] == best.high


@pytest.mark.parametrize(("objective", "metric"), [("f1", "f1_tol1"), ("align", "align_strict")])
def test_choose_detector_maximises_its_objective(ckpt: Path, episodes, objective: str, metric: str) -> None:
    policy = StreamingPolicy.from_checkpoint(ckpt)
    grid = [DetectorConfig(high=h, mode=m) for h in (0.1, 0.3, 0.5, 0.7) for m in ("falling_edge", "peak")]
    _, metrics, _ = _choose(policy, episodes, grid, objective=objective)
    scored = cli.compare_detectors(policy, episodes, {str(i): c for i, c in enumerate(grid)})
    assert metrics[metric] == pytest.approx(max(scored[str(i)][metric] for i in range(len(grid))))
    with pytest.raises(ValueError, match="objective must be one of"):
        _choose(policy, episodes, grid, objective="recall")


def test_ompn_segment_cli_on_a_bag(ckpt: Path, episodes, tmp_path: Path) -> None:
    bag_writer = pytest.importorskip("ompn_ros.data.recorder.bag_writer")
    bag = tmp_path / "bag"
    import dataclasses

    from ompn_ros import layout

    corridor = dataclasses.replace(
        layout.CRAFT, name="corridor", obs_dim=episodes[0].observations.shape[1], action_dim=3
    )
    bag_writer.write_episodes(bag, episodes[:3], corridor)
    out = tmp_path / "out"
    det = tmp_path / "det.yaml"
    det.write_text("/**:\n  ros__parameters:\n    detector_high: 0.4\n    detector_hysteresis: 0.1\n")
    assert (
        segment_cli.main(
            [
                "--bag",
                str(bag),
                "--checkpoint",
                str(ckpt),
                "--out",
                str(out),
                "--detector-config",
                str(det),
                "--plot-episodes",
                "2",
            ]
        )
        == 0
    )
    doc = json.loads((out / "boundaries.json").read_text())
    assert doc["detector"]["high"] == 0.4 and doc["detector"]["low"] == pytest.approx(0.3)
    assert len(doc["episodes"]) == 3
    for ep_doc, ep in zip(doc["episodes"], episodes[:3], strict=True):
        assert ep_doc["true_boundaries"] == ep.boundaries.tolist()
        assert ep_doc["boundaries"][-1]["step"] == ep.length - 1
    arrays = np.load(out / "pi.npz")
    assert arrays["ep0_pi"].shape == (episodes[0].length, 3)
    np.testing.assert_allclose(arrays["ep0_pi"].sum(1), 1.0, atol=1e-5)
    metrics = json.loads((out / "metrics.json").read_text())
    assert "online" in metrics and "offline_topk" in metrics
    assert (out / "episode_0.png").stat().st_size > 1000 and (out / "episode_1.png").exists()
    assert not (out / "episode_2.png").exists()
