"""Closed-loop evaluation over ROS 2: sim (``mode:=policy``) + ``ompn_node`` + an episode monitor.

Three child processes per run (this module itself imports no rclpy):

* ``craft_sim`` / ``dial_sim`` with ``mode:=policy rate:=<sim_rate>`` (default 0 = step as soon as
  ``cmd_action`` arrives), **one sim process per episode**: episode i runs a sim with
  ``seed:=EVAL_SEED_BASE + i episodes:=1`` (map/initial pose ``derive_seed(EVAL_SEED_BASE + i, 0)``, the
  sims' seed rule) and ``wait_for_subscribers:=2`` on ``observation`` and ``episode`` so it starts only
  once ``ompn_node`` and the monitor listen and ``ompn_node``'s ``cmd_action`` publisher is matched (an
  earlier answer would be lost and the sim would hold);
* ``ompn_node`` with the checkpoint and ``done_threshold:=1.0`` so that, as in the in-process
  evaluator, it always sends the argmax env action (a DONE would end a sim episode early);
* ``episode_monitor`` (``ompn_ros/nodes/episode_monitor.py``) printing one JSON line per end marker.

Figures: ``success`` from the end marker, ``length`` = its ``steps``, return = K on success, else the
highest subtask ordinal published (subtasks completed before the last step; a subtask completed by
the very last step of a timed-out episode is not visible on the topic).  :func:`ros_eval_seeds` gives
the seeds, so :func:`ompn_ros.app.closed_loop.run_craft` with ``seeds=ros_eval_seeds(n)`` runs the
same episodes in-process.

**Why one sim per episode.**  The sim/node lockstep carries no step index: ``ompn_node`` also
answers the *final* observation of an episode, and a sim running several episodes has usually
already published the next episode's first observation when that answer arrives, so it executes the
stale command and every later step lags one observation behind (measured with ``episodes:=3
rate:=0``: every episode after the first was shifted; with ``rate:=100`` about 1 run in 5 still was,
under load).  A fresh sim process never sees the previous episode's late answer (volatile QoS).  A
robust fix belongs in the sim (count commands per published observation).  A second, rarer race
remains: ``ompn_node`` may step observation 0 before it handles the start marker, then reset again.

Children inherit ``os.environ`` (LD_LIBRARY_PATH kept) with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
and a ``ROS_DOMAIN_ID`` (kept if set).
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ompn_ros.app.closed_loop import CRAFT_EVAL_TASKS, EVAL_SEED_BASE, ClosedLoopReport, EpisodeResult
from ompn_ros.app.errors import ClosedLoopError, RosEvalError
from ompn_ros.ros.env import child_env
from sim_nodes.registry import derive_seed

SIM_MODULES = {"craft": "sim_nodes.craft.node", "dial": "sim_nodes.dial.node"}


def ros_eval_seeds(n: int, base: int = EVAL_SEED_BASE) -> list[int]:
    """Episode seeds of a ROS run: episode i is a sim started with ``seed:=base + i, episodes:=1``,
    whose episode 0 uses ``derive_seed(base + i, 0)`` (the sims' seed rule)."""
    return [derive_seed(base + i, 0) for i in range(n)]


def ros_available() -> tuple[bool, str]:
    """``(True, '')`` if rclpy and ompn_node can be imported, else ``(False, reason)``."""
    try:
        import importlib.util

        for name in ("rclpy", "ompn_ros.nodes.ompn_node", "sim_nodes.craft.node"):
            if importlib.util.find_spec(name) is None:
                return False, f"module {name} not found"
    except (ImportError, ValueError) as exc:
        return False, f"cannot locate ROS modules: {exc}"
    return True, ""


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGINT, then kill after 5 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def _tail(path: Path, limit: int = 2000) -> str:
    try:
        return path.read_text(errors="replace")[-limit:]
    except OSError:
        return ""


def _sim_args(task: str | None, sim_params: dict[str, Any], sim_rate: float) -> list[str]:
    """The ``--ros-args`` every episode's sim gets (its seed is added per episode)."""
    args = [
        "-p", "mode:=policy", "-p", f"rate:={float(sim_rate)}", "-p", "episodes:=1",
        "-p", "wait_for_subscribers:=2", "-p", "wait_topics:=['observation', 'episode']",
    ]  # fmt: skip
    if task is not None:
        args += ["-p", f"task:={task}"]
    for key, value in sim_params.items():
        args += ["-p", f"{key}:={value}"]
    return args


def _run_episodes(
    sim_cmd: list[str], node: subprocess.Popen[bytes], monitor: subprocess.Popen[bytes],
    episodes: int, seed: int, timeout: float, env: dict[str, str], stderr: Any,
) -> str:
    """One sim process per episode, each waited for up to ``timeout`` s; the first problem ('' for none)."""
    for i in range(episodes):
        sim = subprocess.Popen([*sim_cmd, "-p", f"seed:={seed + i}"], env=env,
                               stdout=subprocess.DEVNULL, stderr=stderr)
        deadline = time.monotonic() + timeout
        while sim.poll() is None and time.monotonic() < deadline:
            if node.poll() is not None or monitor.poll() not in (None, 0):
                break  # e.g. ompn_node cannot load the checkpoint: fail now, not at the timeout
            time.sleep(0.05)
        problem = ""
        if sim.poll() is None:
            _stop(sim)
            problem = f"episode {i} (sim seed:={seed + i}) did not finish within {timeout:.0f} s"
        elif sim.returncode != 0:
            problem = f"sim exited with code {sim.returncode} in episode {i}"
        if node.poll() is not None:
            problem = f"ompn_node exited with code {node.returncode}"
        if problem:
            return problem
    try:
        monitor.wait(timeout=10)
    except subprocess.TimeoutExpired:
        return "the episode monitor did not see every end marker"
    return ""


def _end_records(out_file: Path) -> list[dict[str, Any]]:
    """The monitor's JSON lines of the end markers (other lines skipped)."""
    records = []
    for line in out_file.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if rec.get("event") == "end":
            records.append(rec)
    return records


def _run_one(
    domain: str,
    checkpoint: Path,
    task: str | None,
    episodes: int,
    seed: int,
    timeout: float,
    sim_params: dict[str, Any],
    sim_rate: float,
) -> list[dict[str, Any]]:
    """One monitor + one ompn_node for the run; one sim process per episode (see module docstring)."""
    env = child_env()
    py = sys.executable
    logs = Path(tempfile.mkdtemp(prefix="ompn_closed_loop_"))
    out_file = logs / "monitor.out"
    handles = {name: (logs / f"{name}.err").open("wb") for name in ("monitor", "ompn_node", "sim")}
    monitor = subprocess.Popen(
        [py, "-m", "ompn_ros.nodes.episode_monitor", "--ros-args",
         "-p", f"episodes:={episodes}", "-p", f"timeout:={float(timeout) * episodes + 60.0}",
         "-p", f"record_actions:={'true' if domain == 'craft' else 'false'}"],
        env=env, stdout=out_file.open("wb"), stderr=handles["monitor"],
    )  # fmt: skip
    node = subprocess.Popen(
        [py, "-m", "ompn_ros.nodes.ompn_node", "--ros-args", "-p", f"checkpoint:={checkpoint}",
         "-p", f"domain:={domain}", "-p", "done_threshold:=1.0"],
        env=env, stdout=subprocess.DEVNULL, stderr=handles["ompn_node"],
    )  # fmt: skip
    sim_cmd = [py, "-m", SIM_MODULES[domain], "--ros-args", *_sim_args(task, sim_params, sim_rate)]
    try:
        problem = _run_episodes(sim_cmd, node, monitor, episodes, seed, timeout, env, handles["sim"])
    finally:
        _stop(node)
        _stop(monitor)
        for handle in handles.values():
            handle.close()
    records = _end_records(out_file)
    if problem or len(records) < episodes:
        detail = "\n".join(
            f"--- {name} stderr ---\n{_tail(logs / f'{name}.err')}"
            for name in ("ompn_node", "sim", "monitor")
        )
        raise RosEvalError(
            f"ROS closed loop ({domain}{'/' + task if task else ''}): {len(records)} of {episodes} episodes "
            f"finished; {problem or 'missing end markers'} (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, "
            f"logs in {logs})\n{detail}"
        )
    shutil.rmtree(logs, ignore_errors=True)
    return records


def run_ros_closed_loop(
    domain: str,
    checkpoint: str | Path,
    *,
    episodes: int,
    tasks: Sequence[str] = CRAFT_EVAL_TASKS,
    seed: int = EVAL_SEED_BASE,
    timeout: float = 300.0,
    sim_params: dict[str, Any] | None = None,
    record_actions: bool = False,
    sim_rate: float = 0.0,
) -> ClosedLoopReport:
    """Evaluate ``checkpoint`` over ROS (one sim process per Craft task) -> report (see module doc).

    ``record_actions`` (Craft): keep each episode's executed actions in ``EpisodeResult.actions``.
    """
    if domain not in SIM_MODULES:
        raise ClosedLoopError(f"domain must be 'craft' or 'dial', got {domain!r}")
    if not isinstance(episodes, int) or episodes < 1:
        raise ClosedLoopError(f"episodes must be a positive int, got {episodes!r}")
    ckpt = Path(checkpoint).resolve()
    if not (ckpt / "config.json").is_file():
        raise ClosedLoopError(f"{ckpt}: not a checkpoint directory (no config.json)")
    report = ClosedLoopReport(domain)
    start = time.perf_counter()
    for task in tasks if domain == "craft" else [None]:
        for rec in _run_one(domain, ckpt, task, episodes, seed, timeout, sim_params or {}, sim_rate):
            n = int(rec["n_subtasks"])
            success = bool(rec["success"])
            report.episodes.append(
                EpisodeResult(
                    domain=domain,
                    task=str(rec["task"]),
                    seed=int(rec["seed"]),
                    success=success,
                    subtasks_done=n if success else max(int(rec["max_subtask"]), 0),
                    n_subtasks=n,
                    length=int(rec["steps"]),
                    actions=[int(a) for a in rec.get("actions", [])] if record_actions else None,
                )
            )
    report.seconds = time.perf_counter() - start
    return report
