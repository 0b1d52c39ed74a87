"""Benchmark of the online product: segmenter step latency and ompn_node over DDS.

1. In-process, batch 1: ``StreamingSegmenter.step`` p50/p99 (numpy StreamingPolicy + detector +
   validation; also with the duration decoder, mode 'hsmm', lag 1, and its kernel at the bound of
   its span) vs a plain eager PyTorch
   ``OMPNPolicy.step`` under ``inference_mode``, for the
   Craft (obs 1075, n=3, m=128, discrete) and Dial (obs 39, n=3, m=64, continuous) sizes.
   Random-init checkpoints (latency does not depend on the weights).
2. Two processes on loopback: this process publishes Dial-sized observations and subscribes to the
   node's outputs; ``ompn_node`` runs as a subprocess.  Observation -> ``~/pi`` latency p50/p99
   at 100 Hz (and observation -> ``~/boundary`` for the boundaries that occur; detector_high=0.23 sits
   inside the random-init model's score range so boundaries do occur), then a sustained
   1 kHz stream (``duration`` s; 60 s for the real figure, 5 s with ``quick``) with the lost steps
   taken from the node's own ``/diagnostics`` counters and the node process's CPU use.
   Measured with the node's SingleThreadedExecutor (the EventsExecutor does not work with it, see
   the ompn_node docstring).
3. Multi-topic (``ompn_node`` with ``observation_spec``, :mod:`ompn_ros.nodes.ompn_node_obs`): the Dial
   observation split over three topics, ``/arm/joint_states`` (JointState, 9 joints, position +
   velocity: the step topic), ``/arm/wrench`` (WrenchStamped, every step) and ``/arm/gripper``
   (Float32MultiArray of 15, every 4th step), ``stamp: header`` (JointState and WrenchStamped stamped
   when published, the gripper at reception), tolerance 50 ms, ``wait_s`` 0.1 s (``--multi-wait``): a
   step waits for the wrench of the next tick, published before the next step.  In process: the
   node's work per step (``ObservationAssembler.step`` + ``StreamingSegmenter.step``) p50/p99; over
   DDS: step -> ``~/pi`` and step -> ``~/boundary`` latency at 100 Hz, then 1 kHz on the step topic for
   ``duration`` s (60 s; 10 s with ``quick``): steps in (the node's ``obs.steps``), ``~/pi`` out, lost
   (sent - accepted) and dropped by the assembler.
4. A type without a hand-written parser (``observation_spec`` = :data:`CUSTOM_SPEC`: the Dial observation
   as the four arrays of one ``JointTrajectoryPoint``, read by field path as a lab's own type is): the
   node's work per step in process, step -> ``~/pi`` and step -> ``~/boundary`` latency at 100 Hz.

Run: ``.venv/bin/python bench/bench_node.py [--quick]`` from the repository root.
"""

from __future__ import annotations

import argparse
import gc
import itertools
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from ompn_ros.ros import containment  # noqa: E402 (after the path insert)

containment.contain(os.environ)  # loopback + shared memory only, a per-run ROS_DOMAIN_ID

Result = dict[str, tuple[float, str]]


def _configs() -> dict[str, Any]:
    from ompn_ros.model.config import OMPNConfig

    return {
        "craft": OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5, n_slots=2, slot_size=128),
        "dial": OMPNConfig(obs_dim=39, action_type="continuous", action_dim=9, n_slots=2, slot_size=64),
    }


def _stop(proc: subprocess.Popen[bytes], log: Any) -> None:
    """Interrupt the node process as Ctrl-C would (killed after 10 s) and close its log."""
    proc.send_signal(2)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def _observations(domain: str, steps: int) -> tuple[np.ndarray, list[int]]:
    """``steps`` real expert observations (Craft's one-hot features are sparse) and the episode start
    rows; at most 60 episodes are generated and repeated for longer streams."""
    if domain == "craft":
        from sim_nodes.craft import generate_episode as craft_episode

        seeds = range(min(60, steps // 20 + 1))
        episodes = [craft_episode(seed, task="makebed").observations for seed in seeds]
    else:
        from sim_nodes.dial import generate_episode as dial_episode

        episodes = [dial_episode(seed).observations for seed in range(min(60, steps // 150 + 1))]
    lengths = [len(e) for e in episodes]
    reps = -(-steps // sum(lengths))
    starts = np.cumsum([0] + lengths * reps)[:-1]
    stream = np.concatenate(episodes * reps).astype(np.float32)[:steps]
    return stream, [int(s) for s in starts if s < steps]


def _time_steps(reset: Any, step: Any, obs: np.ndarray, starts: list[int], reps: int = 3) -> list[float]:
    """Per-step wall times in µs, ``reps`` passes over ``obs`` after one warm-up pass."""
    begin = set(starts)
    times: list[float] = []
    for rep in range(reps + 1):
        for i, x in enumerate(obs):
            if i in begin:
                reset()
            t0 = time.perf_counter_ns()
            step(x)
            if rep:
                times.append((time.perf_counter_ns() - t0) / 1e3)
    return times


def _torch_stepper(model: Any) -> tuple[Any, Any]:
    """``(reset, step)`` of a plain eager PyTorch ``OMPNPolicy.step`` under ``inference_mode``."""
    import torch

    state = [model.initial_state(1)]

    def reset() -> None:
        state[0] = model.initial_state(1)

    def step(x: np.ndarray) -> None:
        with torch.inference_mode():
            out, state[0] = model.step(torch.from_numpy(x).unsqueeze(0), state[0])
            _ = out.p_hat.numpy()

    return reset, step


def _cost_model() -> Any:
    """A duration model of 4 subtasks of 4-8 steps (for timing the 'hsmm' decoder only)."""
    from ompn_ros.detect.duration import fit_duration_model

    rng = np.random.default_rng(0)
    bounds = [np.cumsum(rng.integers(4, 9, size=4)) - 1 for _ in range(100)]
    scores = [np.where(np.isin(np.arange(b[-1] + 1), b), 0.6, 0.1) + rng.normal(0, 0.05, b[-1] + 1)
              for b in bounds]
    return fit_duration_model(scores, bounds)


def _cost_head(features: int) -> Any:
    """A boundary head of the trained sizes (window 8, 2 × 64 hidden, lags 0-6) with random weights
    (for timing mode 'head' only)."""
    from ompn_ros.detect.head import BoundaryHead

    rng = np.random.default_rng(0)
    sizes = [8 * features, 64, 64, 7]
    weights = tuple((rng.normal(0, 0.1, (a, b)), rng.normal(0, 0.1, b)) for a, b in itertools.pairwise(sizes))
    return BoundaryHead(weights, np.zeros(sizes[0]), np.ones(sizes[0]), 8, features)


def bench_duration_span(reps: int = 2000) -> Result:
    """The duration decoder's per-step kernel at its bound: ``MAX_SPAN`` steps since the last boundary,
    no boundary published yet (the backward pass covers every later subtask), K = 4 and 8."""
    from ompn_ros.detect.duration import MAX_SPAN, DurationModel, _end_posterior

    out: Result = {}
    rng = np.random.default_rng(0)
    for k in (4, 8):
        model = DurationModel(subtasks=k, hazard=rng.uniform(0.05, 0.5, size=(k, 61)),
                              f0=rng.dirichlet(np.ones(100)), f1=rng.dirichlet(np.ones(100)))
        bins = rng.integers(0, 100, size=MAX_SPAN).astype(np.int64)
        args = (*model.lengths, model.logs[2], model.logs[3], bins, 0, 0, 1, MAX_SPAN - 2)
        _end_posterior(*args)  # compile / load the cached kernel
        times = []
        for _ in range(reps):
            t0 = time.perf_counter_ns()
            _end_posterior(*args)
            times.append((time.perf_counter_ns() - t0) / 1e3)
        out[f"hsmm_span{MAX_SPAN}_k{k}_p50"] = (_pct(times, 50), "us")
        out[f"hsmm_span{MAX_SPAN}_k{k}_p99"] = (_pct(times, 99), "us")
    return out


def bench_in_process(steps: int) -> Result:
    """Segmenter step (every backend) vs eager torch step, batch 1, on the shipped checkpoints."""
    import torch

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.checkpoint import load_checkpoint
    from ompn_ros.model.streaming import StreamingPolicy
    from ompn_ros.segmenter import StreamingSegmenter

    torch.set_num_threads(1)
    out: Result = {}
    for name in ("craft", "dial"):
        model, _ = load_checkpoint(shipped_checkpoint(name))
        model.eval()
        obs, starts = _observations(name, steps)
        for backend in ("jit", "numpy"):
            seg = StreamingSegmenter(StreamingPolicy(model, backend=backend), DetectorConfig(high=0.5))
            times = _time_steps(seg.reset, seg.step, obs, starts)
            prefix = f"{name}_segmenter" if backend == "jit" else f"{name}_segmenter_{backend}"
            out[f"{prefix}_step_p50"] = (_pct(times, 50), "us")
            out[f"{prefix}_step_p99"] = (_pct(times, 99), "us")
        # the duration decoder (mode 'hsmm') at the shipped Craft settings; its cost grows with the
        # steps since the last boundary (bench_duration_span gives the bound)
        config = DetectorConfig(mode="hsmm", high=0.98, lag=1)
        seg = StreamingSegmenter(StreamingPolicy(model, backend="jit"), config, _cost_model())
        times = _time_steps(seg.reset, seg.step, obs, starts)
        out[f"{name}_segmenter_hsmm_step_p50"] = (_pct(times, 50), "us")
        out[f"{name}_segmenter_hsmm_step_p99"] = (_pct(times, 99), "us")
        # the boundary head (mode 'head'): one pass of its network per step on the model's outputs
        features = model.config.n_slots + 1 + model.config.action_dim
        config = DetectorConfig(mode="head", high=0.5, lag=3, min_segment_length=2)
        seg = StreamingSegmenter(StreamingPolicy(model, backend="jit"), config, None, _cost_head(features))
        times = _time_steps(seg.reset, seg.step, obs, starts)
        out[f"{name}_segmenter_head_step_p50"] = (_pct(times, 50), "us")
        out[f"{name}_segmenter_head_step_p99"] = (_pct(times, 99), "us")
        # the duration decoder over the head (mode 'head_hsmm'): both costs, its evidence read from rows
        config = DetectorConfig(mode="head_hsmm", high=0.98, lag=1)
        seg = StreamingSegmenter(StreamingPolicy(model, backend="jit"), config, _cost_model(),
                                 _cost_head(features))
        times = _time_steps(seg.reset, seg.step, obs, starts)
        out[f"{name}_segmenter_head_hsmm_step_p50"] = (_pct(times, 50), "us")
        out[f"{name}_segmenter_head_hsmm_step_p99"] = (_pct(times, 99), "us")
        torch_reset, torch_step = _torch_stepper(model)
        times = _time_steps(torch_reset, torch_step, obs, starts, reps=1)
        out[f"{name}_torch_step_p50"] = (_pct(times, 50), "us")
        out[f"{name}_torch_step_p99"] = (_pct(times, 99), "us")
        speedup = out[f"{name}_torch_step_p50"][0] / out[f"{name}_segmenter_step_p50"][0]
        out[f"{name}_speedup_p50"] = (speedup, "x")
    return out


def bench_ensemble_in_process(path: Path, domain: str, steps: int) -> Result:
    """Segmenter step of an ensemble checkpoint directory (``ensemble.json``) vs one of its members."""
    import torch

    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.load import stepper_from_checkpoint
    from ompn_ros.segmenter import StreamingSegmenter

    torch.set_num_threads(1)
    ensemble = stepper_from_checkpoint(path)
    members = len(ensemble.members)
    obs, starts = _observations(domain, steps)
    out: Result = {}
    seg = StreamingSegmenter(ensemble, DetectorConfig(high=0.5))
    times = _time_steps(seg.reset, seg.step, obs, starts)
    out[f"{domain}_ensemble{members}_segmenter_step_p50"] = (_pct(times, 50), "us")
    out[f"{domain}_ensemble{members}_segmenter_step_p99"] = (_pct(times, 99), "us")
    return out


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _Client:
    """Publisher of observations and subscriber of the node's outputs (this process)."""

    def __init__(self, ctx: Any, executor: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float32MultiArray

        from ompn_interfaces.msg import SubtaskBoundary

        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        events = QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        self.node = rclpy.create_node("bench_client", context=ctx)
        from ompn_ros.ros.run import make_executor

        self.executor = make_executor(executor, context=ctx)
        self.executor.add_node(self.node)
        self.pub = self.node.create_publisher(Float32MultiArray, "observation", reliable)
        self.pi_times: list[int] = []
        self.boundaries: list[tuple[int, int]] = []  # (detected_at, arrival ns)
        self.diag: dict[str, str] = {}
        # Outputs are taken raw and stamped on arrival, before any decoding: the figures are the
        # node's latency, not this Python client's message conversion (decoded afterwards).
        self.node.create_subscription(
            Float32MultiArray, "/ompn_node/pi", lambda m: self.pi_times.append(time.monotonic_ns()), reliable,
            raw=True,
        )
        self.node.create_subscription(
            SubtaskBoundary, "/ompn_node/boundary", self._on_boundary, events, raw=True
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self._boundary_type = SubtaskBoundary

    def _on_boundary(self, raw: bytes) -> None:
        arrival = time.monotonic_ns()
        from rclpy.serialization import deserialize_message

        msg = deserialize_message(raw, self._boundary_type)
        self.boundaries.append((int(msg.decided_step), arrival))

    def _on_diag(self, msg: Any) -> None:
        if msg.status and msg.status[0].name.endswith(": segmenter"):
            self.diag = {kv.key: kv.value for kv in msg.status[0].values}

    def pump(self, cond: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.005)
            if cond():
                return True
        return bool(cond())

    def stream(self, observations: np.ndarray, rate: float) -> list[int]:
        """Publish at ``rate`` Hz while spinning; returns the publish times (monotonic ns).

        Messages go out as pre-encoded CDR, as a bag replay publishes them.
        """
        from ompn_ros.data.messages import encode_float32_array

        return self.pace([[(self.pub, encode_float32_array(x, "obs"))] for x in observations], rate)

    def pace(self, batches: list[list[tuple[Any, bytes]]], rate: float) -> list[int]:
        """Publish one batch of ``(publisher, CDR)`` per tick at ``rate`` Hz while spinning; returns the
        publish time of each batch's last message (the step message)."""
        msgs = batches
        period = 1e9 / rate
        t_start = time.monotonic_ns() + 1_000_000
        sent = []
        for i, m in enumerate(msgs):
            due = t_start + int(i * period)
            # sleep-paced (a busy-wait pacer would take a core from the node on this 2-core machine)
            while True:
                now = time.monotonic_ns()
                if now >= due:
                    break
                if due - now > 400_000:  # serve callbacks while waiting (blocks, does not spin)
                    self.executor.spin_once(timeout_sec=(due - now - 300_000) / 1e9)
                elif due - now > 150_000:
                    time.sleep((due - now - 100_000) / 1e9)
            for pub, raw in m[:-1]:
                _publish(pub, raw)
            sent.append(time.monotonic_ns())
            _publish(*m[-1])
        return sent


def bench_dds(domain: str, duration: float, latency_msgs: int, executor: str = "events",
              client: str = "events", checkpoint: Path | None = None, label: str = "",
              obs_qos: str = "best_effort") -> Result:
    """``ompn_node`` (shipped checkpoint, or ``checkpoint``, and the shipped detector of ``domain``)
    in its own process, fed with real expert observations of one long stream (no resets: step index
    = accepted count); 1 kHz run only when ``duration`` > 0.  ``label`` prefixes the figure names."""
    import rclpy

    from ompn_ros.paths import config_file

    out: Result = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench_node_"))
    obs_all, _ = _observations(domain, 20 + latency_msgs + int(duration * 1000))
    _freeze_garbage()
    cmd = [
        sys.executable,
        "-m",
        "ompn_ros.nodes.ompn_node",
        "--ros-args",
        "--params-file",
        str(config_file(f"ompn_node_{domain}.yaml")),
        "-p",
        f"executor:={executor}",
        "-p",
        "diagnostics_period:=0.2",
        "-p",
        "qos_depth:=1000",
        "-p",
        f"obs_qos:={obs_qos}",
    ]
    if checkpoint is not None:
        cmd += ["-p", f"checkpoint:={checkpoint}"]
    # one endless stream without episode markers, where the duration decoder (mode 'hsmm') would stop
    # after K - 1 boundaries: the threshold detector runs here; the live demo measures the decoder
    cmd += ["-p", "detector_mode:=peak", "-p", "detector_high:=0.2"] if domain == "craft" else []
    log_path = tmp / f"node_{domain}_{executor}.log"
    log = open(log_path, "w")  # closed in the finally block
    proc = subprocess.Popen(cmd, env=dict(os.environ), cwd=str(ROOT), stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        client = _Client(ctx, client)
        executor = f"{domain}{label}_{executor}"
        if not client.pump(lambda: bool(client.diag) and client.pub.get_subscription_count() > 0, 30):
            raise RuntimeError(f"ompn_node did not come up: {log_path.read_text()}")
        client.pump(lambda: False, 0.5)
        # warm-up (first messages after matching may be dropped by the late reader)
        client.stream(obs_all[:20], 100.0)
        client.pump(lambda: False, 0.5)
        base_pi = len(client.pi_times)
        base_accepted = int(client.diag["accepted"])
        sent = client.stream(obs_all[20 : 20 + latency_msgs], 100.0)
        client.pump(lambda: len(client.pi_times) - base_pi >= latency_msgs, 5)
        got = client.pi_times[base_pi:]
        lat = [(r - s) / 1e6 for s, r in zip(sent, got, strict=False)]
        out[f"{executor}_pi_latency_100hz_p50"] = (_pct(lat, 50), "ms")
        out[f"{executor}_pi_latency_100hz_p99"] = (_pct(lat, 99), "ms")
        # boundaries detected during this window: detected_at counts steps since the last reset
        first_step = base_accepted  # one episode, never reset: step index == accepted count
        blat = [
            (r - sent[d - first_step]) / 1e6 for d, r in client.boundaries if 0 <= d - first_step < len(sent)
        ]
        out[f"{executor}_boundary_latency_100hz_p50"] = (_pct(blat, 50), "ms")
        out[f"{executor}_boundary_latency_100hz_p99"] = (_pct(blat, 99), "ms")
        out[f"{executor}_boundary_events_100hz"] = (float(len(blat)), "events")

        if duration <= 0:
            return out
        client.pump(lambda: False, 0.5)
        accepted_before = int(client.diag["accepted"])
        missed_before = int(client.diag.get("messages_missed", 0))
        n = int(duration * 1000)
        obs = obs_all[20 + latency_msgs :][:n]
        cpu0, wall0 = _cpu_seconds(proc.pid), time.monotonic()
        sent = client.stream(obs, 1000.0)
        wall = time.monotonic() - wall0
        cpu = _cpu_seconds(proc.pid) - cpu0
        client.pump(lambda: int(client.diag.get("accepted", 0)) - accepted_before >= n, 5)
        client.pump(lambda: False, 0.5)
        accepted = int(client.diag["accepted"]) - accepted_before
        out[f"{executor}_1khz_sent"] = (float(n), "msgs")
        out[f"{executor}_1khz_achieved_rate"] = (n / wall, "Hz")
        out[f"{executor}_1khz_lost_steps"] = (float(n - accepted), "steps")
        # of those, the ones the node counted as sent and never received (its input queue overflowed)
        missed = int(client.diag.get("messages_missed", 0)) - missed_before
        out[f"{executor}_1khz_lost_counted"] = (float(missed), "steps")
        out[f"{executor}_1khz_node_cpu"] = (100.0 * cpu / wall, "% of one core")
    finally:
        rclpy.try_shutdown(context=ctx)
        _stop(proc, log)
    return out


ARM_JOINTS = [f"j{i}" for i in range(9)]
ARM_SPEC: dict[str, Any] = {
    "step_topic": "/arm/joint_states",
    "tolerance_s": 0.05,
    "stamp": "header",
    "fields": [
        {"topic": "/arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "position",
         "names": ARM_JOINTS},
        {"topic": "/arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "velocity",
         "names": ARM_JOINTS},
        {"topic": "/arm/gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 15},
        {"topic": "/arm/wrench", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"},
    ],
}  # fmt: skip
"""The Dial observation (39) over three topics: 9 + 9 joint values, 15 gripper/object values, 6 wrench.
Header stamps (set when published): a step waits for the wrench stamped at or after it (``wait_s``)."""


def _arm_messages(obs: np.ndarray) -> list[list[tuple[str, bytes]]]:
    """Per step, pre-encoded ``(topic, CDR)``: the wrench, every 4th step the gripper, then the step."""
    from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float32MultiArray

    out = []
    for k, x in enumerate(obs.astype(float)):
        js = JointState(name=ARM_JOINTS, position=list(x[0:9]), velocity=list(x[9:18]))
        force, torque = Vector3(x=x[33], y=x[34], z=x[35]), Vector3(x=x[36], y=x[37], z=x[38])
        ft = WrenchStamped(wrench=Wrench(force=force, torque=torque))
        batch = [("/arm/wrench", bytearray(serialize_message(ft)))]  # bytearray: stamped when published
        if k % 4 == 0:  # 25 Hz at 100 Hz steps: within the 50 ms tolerance
            batch.append(("/arm/gripper", serialize_message(Float32MultiArray(data=list(x[18:33])))))
        batch.append(("/arm/joint_states", bytearray(serialize_message(js))))
        out.append(batch)
    return out


def _freeze_garbage() -> None:
    """Collect, then exempt every object alive now from the garbage collector.  With tens of
    thousands of pre-encoded messages alive, a full collection in this (publishing) process pauses
    it for hundreds of ms, e.g. between a tick's gripper and its step: the node then rightly drops
    the step as stale, and the pause would be counted against the node."""
    gc.collect()
    gc.freeze()


def _publish(pub: Any, raw: bytes | bytearray) -> None:
    """Publish pre-encoded CDR; a ``bytearray`` gets ``header.stamp`` = now (system clock, the ROS
    clock of every process here) written in place: its first field, right after the 4-byte CDR header."""
    if isinstance(raw, bytearray):
        sec, nsec = divmod(time.time_ns(), 1_000_000_000)
        struct.pack_into("<iI", raw, 4, sec, nsec)
    pub.publish(bytes(raw) if isinstance(raw, bytearray) else raw)


def bench_multi_in_process(steps: int) -> Result:
    """The node's work per assembled step: ``ObservationAssembler.step`` + ``StreamingSegmenter.step``
    (shipped Dial checkpoint), partners offered untimed, receive stamps 1 ms apart."""
    import torch

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec
    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.load import stepper_from_checkpoint
    from ompn_ros.segmenter import StreamingSegmenter

    torch.set_num_threads(1)
    spec = ObservationSpec.from_dict(ARM_SPEC)
    asm = ObservationAssembler(spec)
    seg = StreamingSegmenter(stepper_from_checkpoint(shipped_checkpoint("dial")), DetectorConfig(high=0.1))
    obs, _ = _observations("dial", steps)
    batches = _arm_messages(obs)
    times: list[float] = []
    stamp = 0
    for rep in range(3):
        for batch in batches:
            for topic, raw in batch[:-1]:
                stamp += 100_000
                asm.offer(topic, stamp, bytes(raw))
            stamp += 1_000_000
            step_raw = bytes(batch[-1][1])
            t0 = time.perf_counter_ns()
            x = asm.step(stamp, step_raw)
            if not isinstance(x, Drop):
                seg.step(x, stamp)
            if rep:
                times.append((time.perf_counter_ns() - t0) / 1e3)
    return {"dial_multi_node_step_p50": (_pct(times, 50), "us"),
            "dial_multi_node_step_p99": (_pct(times, 99), "us")}


def _counter_sum(diag: dict[str, str], prefix: str) -> int:
    return sum(int(v) for k, v in diag.items() if k.startswith(prefix))


def _multi_latency(c: _Client, ticks: list[list[tuple[Any, bytes]]], name: str) -> Result:
    """Step -> ``~/pi`` and step -> ``~/boundary`` latency of ``ticks`` published at 100 Hz."""
    base_pi, base_accepted = len(c.pi_times), int(c.diag["accepted"])
    sent = c.pace(ticks, 100.0)
    c.pump(lambda: len(c.pi_times) - base_pi >= len(ticks), 5)
    received = c.pi_times[base_pi:]
    # ~/pi carries no stamp: pairs are made in order, so they are only trusted when every step gave one
    lat = [(r - s) / 1e6 for s, r in zip(sent, received, strict=True)] if len(received) == len(sent) else []
    # one episode, never reset: a boundary's detected_at is the accepted count at its step
    blat = [(r - sent[d - base_accepted]) / 1e6 for d, r in c.boundaries
            if 0 <= d - base_accepted < len(sent)]  # fmt: skip
    return {f"{name}_pi_latency_100hz_p50": (_pct(lat, 50), "ms"),
            f"{name}_pi_latency_100hz_p99": (_pct(lat, 99), "ms"),
            f"{name}_boundary_latency_100hz_p50": (_pct(blat, 50), "ms"),
            f"{name}_boundary_latency_100hz_p99": (_pct(blat, 99), "ms"),
            f"{name}_boundary_events_100hz": (float(len(blat)), "events"),
            f"{name}_pi_missing_100hz": (float(len(sent) - len(received)), "steps")}  # fmt: skip


def _multi_sustained(c: _Client, pid: int, ticks: list[list[tuple[Any, bytes]]], name: str) -> Result:
    """``ticks`` at 1 kHz: steps in (the node's ``obs.steps``), ``~/pi`` out, lost, dropped, node CPU."""
    c.pump(lambda: False, 0.5)
    before, pi_before, n = dict(c.diag), len(c.pi_times), len(ticks)
    cpu0, wall0 = _cpu_seconds(pid), time.monotonic()
    c.pace(ticks, 1000.0)
    wall, cpu = time.monotonic() - wall0, _cpu_seconds(pid) - cpu0
    c.pump(lambda: int(c.diag.get("obs.steps", 0)) - int(before["obs.steps"]) >= n, 5)
    c.pump(lambda: False, 0.5)
    accepted = int(c.diag["accepted"]) - int(before["accepted"])
    dropped = _counter_sum(c.diag, "obs.dropped.") - _counter_sum(before, "obs.dropped.")
    late = _counter_sum(c.diag, "obs.late") - _counter_sum(before, "obs.late")
    return {f"{name}_1khz_sent": (float(n), "steps"),
            f"{name}_1khz_achieved_rate": (n / wall, "Hz"),
            f"{name}_1khz_steps_in": (float(int(c.diag["obs.steps"]) - int(before["obs.steps"])), "steps"),
            f"{name}_1khz_pi_out": (float(len(c.pi_times) - pi_before), "msgs"),
            f"{name}_1khz_lost_steps": (float(n - accepted), "steps"),
            f"{name}_1khz_dropped_steps": (float(dropped), "steps"),
            f"{name}_1khz_late_steps": (float(late), "steps"),
            f"{name}_1khz_node_cpu": (100.0 * cpu / wall, "% of one core"),
            **{f"{name}_1khz_dropped_{k.split('.')[-1]}": (float(int(v) - int(before.get(k, 0))), "steps")
               for k, v in c.diag.items() if k.startswith("obs.dropped.")}}  # fmt: skip


def bench_dds_multi(duration: float, latency_msgs: int, executor: str = "events",
                    client: str = "events", wait_s: float | None = None,
                    obs_qos: str = "best_effort") -> Result:
    """``ompn_node`` (shipped Dial checkpoint and detector) with ``observation_spec`` = :data:`ARM_SPEC`
    in its own process; this process publishes the three topics (module docstring, part 3)."""
    import rclpy
    import yaml
    from geometry_msgs.msg import WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float32MultiArray

    from ompn_ros.paths import config_file

    tmp = Path(tempfile.mkdtemp(prefix="bench_node_multi_"))
    spec_file = tmp / "arm.yaml"
    spec = ARM_SPEC if wait_s is None else {**ARM_SPEC, "wait_s": wait_s}
    spec_file.write_text(yaml.safe_dump({"observation": spec}))
    batches = _arm_messages(_observations("dial", 20 + latency_msgs + int(duration * 1000))[0])
    _freeze_garbage()
    cmd = [sys.executable, "-m", "ompn_ros.nodes.ompn_node", "--ros-args",
           "--params-file", str(config_file("ompn_node_dial.yaml")), "-p", f"executor:={executor}",
           "-p", "diagnostics_period:=0.2", "-p", "qos_depth:=1000", "-p", f"observation_spec:={spec_file}",
           "-p", f"obs_qos:={obs_qos}"]
    log_path = tmp / f"node_multi_{executor}.log"
    log = open(log_path, "w")  # closed in the finally block
    proc = subprocess.Popen(cmd, env=dict(os.environ), cwd=str(ROOT), stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        c = _Client(ctx, client)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        classes = {"/arm/joint_states": JointState, "/arm/gripper": Float32MultiArray,
                   "/arm/wrench": WrenchStamped}
        pubs = {t: c.node.create_publisher(cls, t, reliable) for t, cls in classes.items()}
        ticks = [[(pubs[t], raw) for t, raw in b] for b in batches]
        name = f"dial_multi_{executor}"
        matched = [p.get_subscription_count for p in pubs.values()]
        if not c.pump(lambda: bool(c.diag) and min(count() for count in matched) > 0, 30):
            raise RuntimeError(f"ompn_node did not come up: {log_path.read_text()}")
        c.pump(lambda: False, 0.5)
        c.pace(ticks[:20], 100.0)  # warm-up (the first messages after matching may be lost)
        c.pump(lambda: False, 0.5)
        out = _multi_latency(c, ticks[20 : 20 + latency_msgs], name)
        if duration > 0:
            out.update(_multi_sustained(c, proc.pid, ticks[20 + latency_msgs :], name))
    finally:
        rclpy.try_shutdown(context=ctx)
        _stop(proc, log)
    return out


CUSTOM_TYPE = "trajectory_msgs/msg/JointTrajectoryPoint"
CUSTOM_SPEC: dict[str, Any] = {
    "step_topic": "/arm/point",
    "stamp": "receive",
    "fields": [{"topic": "/arm/point", "type": CUSTOM_TYPE, "field": name}
               for name in ("positions", "velocities", "accelerations", "effort")],
}  # fmt: skip
"""The Dial observation (39) from one message of a type without a hand-written parser: 9 positions,
9 velocities, 15 accelerations, 6 efforts of a ``JointTrajectoryPoint`` (plus its ``Duration``), read by
field path through the type's definition, as a lab's own message type is (docs/specs.md)."""


def _custom_messages(obs: np.ndarray) -> list[bytes]:
    """Per step, the CDR of one ``JointTrajectoryPoint`` carrying the observation."""
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import JointTrajectoryPoint

    return [serialize_message(JointTrajectoryPoint(positions=list(x[0:9]), velocities=list(x[9:18]),
                                                   accelerations=list(x[18:33]), effort=list(x[33:39])))
            for x in obs.astype(float)]  # fmt: skip


def bench_custom_in_process(steps: int) -> Result:
    """The node's work per step on :data:`CUSTOM_SPEC`: ``ObservationAssembler.step`` (field paths) +
    ``StreamingSegmenter.step`` (shipped Dial checkpoint), receive stamps 1 ms apart."""
    import torch

    from ompn_ros.checkpoints import shipped_checkpoint
    from ompn_ros.data.obs import Drop, ObservationAssembler, ObservationSpec
    from ompn_ros.detect.online import DetectorConfig
    from ompn_ros.model.load import stepper_from_checkpoint
    from ompn_ros.segmenter import StreamingSegmenter

    torch.set_num_threads(1)
    asm = ObservationAssembler(ObservationSpec.from_dict(CUSTOM_SPEC))
    seg = StreamingSegmenter(stepper_from_checkpoint(shipped_checkpoint("dial")), DetectorConfig(high=0.1))
    obs, _ = _observations("dial", steps)
    raws = _custom_messages(obs)
    times: list[float] = []
    for rep in range(3):
        for k, raw in enumerate(raws):
            stamp = (rep * len(raws) + k + 1) * 1_000_000
            t0 = time.perf_counter_ns()
            x = asm.step(stamp, raw)
            if not isinstance(x, Drop):
                seg.step(x, stamp)
            if rep:
                times.append((time.perf_counter_ns() - t0) / 1e3)
    return {"dial_custom_node_step_p50": (_pct(times, 50), "us"),
            "dial_custom_node_step_p99": (_pct(times, 99), "us")}


def bench_dds_custom(latency_msgs: int, executor: str = "events", client: str = "events",
                     obs_qos: str = "best_effort") -> Result:
    """``ompn_node`` (shipped Dial checkpoint and detector) with ``observation_spec`` = :data:`CUSTOM_SPEC`
    in its own process; this process publishes the points at 100 Hz: step -> ``~/pi`` and step ->
    ``~/boundary`` latency."""
    import rclpy
    import yaml
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from trajectory_msgs.msg import JointTrajectoryPoint

    from ompn_ros.paths import config_file

    tmp = Path(tempfile.mkdtemp(prefix="bench_node_custom_"))
    spec_file = tmp / "arm.yaml"
    spec_file.write_text(yaml.safe_dump({"observation": CUSTOM_SPEC}))
    raws = _custom_messages(_observations("dial", 20 + latency_msgs)[0])
    _freeze_garbage()
    cmd = [sys.executable, "-m", "ompn_ros.nodes.ompn_node", "--ros-args",
           "--params-file", str(config_file("ompn_node_dial.yaml")), "-p", f"executor:={executor}",
           "-p", "diagnostics_period:=0.2", "-p", "qos_depth:=1000", "-p", f"observation_spec:={spec_file}",
           "-p", f"obs_qos:={obs_qos}"]  # fmt: skip
    log_path = tmp / f"node_custom_{executor}.log"
    log = open(log_path, "w")  # closed in the finally block
    proc = subprocess.Popen(cmd, env=dict(os.environ), cwd=str(ROOT), stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        c = _Client(ctx, client)
        pub = c.node.create_publisher(JointTrajectoryPoint, "/arm/point",
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        ticks = [[(pub, raw)] for raw in raws]
        if not c.pump(lambda: bool(c.diag) and pub.get_subscription_count() > 0, 30):
            raise RuntimeError(f"ompn_node did not come up: {log_path.read_text()}")
        c.pump(lambda: False, 0.5)
        c.pace(ticks[:20], 100.0)  # warm-up (the first messages after matching may be lost)
        c.pump(lambda: False, 0.5)
        out = _multi_latency(c, ticks[20:], f"dial_custom_{executor}")
    finally:
        rclpy.try_shutdown(context=ctx)
        _stop(proc, log)
    return out


def run(quick: bool = False, executor: str = "events", client: str = "events", parts: str = "all",
        multi_wait: float | None = None, obs_qos: str = "best_effort") -> Result:
    """All figures (name -> (value, unit)); ``quick`` = 5 s at 1 kHz (multi-topic: 10 s) and fewer
    samples; ``obs_qos`` = the node's ``obs_qos`` parameter (``reliable``: the publisher's queue absorbs
    the node's stalls, the zero-loss configuration on a busy CPU)."""
    results: Result = {}
    if parts in ("all", "step"):
        results.update(bench_in_process(1000 if quick else 5000))
        results.update(bench_duration_span(200 if quick else 2000))
    if parts in ("all", "dds"):
        results.update(bench_dds("dial", duration=5.0 if quick else 60.0, latency_msgs=300 if quick else 3000,
                                 executor=executor, client=client, obs_qos=obs_qos))
        results.update(bench_dds("craft", duration=0.0, latency_msgs=300 if quick else 2000,
                                 executor=executor, client=client, obs_qos=obs_qos))
    if parts in ("all", "multi"):
        results.update(bench_multi_in_process(1000 if quick else 5000))
        results.update(bench_dds_multi(duration=10.0 if quick else 60.0, latency_msgs=300 if quick else 3000,
                                       executor=executor, client=client, wait_s=multi_wait, obs_qos=obs_qos))
    if parts in ("all", "custom"):
        results.update(bench_custom_in_process(1000 if quick else 5000))
        results.update(bench_dds_custom(300 if quick else 3000, executor=executor, client=client,
                                        obs_qos=obs_qos))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--executor", choices=("events", "single"), default="events",
                        help="ompn_node's executor parameter")
    parser.add_argument("--client-executor", choices=("events", "single"), default="events",
                        help="executor of the publishing/subscribing benchmark client")
    parser.add_argument("--parts", choices=("all", "step", "dds", "multi", "custom"), default="all",
                        help="multi: the multi-topic observation_spec case alone; custom: an observation "
                             "type read by field path")
    parser.add_argument("--multi-wait", type=float, default=None, metavar="S",
                        help="wait_s of the multi-topic spec (default: the spec's default; 0 = no wait)")
    parser.add_argument("--obs-qos", choices=("best_effort", "reliable"), default="best_effort",
                        help="ompn_node's obs_qos parameter (default: the shipped best_effort)")
    parser.add_argument("--ensemble", type=Path, default=None, metavar="DIR",
                        help="instead: a Craft ensemble checkpoint directory (ensemble.json, written by "
                             "python -m lab.reproduce --members), in process and in ompn_node at 100 Hz")
    args = parser.parse_args()
    if args.ensemble is not None:
        from ompn_ros.model.ensemble import read_ensemble

        members = len(read_ensemble(args.ensemble)[0])
        results = bench_ensemble_in_process(args.ensemble, "craft", 1000 if args.quick else 5000)
        results.update(bench_dds("craft", duration=0.0, latency_msgs=300 if args.quick else 2000,
                                 executor=args.executor, client=args.client_executor,
                                 checkpoint=args.ensemble.resolve(), label=f"_ensemble{members}"))
    else:
        results = run(quick=args.quick, executor=args.executor, client=args.client_executor, parts=args.parts,
                      multi_wait=args.multi_wait, obs_qos=args.obs_qos)
    width = max(len(k) for k in results)
    for name, (value, unit) in results.items():
        print(f"{name:<{width}}  {value:12.3f}  {unit}")


if __name__ == "__main__":
    main()
