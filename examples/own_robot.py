"""Your robot in five commands: record an arm's own topics, read them, train, segment (then run live).

``dial_sim``'s robot profile stands in for another lab's arm: it publishes only ``jaco/joint_states``
(``sensor_msgs/JointState``), ``jaco/effort_command`` (``std_msgs/Float64MultiArray``) and
``jaco/skill_id`` (``std_msgs/Int32``, the digit being pressed: an id), no episode markers and no
sketch, with pauses of at least 1 s between episodes (see ``sim_nodes/dial/node.py``).  The commands,
printed as they run::

    # 1. record (twice: training episodes, then held-out episodes from other seeds)
    bag_recorder --ros-args -p output:=OUT/bags/train \\
        -p topics:="['jaco/joint_states','jaco/skill_id','jaco/effort_command']" &
    dial_sim --ros-args -p profile:=robot -p rate:=0.0 -p joint_states_qos:=reliable \\
        -p episodes:=N -p seed:=0 -p wait_for_subscribers:=1
    kill -INT %1
    # 2. read: observation = JointState position + velocity, action = effort command,
    #    labels = skill ids, episodes split at the pauses (what ompn_train and ompn_segment do)
    #    -> config/reader_dial_robot.yaml
    # 3. train
    ompn_train --bags OUT/bags/train --config config/train_dial.yaml --out OUT/model \\
        --set data.domain=null --set data.reader_spec=config/reader_dial_robot.yaml
    # 4. tune the online detector on the training bag, then segment the held-out episodes
    #    against the sim's skill ids (prints F1 and alignment of the online and offline detectors)
    ompn_segment --tune --objective align --bag OUT/bags/train --checkpoint OUT/model/best \\
        --reader-config config/reader_dial_robot.yaml --write-config OUT/ompn_node_robot.yaml
    ompn_segment --bag OUT/bags/heldout --checkpoint OUT/model/best --reader-config \\
        config/reader_dial_robot.yaml --detector-config OUT/ompn_node_robot.yaml --out OUT/segment
    # 5. live: the sim on the held-out seeds again, ompn_node on jaco/joint_states with the reader's
    #    assemble block and its time_gap as episode_gap (no markers: episodes end at the pauses);
    #    bag_recorder keeps the node's ~/boundary with the sim's topics, scored against the skill ids
    bag_recorder --ros-args -p output:=OUT/bags/live \
        -p topics:="['jaco/joint_states','jaco/skill_id','jaco/effort_command','ompn_node/boundary']" &
    ompn_node --ros-args -p checkpoint:=OUT/model/best -p observation_spec:=config/reader_dial_robot.yaml \
        -p episode_gap:=0.5 -p obs_qos:=reliable -p boundary_replay:=none &  # detector: step 4's tuning
    # (start the sim once the recorder has logged 'subscribed .../ompn_node/boundary')
    dial_sim --ros-args -p profile:=robot -p rate:=25.0 -p joint_states_qos:=reliable \
        -p episodes:=N -p seed:=1000000 -p wait_for_subscribers:=2 -p "wait_topics:=['jaco/joint_states']"

``rate:=0`` runs the sim as fast as it can; its JointState publisher is then made RELIABLE
(``joint_states_qos:=reliable``): the recorder subscribes RELIABLE, and a best-effort publisher in
bursts would lose messages.  A real arm publishing at its own rate needs neither.  Step 5 runs the
sim at 25 Hz (real time, ``--live-rate``).  Live, the node cannot know that a JointState is an
episode's last one: it closes the episode at the last step it saw (``T``, the final observation),
which is scored as ``T - 1`` exactly as ``ompn_segment``'s replay closes it; the live boundaries are
compared with ``ompn_segment`` on the same live recording (the offline replay of the same stream) on
those decided before the episode's last step, which both take alike (:func:`decided_alike`).

Run: ``python examples/own_robot.py --out runs/own_robot [--episodes 300 --heldout 50]`` (or
``examples/own_robot.sh``).  Every process runs DDS on loopback and shared memory only
(``ompn_ros.ros.containment``), in a namespace of its own.  Exit code 2 with one line on a known failure.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from ompn_ros import layout  # noqa: E402
from ompn_ros.data import ReaderSpec, ReadResult, read_episodes  # noqa: E402
from ompn_ros.data.episode import Episode  # noqa: E402
from ompn_ros.data.messages import decode_subtask_boundary  # noqa: E402
from ompn_ros.detect.tune import score_predictions  # noqa: E402
from ompn_ros.ros import containment  # noqa: E402

READER = ROOT / "config" / "reader_dial_robot.yaml"
TRAIN_CONFIG = ROOT / "config" / "train_dial.yaml"
TOPICS = ("jaco/joint_states", "jaco/skill_id", "jaco/effort_command")
LIVE_BOUNDARY = f"ompn_node/{layout.BOUNDARY.removeprefix('~/')}"  # the node's ~/boundary, recorded live
OBS_DIM = 18  # 9 joint positions + 9 joint velocities
ACTION_DIM = 9  # 9 effort commands
HELDOUT_SEED = 1_000_000  # held-out episodes come from seeds the training bag never used


class OwnRobotError(RuntimeError):
    """A step of the flow failed (the message names the step and the reason)."""


@dataclass(frozen=True)
class Flow:
    """Where and how big: output directory, episodes to record, training iterations."""

    out: Path
    episodes: int = 300
    heldout: int = 50
    iterations: int | None = None  # None: the training config's own
    seed: int = 0
    timeout_s: float = 3600.0
    threads: int | None = None  # torch threads of ompn_train (None: the config's); 1 on a busy machine
    live: bool = True  # step 5: run ompn_node live on the held-out seeds
    live_rate: float = 25.0  # Hz of the sim in step 5 (25 = real time)
    action_norm: str | None = None  # train.action_norm (None: the training config's)


def ros_env() -> dict[str, str]:
    """This environment (LD_LIBRARY_PATH included) with DDS kept on this machine, in domain 1..100."""
    env = dict(os.environ)
    containment.contain(env)  # loopback and shared memory only, a ROS_DOMAIN_ID in 1..100
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def _command(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def _show(step: str, argv: Sequence[str]) -> None:
    print(f"[own_robot] {step}: " + " ".join(argv[2:] if argv[:2] == [sys.executable, "-m"] else argv),
          file=sys.stderr, flush=True)


def record(flow: Flow, name: str, episodes: int, seed: int, env: dict[str, str]) -> Path:
    """Step 1: ``bag_recorder`` on the three topics while ``dial_sim profile:=robot`` runs ``episodes``."""
    bag = flow.out / "bags" / name
    ns = f"/own_robot_{uuid.uuid4().hex[:8]}"  # a namespace of its own: no cross-talk with other graphs
    topics = "[" + ",".join(f"'{t}'" for t in TOPICS) + "]"
    rec_argv = _command("ompn_ros.nodes.bag_recorder", "--ros-args", "-r", f"__ns:={ns}",
                        "-p", f"output:={bag}", "-p", f"topics:={topics}")
    sim_argv = _command("sim_nodes.dial.node", "--ros-args", "-r", f"__ns:={ns}", "-p", "profile:=robot",
                        "-p", "rate:=0.0", "-p", "joint_states_qos:=reliable", "-p", f"episodes:={episodes}",
                        "-p", f"seed:={seed}", "-p", "wait_for_subscribers:=1")
    _show("record", rec_argv)
    recorder = subprocess.Popen(rec_argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True)
    sim = None
    try:
        _show("record", sim_argv)
        sim = subprocess.Popen(sim_argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        sim_out, _ = sim.communicate(timeout=flow.timeout_s)
        if sim.returncode != 0:
            raise OwnRobotError(f"record: dial_sim exited with {sim.returncode}: {sim_out.strip()[-300:]}")
        time.sleep(0.5)  # let the recorder drain its queues
        recorder.send_signal(signal.SIGINT)
        rec_out, _ = recorder.communicate(timeout=30)
    except subprocess.TimeoutExpired as err:
        raise OwnRobotError(f"record: {err}") from err
    finally:
        for proc in (sim, recorder):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    if recorder.returncode != 0 or not bag.exists():
        raise OwnRobotError(f"record: bag_recorder exited with {recorder.returncode}: "
                            f"{rec_out.strip()[-300:]}")
    return bag


def read(bag: Path) -> ReadResult:
    """Step 2: the bag's episodes under ``config/reader_dial_robot.yaml`` (dims and labels checked)."""
    result = read_episodes(bag, spec=ReaderSpec.from_yaml(READER), on_error="raise")
    print(result.report.summary(), file=sys.stderr)
    for i, ep in enumerate(result.episodes):
        if ep.observations.shape[1] != OBS_DIM or ep.actions.shape[1:] != (ACTION_DIM,):
            raise OwnRobotError(f"read: episode {i} has observations {ep.observations.shape} and actions "
                                f"{ep.actions.shape}, expected {OBS_DIM} and {ACTION_DIM} per step")
        if ep.subtask is None:
            raise OwnRobotError(f"read: episode {i} has no labels (jaco/skill_id missing?)")
    return result


def train(flow: Flow, bag: Path, env: dict[str, str]) -> Path:
    """Step 3: ``ompn_train`` on the training bag; returns the best checkpoint directory."""
    out = flow.out / "model"
    argv = _command("ompn_ros.cli.train", "--bags", str(bag), "--config", str(TRAIN_CONFIG),
                    "--out", str(out), "--overwrite", "--quiet",
                    "--set", "data.domain=null", "--set", f"data.reader_spec={READER}")
    if flow.iterations is not None:
        every = max(1, min(20, flow.iterations))  # a short run is evaluated once, at its end
        argv += ["--set", f"train.iterations={flow.iterations}", "--set", f"train.eval_every={every}",
                 "--set", "train.patience=0"]  # a given length is a fixed length
    if flow.threads is not None:
        argv += ["--set", f"train.threads={flow.threads}"]
    if flow.action_norm is not None:
        argv += ["--set", f"train.action_norm={flow.action_norm}"]
    _show("train", argv)
    _run(argv, env, flow.timeout_s, "train")
    if not (out / "best").is_dir():
        raise OwnRobotError(f"train: no checkpoint in {out / 'best'}")
    return out / "best"


def tune(flow: Flow, bag: Path, checkpoint: Path, env: dict[str, str]) -> Path:
    """Step 4a: ``ompn_segment --tune`` on the training bag: online detector settings for this checkpoint
    (objective: alignment, as for Dial), written as an ``ompn_node`` params file."""
    out = flow.out / "ompn_node_robot.yaml"
    argv = _command("ompn_ros.cli.segment", "--tune", "--objective", "align", "--bag", str(bag),
                    "--checkpoint", str(checkpoint), "--reader-config", str(READER),
                    "--write-config", str(out))
    _show("tune", argv)
    _run(argv, env, flow.timeout_s, "tune")
    return out


def segment(flow: Flow, bag: Path, checkpoint: Path, detector: Path | None,
            env: dict[str, str], name: str = "segment") -> dict[str, Any]:
    """Step 4b: ``ompn_segment`` on the held-out bag; returns its metrics (online and offline detectors)."""
    out = flow.out / name
    argv = _command("ompn_ros.cli.segment", "--bag", str(bag), "--checkpoint", str(checkpoint),
                    "--reader-config", str(READER), "--out", str(out), "--plot-episodes", "2")
    if detector is not None:
        argv += ["--detector-config", str(detector)]
    _show("segment", argv)
    _run(argv, env, flow.timeout_s, "segment")
    path = out / "metrics.json"
    if not path.is_file():
        raise OwnRobotError(f"segment: {path} was not written (no labels in the held-out bag?)")
    metrics: dict[str, Any] = json.loads(path.read_text())
    return metrics


def live_command(checkpoint: Path) -> str:
    """Step 5, what to run on the live arm: ``ompn_node`` on the ``jaco/joint_states`` stream with the
    trained checkpoint (the detector tuned in step 4 is in its ``detector.json``), the reader's
    ``assemble:`` block (the same observation rule live) and its ``time_gap`` as ``episode_gap``
    (episodes end at pauses)."""
    return (f"ompn_node --ros-args -p checkpoint:={checkpoint} -p observation_spec:={READER} "
            f"-p episode_gap:={ReaderSpec.from_yaml(READER).time_gap}")


def live(flow: Flow, checkpoint: Path, env: dict[str, str]) -> Path:
    """Step 5: ``dial_sim`` on the held-out seeds at ``live_rate``, ``ompn_node`` on its
    ``jaco/joint_states`` (detector: the checkpoint's ``detector.json``, tuned in step 4) and
    ``bag_recorder`` keeping the node's ``~/boundary`` with the sim's topics; returns the live bag."""
    bag = flow.out / "bags" / "live"
    ns = f"/own_robot_{uuid.uuid4().hex[:8]}"
    gap = ReaderSpec.from_yaml(READER).time_gap
    topics = "[" + ",".join(f"'{t}'" for t in (*TOPICS, LIVE_BOUNDARY)) + "]"
    rec_argv = _command("ompn_ros.nodes.bag_recorder", "--ros-args", "-r", f"__ns:={ns}",
                        "-p", f"output:={bag}", "-p", f"topics:={topics}")
    node_argv = _command("ompn_ros.nodes.ompn_node", "--ros-args", "-r", f"__ns:={ns}",
                         "-p", f"checkpoint:={checkpoint}", "-p", f"observation_spec:={READER}",
                         "-p", f"episode_gap:={gap}", "-p", "obs_qos:=reliable", "-p", "qos_depth:=1000",
                         "-p", "boundary_replay:=none")
    sim_argv = _command("sim_nodes.dial.node", "--ros-args", "-r", f"__ns:={ns}", "-p", "profile:=robot",
                        "-p", f"rate:={flow.live_rate}", "-p", "joint_states_qos:=reliable",
                        "-p", f"episodes:={flow.heldout}", "-p", f"seed:={flow.seed + HELDOUT_SEED}",
                        "-p", "wait_for_subscribers:=2", "-p", "wait_topics:=['jaco/joint_states']")
    logs = {name: flow.out / f"live_{name}.log" for name in ("recorder", "ompn_node", "dial_sim")}
    procs: dict[str, subprocess.Popen[str]] = {}
    try:
        for name, step_argv in (("recorder", rec_argv), ("ompn_node", node_argv), ("dial_sim", sim_argv)):
            if name == "dial_sim":  # the first boundary must not come before the recorder takes it
                _wait_subscribed(procs, logs, f"{ns}/{LIVE_BOUNDARY}", flow.timeout_s)
            _show("live", step_argv)
            with logs[name].open("w") as log:  # a file, not a pipe: a chatty node never blocks on it
                procs[name] = subprocess.Popen(step_argv, env=env, stdout=log, stderr=subprocess.STDOUT,
                                               text=True)
        _wait_live(procs, logs, flow.timeout_s)
        time.sleep(2 * gap + 1.0)  # the node's silence timer ends the last episode
        for name in ("recorder", "ompn_node"):  # the recorder drains and closes the bag, then the node
            procs[name].send_signal(signal.SIGINT)
            procs[name].wait(timeout=30)
    except subprocess.TimeoutExpired as err:
        raise OwnRobotError(f"live: {err}") from err
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    if procs["recorder"].returncode != 0 or not bag.exists():
        raise OwnRobotError(f"live: bag_recorder exited with {procs['recorder'].returncode}: "
                            f"{_tail(logs['recorder'])}")
    return bag


def _tail(path: Path) -> str:
    lines = path.read_text(errors="replace").strip().splitlines() if path.is_file() else []
    return lines[-1] if lines else ""


def _wait_until(done: Callable[[], bool], procs: dict[str, subprocess.Popen[str]], logs: dict[str, Path],
                timeout_s: float, what: str) -> None:
    """Until ``done()``; a recorder or node that exits first, or the timeout, fails the step."""
    deadline = time.monotonic() + timeout_s
    while not done():
        for name in ("recorder", "ompn_node"):
            if procs[name].poll() is not None:
                raise OwnRobotError(f"live: {name} exited with {procs[name].returncode} before {what}: "
                                    f"{_tail(logs[name])}")
        if time.monotonic() > deadline:
            raise OwnRobotError(f"live: {what} took more than {timeout_s:.0f} s")
        time.sleep(0.1)


def _wait_subscribed(procs: dict[str, subprocess.Popen[str]], logs: dict[str, Path], topic: str,
                     timeout_s: float) -> None:
    """Until the recorder logs its subscription to ``topic``: it finds topics by discovery, and the
    node's ``~/boundary`` (volatile here) appears only once the node is configured, so a sim started
    before that could see its first boundaries published to no recorder."""
    line = f"subscribed {topic} ["
    _wait_until(lambda: line in logs["recorder"].read_text(errors="replace"), procs, logs, timeout_s,
                f"the recorder subscribed {topic} (see {logs['recorder']})")


def _wait_live(procs: dict[str, subprocess.Popen[str]], logs: dict[str, Path], timeout_s: float) -> None:
    """Until the sim has run its episodes; a recorder or node that exits first fails the step."""
    _wait_until(lambda: procs["dial_sim"].poll() is not None, procs, logs, timeout_s,
                f"the sim finished (see {logs['dial_sim']})")
    if procs["dial_sim"].returncode != 0:
        raise OwnRobotError(f"live: dial_sim exited with {procs['dial_sim'].returncode}: "
                            f"{_tail(logs['dial_sim'])}")


def live_boundaries(bag: Path) -> list[list[tuple[int, int]]]:
    """The node's ``~/boundary`` events in the live bag, one list of (step, decided step) per episode
    (an episode ends with its ``final`` event)."""
    from rosbags.rosbag2 import Reader

    episodes: list[list[tuple[int, int]]] = [[]]
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic.endswith("/" + LIVE_BOUNDARY)]
        for _, _, raw in reader.messages(connections=conns):
            event = decode_subtask_boundary(raw)  # ompn_interfaces/msg/SubtaskBoundary
            episodes[-1].append((int(event.step), int(event.decided_step)))
            if event.final:
                episodes.append([])
    return episodes[:-1] if not episodes[-1] else episodes


def as_replayed(steps: Sequence[int], length: int) -> list[int]:
    """Live boundary steps as the replay scores them: the node closes an episode at the last step it
    saw (``T``, the final observation, since nothing marks it); the replay closes it at ``T - 1`` and
    drops a boundary on the final observation."""
    return sorted({s for s in steps if s <= length - 1} | {length - 1})


def decided_alike(events: Sequence[tuple[int, int]], length: int) -> list[int]:
    """The steps of the boundaries decided at steps ``<= length - 2``: a causal detector has taken the
    same steps there live and in the replay.  After that the node takes two more (the episode's last
    step and its final observation), the replay one, and each closes the episode where it stopped, so
    what is decided then (the boundary head's last ``lag`` steps, the duration decoder's open
    segments) may differ."""
    return [step for step, decided in events if decided <= length - 2]


def score_live(bag: Path, replay_dir: Path) -> dict[str, Any]:
    """Live boundaries against the skill ids of the same recording (read with the reader spec), and
    per-episode agreement with ``ompn_segment``'s replay of that recording (``replay_dir``) on the
    boundaries both decide from the same steps (:func:`decided_alike`)."""
    episodes: list[Episode] = read(bag).episodes
    events = live_boundaries(bag)
    if len(events) != len(episodes):
        raise OwnRobotError(f"live: the node ended {len(events)} episodes, the recording has {len(episodes)}")
    preds = [as_replayed([s for s, _ in e], ep.length) for e, ep in zip(events, episodes, strict=True)]
    replayed = json.loads((replay_dir / "boundaries.json").read_text())["episodes"]
    differ = {}  # episode index: (live, replay) boundaries where they differ
    for i, (e, r, ep) in enumerate(zip(events, replayed, episodes, strict=True)):
        pair = (decided_alike(e, ep.length),
                decided_alike([(int(b["step"]), int(b["detected_at"])) for b in r["boundaries"]], ep.length))
        if pair[0] != pair[1]:
            differ[i] = pair
    scored = score_predictions([np.asarray(p, dtype=np.int64) for p in preds], episodes)
    return {"episodes": len(episodes), "metrics": scored, "boundaries": [[s for s, _ in e] for e in events],
            "agree_with_replay": 1.0 - len(differ) / len(episodes), "differ_from_replay": differ}


def _run(argv: list[str], env: dict[str, str], timeout: float, step: str) -> None:
    try:
        proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired as err:
        raise OwnRobotError(f"{step}: timed out after {timeout:.0f} s") from err
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        raise OwnRobotError(f"{step}: exit code {proc.returncode}: {lines[-1] if lines else ''}")


def headline(metrics: dict[str, Any]) -> dict[str, float]:
    """F1 at tolerance 1 and alignment accuracy of each detector in ``metrics`` (flat names)."""
    out: dict[str, float] = {}
    for detector, values in metrics.items():
        if not isinstance(values, dict):
            continue
        for key, value in values.items():
            if isinstance(value, (int, float)) and (key.startswith("f1") or key.startswith("align")):
                out[f"{detector}.{key}"] = float(value)
    return out


def run(flow: Flow) -> dict[str, Any]:
    """Steps 1-4 (and the step-5 placeholder); returns episodes read, dims and held-out metrics."""
    env = ros_env()
    clock = [time.monotonic()]
    seconds: dict[str, float] = {}

    def lap(name: str) -> None:
        clock.append(time.monotonic())
        seconds[name] = round(clock[-1] - clock[-2], 1)

    train_bag = record(flow, "train", flow.episodes, flow.seed, env)
    heldout_bag = record(flow, "heldout", flow.heldout, flow.seed + HELDOUT_SEED, env)
    lap("record")
    train_read, heldout_read = read(train_bag), read(heldout_bag)
    lap("read")
    checkpoint = train(flow, train_bag, env)
    lap("train")
    detector = tune(flow, train_bag, checkpoint, env)
    lap("tune")
    metrics = segment(flow, heldout_bag, checkpoint, detector, env)
    lap("segment")
    live_doc: dict[str, Any] | None = None
    print(f"[own_robot] 5. live: {live_command(checkpoint)}", file=sys.stderr)
    if flow.live:
        live_bag = live(flow, checkpoint, env)
        replay = segment(flow, live_bag, checkpoint, None, env, name="segment_live")  # detector.json
        live_doc = score_live(live_bag, flow.out / "segment_live")
        live_doc["replay_metrics"] = replay
        (flow.out / "live.json").write_text(json.dumps(live_doc, indent=1))
        lap("live")
    first = train_read.episodes[0]
    return {
        "train_episodes": len(train_read.episodes),
        "heldout_episodes": len(heldout_read.episodes),
        "train_report": train_read.report.to_dict(),
        "obs_dim": int(first.observations.shape[1]),
        "action_dim": int(first.actions.shape[1]),
        "obs_names": list(first.extras.get("obs_names", [])),
        "checkpoint": str(checkpoint),
        "metrics": metrics,
        "headline": headline(metrics),
        "live": live_doc,
        "seconds": seconds,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/own_robot"), help="output directory")
    parser.add_argument("--episodes", type=int, default=300, help="training episodes to record")
    parser.add_argument("--heldout", type=int, default=50, help="held-out episodes to record")
    parser.add_argument("--iterations", type=int, default=None,
                        help="fixed training length (default: the config's early stopping)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the training episodes")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads of ompn_train (default: the config's; 1 on a busy machine)")
    parser.add_argument("--no-live", action="store_true", help="skip step 5 (ompn_node live)")
    parser.add_argument("--live-rate", type=float, default=25.0, help="sim rate of step 5 in Hz (25)")
    parser.add_argument("--action-norm", choices=("none", "standard"), default=None,
                        help="train.action_norm (default: the training config's)")
    args = parser.parse_args(argv)
    if args.episodes < 2 or args.heldout < 1 or not args.live_rate > 0:
        print("own_robot: --episodes must be >= 2, --heldout >= 1 and --live-rate > 0", file=sys.stderr)
        return 2
    try:
        summary = run(Flow(args.out, args.episodes, args.heldout, args.iterations, args.seed,
                           threads=args.threads, live=not args.no_live, live_rate=args.live_rate,
                           action_norm=args.action_norm))
    except (OwnRobotError, OSError, ValueError) as err:
        print(f"own_robot: {err}", file=sys.stderr)
        return 2
    doc = {k: summary[k] for k in ("train_episodes", "heldout_episodes", "obs_dim", "action_dim", "headline",
                                   "seconds")}
    if summary["live"] is not None:
        doc["live"] = {k: summary["live"][k] for k in ("episodes", "metrics", "agree_with_replay")}
    print(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
