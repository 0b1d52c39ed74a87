"""``<node> --help`` prints every parameter with its default and touches nothing: no node, no files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]
NODES = {
    "ompn_node": ("ompn_ros.nodes.ompn_node", "detector_high"),
    "dial_sim": ("sim_nodes.dial.node", "press_tolerance"),
    "craft_sim": ("sim_nodes.craft.node", "full_obs"),
    "episode_monitor": ("ompn_ros.nodes.episode_monitor", "record_actions"),
    "smoke_talker": ("ompn_ros.nodes.dds_probe", "wait_for_subscriber"),
}


@pytest.mark.parametrize("name", sorted(NODES))
def test_help_lists_parameters_and_starts_nothing(name: str, tmp_path: Path, ros_env: dict[str, str]) -> None:
    module, parameter = NODES[name]
    ros_env["PYTHONPATH"] = str(ROOT)
    # a node that started would stay up (sims run forever by default): the help must return at once
    done = subprocess.run([sys.executable, "-m", module, "--help"], cwd=tmp_path, env=ros_env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert f"  {parameter} (default " in done.stdout and "usage:" in done.stdout
    assert "[INFO]" not in done.stderr and "[ERROR]" not in done.stderr  # no node was created
    assert list(tmp_path.iterdir()) == []

