"""Benchmark "your robot in five commands" (``examples/own_robot.py``) at full size, step 5 live included.

``dial_sim profile:=robot`` publishes only ``jaco/joint_states``, ``jaco/effort_command`` and
``jaco/skill_id``; ``bag_recorder`` records them, the reader (``config/reader_dial_robot.yaml``) makes
episodes of joint positions and velocities (18-d), effort commands (9-d) and skill-id labels,
``ompn_train`` runs the shipped Dial training config, ``ompn_segment --tune`` chooses the online
detector settings on the training bag (objective: alignment) and ``ompn_segment`` scores held-out
episodes against the sim's skill ids.  Step 5 runs the sim again on the held-out seeds at 25 Hz with
``ompn_node`` on its JointState stream (``episode_gap`` splits the episodes at the pauses) and scores
the recorded ``~/boundary`` events.  Figures:

* ``own_robot_align``, ``own_robot_f1_tol1``: held-out alignment accuracy and boundary F1 at
  tolerance 1 of the online detector (tuned settings) and of the offline automatic threshold
  (``own_robot_offline_auto_*``; paper Alg. 1-2), from joint positions and velocities alone
  (target alignment >= 0.85); ``own_robot_val_*``: the same on the validation split (best checkpoint);
* ``own_robot_live_align``, ``own_robot_live_f1_tol1``: the live node's boundaries, and
  ``own_robot_live_agree_with_replay``: the fraction of live episodes whose boundaries equal the
  replay of the same recording (those decided before the episode's last step, which both take alike);
* ``own_robot_train_episodes``, ``own_robot_steps``: what the reader made of the training bag;
* ``own_robot_<step>_s``: wall time of recording, reading, training, tuning, segmenting and step 5.

Full size: 300 training episodes, 50 held-out, a fixed 300 iterations with one torch thread.
Measured (seeds 0 and 1000000, docs/experiments.md §25): alignment 0.927 online (live: the same,
every live episode equal to the replay) and 0.831 offline; F1@1 0.25 online, 0.43 offline: the
online boundaries lie a steady 4 steps after the skill-id change.  ``--action-norm standard``
(torques standardised per joint) gave 0.637 / 0.22 and lost on the validation split too.
A full run writes the table rows to ``results/own_robot.json`` (keeping the other variant's row).
``quick``: 20 + 5 episodes, 40 iterations (the figures then only show that the flow runs).
Run: ``.venv/bin/python bench/bench_own_robot.py [--quick]`` or ``make bench-own-robot``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lab.spec import DEFAULT_EPISODES  # noqa: E402

# DDS containment (loopback and shared memory, a domain in 1..100) is applied to every child
# process by the example (ompn_ros.ros.containment); this process itself starts no ROS node.

Result = dict[str, tuple[float, str]]
# one torch thread: with other jobs on the CPU, two threads made training 7x slower (spin-waiting)
FULL: dict[str, Any] = {"episodes": 300, "heldout": 50, "iterations": 300, "threads": 1,
                        "action_norm": "none", "live_rate": 25.0}
QUICK: dict[str, Any] = {"episodes": 20, "heldout": 5, "iterations": 40, "threads": 1,
                         "action_norm": "none", "live_rate": 25.0}
REFERENCE = ROOT / "results" / "dial.json"  # the 39-d observation, shipped-data reproduction
REFERENCE_EXTRAS = ROOT / "results" / "dial_extras.json"
RESULTS = ROOT / "results" / "own_robot.json"


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("own_robot", ROOT / "examples" / "own_robot.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules["own_robot"] = module
    spec.loader.exec_module(module)
    return module


def run(quick: bool = False, out: Path | None = None, results: Path | None = None,
        action_norm: str = "none") -> Result:
    """Run the flow (``quick``: small) and return its figures; ``results``: also write the rows of
    ``results/own_robot.json`` there."""
    own = _example()
    size = {**(QUICK if quick else FULL), "action_norm": action_norm}
    with tempfile.TemporaryDirectory(prefix="own_robot_") as tmp:
        flow = own.Flow(out or Path(tmp), timeout_s=4 * 3600.0, **size)
        summary = own.run(flow)
        val = json.loads((Path(summary["checkpoint"]).parent / "summary.json").read_text())["best"]
    if results is not None:
        doc = results_doc(summary, size, val, " ".join(["bench/bench_own_robot.py", *sys.argv[1:]]))
        if results.is_file():  # keep the other action_norm's 18-d row of an earlier run
            old = json.loads(results.read_text()).get("rows", [])
            doc["rows"][1:1] = [r for r in old if r.get("obs_dim") == summary["obs_dim"]
                                and r.get("action_norm") != size["action_norm"]]
        results.write_text(json.dumps(doc, indent=1) + "\n")
    head = summary["headline"]
    figures: Result = {
        "own_robot_align": (head.get("online.align", float("nan")), "fraction"),
        "own_robot_f1_tol1": (head.get("online.f1_tol1", float("nan")), "fraction"),
        "own_robot_offline_auto_align": (head.get("offline_auto.align", float("nan")), "fraction"),
        "own_robot_offline_auto_f1_tol1": (head.get("offline_auto.f1_tol1", float("nan")), "fraction"),
        "own_robot_train_episodes": (float(summary["train_episodes"]), "episodes"),
        "own_robot_steps": (float(summary["train_report"]["steps"]), "steps"),
    }
    figures["own_robot_val_align"] = (float(val["align"]), "fraction")  # validation split, auto threshold
    figures["own_robot_val_f1_tol1"] = (float(val["f1_tol1"]), "fraction")
    live = summary["live"]
    if live is not None:
        figures["own_robot_live_align"] = (float(live["metrics"]["align"]), "fraction")
        figures["own_robot_live_f1_tol1"] = (float(live["metrics"]["f1_tol1"]), "fraction")
        figures["own_robot_live_agree_with_replay"] = (float(live["agree_with_replay"]), "fraction")
    for step, seconds in summary["seconds"].items():
        figures[f"own_robot_{step}_s"] = (float(seconds), "s")
    return figures


def _cpu() -> str:
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return "unknown"
    names = [ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")]
    return f"{names[0] if names else 'unknown'} x{len(names)}"


def reference_row() -> dict[str, Any] | None:
    """The 39-d row from ``results/dial.json`` (NoSketch, mean over its seeds) and the test-set size
    from ``results/dial_extras.json`` (of ``DEFAULT_EPISODES['dial']`` episodes); None without them."""
    if not (REFERENCE.is_file() and REFERENCE_EXTRAS.is_file()):
        return None
    ref = json.loads(REFERENCE.read_text())["nosketch"]
    n_test = int(json.loads(REFERENCE_EXTRAS.read_text())["meta"]["n_test"]["full"])
    return {
        "observation": "39-d Dial observation (shipped-data reproduction, NoSketch; results/dial.json, "
                       f"mean of {ref['online_align']['n']} seeds)",
        "obs_dim": 39, "train_episodes": DEFAULT_EPISODES["dial"] - n_test, "test_episodes": n_test,
        "action_norm": "none",
        "online_f1_1": ref["online_f1_tol1"]["mean"], "online_align": ref["online_align"]["mean"],
        "offline_f1_1": ref["f1_tol1"]["mean"], "offline_align": ref["align"]["mean"],
        "live_f1_1": None, "live_align": None,
    }


def results_doc(summary: dict[str, Any], size: dict[str, Any], val: dict[str, Any],
                command: str) -> dict[str, Any]:
    """``results/own_robot.json``: this run's row (18-d joint positions and velocities) and, from
    ``results/dial.json``, the 39-d reference row (shipped data, NoSketch, mean over its seeds)."""
    head, live = summary["headline"], summary["live"]
    rows: list[dict[str, Any]] = [{
        "observation": f"joint positions + velocities (JointState, robot profile; action_norm "
                       f"{size['action_norm']})",
        "obs_dim": summary["obs_dim"], "train_episodes": summary["train_episodes"],
        "test_episodes": summary["heldout_episodes"], "action_norm": size["action_norm"],
        "online_f1_1": head.get("online.f1_tol1"), "online_align": head.get("online.align"),
        "offline_f1_1": head.get("offline_auto.f1_tol1"), "offline_align": head.get("offline_auto.align"),
        "live_f1_1": None if live is None else live["metrics"]["f1_tol1"],
        "live_align": None if live is None else live["metrics"]["align"],
        "val_f1_1": val.get("f1_tol1"), "val_align": val.get("align"), "command": command,
    }]
    reference = reference_row()
    if reference is not None:
        rows.append(reference)
    meta = {"command": command, "date": time.strftime("%Y-%m-%d", time.gmtime()), "cpu": _cpu(),
            "torch_threads": size["threads"], "live_rate_hz": size["live_rate"],
            "seeds": {"train": 0, "heldout": 1_000_000}, "seconds": summary["seconds"],
            "live_agree_with_replay": None if live is None else live["agree_with_replay"]}
    return {"meta": meta, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 + 5 episodes, 40 iterations")
    parser.add_argument("--out", type=Path, default=None, help="keep bags, model and plots here")
    parser.add_argument("--results", default=None,
                        help="write the table rows here (default: results/own_robot.json at full size, "
                        "nothing with --quick; '' = nothing)")
    parser.add_argument("--action-norm", choices=("none", "standard"), default="none",
                        help="train.action_norm (none: chosen on the validation split, "
                        "docs/experiments.md §25)")
    args = parser.parse_args(argv)
    results = args.results if args.results is not None else ("" if args.quick else str(RESULTS))
    figures = run(args.quick, args.out, Path(results) if results else None, args.action_norm)
    print(json.dumps({k: {"value": v, "unit": u} for k, (v, u) in figures.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
