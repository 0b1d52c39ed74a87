"""sim -> ompn_node -> subscriber over DDS, with the shipped checkpoint, checked against ground truth."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ompn_ros.checkpoints import MissingCheckpointError, shipped_checkpoint


def _shipped(domain: str) -> Path:
    try:
        return shipped_checkpoint(domain)
    except MissingCheckpointError as exc:  # pragma: no cover - the package ships both
        pytest.fail(str(exc))


def test_craft_sim_and_ompn_node_segment_live_against_ground_truth(tmp_path: Path, ros_env: dict[str, str]):
    checkpoint = _shipped("craft")
    result = subprocess.run(
        [sys.executable, "-m", "ompn_ros.cli.live_demo", "--domain", "craft", "--episodes", "4",
         "--rate", "50", "--seed", "2000", "--checkpoint", str(checkpoint), "--out", str(tmp_path),
         "--timeout", "120"],
        env=ros_env, capture_output=True, text=True, timeout=180,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["episodes"] == 4
    # The shipped Craft model finds most boundaries within one step, causally, over DDS.
    assert summary["f1_tol1"] >= 0.7, summary
    assert summary["align_acc"] >= 0.6, summary
    assert 0 < summary["latency_ms_p50"] < 100, summary
    assert (tmp_path / "live_episode0.png").stat().st_size > 10_000
    assert "true boundary" in result.stdout and "detected boundary: step" in result.stdout
