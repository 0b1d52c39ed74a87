"""Benchmark "your robot in five commands" (``examples/own_robot.py``) at full size.

``dial_sim profile:=robot`` publishes only ``jaco/joint_states``, ``jaco/effort_command`` and
``jaco/skill_id``; ``bag_recorder`` records them, the reader (``config/reader_dial_robot.yaml``) makes
episodes of joint positions and velocities (18-d), effort commands (9-d) and skill-id labels,
``ompn_train`` runs the shipped Dial training config, ``ompn_segment --tune`` chooses the online
detector settings on the training bag (objective: alignment) and ``ompn_segment`` scores held-out
episodes against the sim's skill ids.  Figures:

* ``own_robot_align``, ``own_robot_f1_tol1``: held-out alignment accuracy and boundary F1 at
  tolerance 1 of the online detector (tuned settings) and of the offline automatic threshold
  (``own_robot_offline_auto_*``; paper Alg. 1-2), from joint positions and velocities alone
  (target alignment >= 0.85);
* ``own_robot_train_episodes``, ``own_robot_steps``: what the reader made of the training bag;
* ``own_robot_<step>_s``: wall time of recording, reading, training, tuning and segmenting.

Full size: 300 training episodes, 50 held-out, the config's 300 iterations with one torch thread
(about 40 minutes on a busy 2-core machine).  Measured once (seeds 0 and 1000000, best checkpoint at
iteration 280): held-out alignment 0.927 online (tuned: falling edge, high 0.15, low 0.05) and 0.831
offline (automatic threshold); F1@1 0.25 online (3 false alarms per episode) and 0.43 offline.  The
actions are raw torques (N·m, up to ±30) that the trainer does not normalise, and joint positions and
velocities say nothing about which key comes next, which limits both.
``quick``: 20 + 5 episodes, 40 iterations (the figures then only show that the flow runs).
Run: ``.venv/bin/python bench/bench_own_robot.py [--quick]`` or ``make bench-own-robot``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import random
import sys
import tempfile
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
if not os.environ.get("ROS_DOMAIN_ID", "").isdigit() or not 1 <= int(os.environ["ROS_DOMAIN_ID"]) <= 100:
    os.environ["ROS_DOMAIN_ID"] = str(random.randint(1, 100))

Result = dict[str, tuple[float, str]]
# one torch thread: with other jobs on the CPU, two threads made training 7x slower (spin-waiting)
FULL = {"episodes": 300, "heldout": 50, "iterations": None, "threads": 1}
QUICK = {"episodes": 20, "heldout": 5, "iterations": 40, "threads": 1}


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("own_robot", ROOT / "examples" / "own_robot.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules["own_robot"] = module
    spec.loader.exec_module(module)
    return module


def run(quick: bool = False, out: Path | None = None) -> Result:
    """Run the flow (``quick``: small) and return its figures."""
    own = _example()
    size = QUICK if quick else FULL
    with tempfile.TemporaryDirectory(prefix="own_robot_") as tmp:
        flow = own.Flow(out or Path(tmp), timeout_s=4 * 3600.0, **size)
        summary = own.run(flow)
    head = summary["headline"]
    figures: Result = {
        "own_robot_align": (head.get("online.align", float("nan")), "fraction"),
        "own_robot_f1_tol1": (head.get("online.f1_tol1", float("nan")), "fraction"),
        "own_robot_offline_auto_align": (head.get("offline_auto.align", float("nan")), "fraction"),
        "own_robot_offline_auto_f1_tol1": (head.get("offline_auto.f1_tol1", float("nan")), "fraction"),
        "own_robot_train_episodes": (float(summary["train_episodes"]), "episodes"),
        "own_robot_steps": (float(summary["train_report"]["steps"]), "steps"),
    }
    for step, seconds in summary["seconds"].items():
        figures[f"own_robot_{step}_s"] = (float(seconds), "s")
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 + 5 episodes, 40 iterations")
    parser.add_argument("--out", type=Path, default=None, help="keep bags, model and plots here")
    args = parser.parse_args(argv)
    figures = run(args.quick, args.out)
    print(json.dumps({k: {"value": v, "unit": u} for k, (v, u) in figures.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
