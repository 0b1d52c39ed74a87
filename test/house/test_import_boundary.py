"""The ROS-free core imports no rclpy: model, training, detectors, metrics, bags, environments."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ROS_SIDE = {"ompn_ros.nodes", "ompn_ros.ros", "sim_nodes.ros_common"}


def _core_modules() -> list[str]:
    modules = []
    for package in ("ompn_ros", "sim_nodes"):
        for path in sorted((ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            if any(name == r or name.startswith(r + ".") for r in ROS_SIDE) or name.endswith(".node"):
                continue
            modules.append(name)
    return modules


def test_core_modules_exist():
    modules = _core_modules()
    for expected in ("ompn_ros.model.policy", "ompn_ros.segmenter", "ompn_ros.data.reader",
                     "sim_nodes.craft.env", "sim_nodes.dial.env", "ompn_ros.metrics"):
        assert expected in modules


def test_importing_the_core_never_loads_rclpy():
    probe = (
        "import importlib, json, sys\n"
        f"mods = {_core_modules()!r}\n"
        "for m in mods:\n"
        "    importlib.import_module(m)\n"
        "ros = ('rclpy', 'rcl_interfaces')\n"
        "print(json.dumps(sorted(k for k in sys.modules if k.split('.')[0] in ros)))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True,
                            timeout=180, env=dict(os.environ))
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1]) == []
