"""Recorder: nothing received before a stop signal is lost, under load (issue: recorder loses data).

Each case starts ``bag_recorder``, a publisher of numbered messages (RELIABLE, KEEP_ALL, in its own
namespace) and, with ``busy``, two busy-loop processes that keep both cores saturated (bounded in
time).  Mid-stream the recorder gets SIGINT or SIGTERM (or SIGKILL).  The publisher logs, for every
message, the system time at which ``publish()`` returned; a message "sent before the signal" is one
whose publish returned before the signal was sent.  The figures count those messages in the bag:

* ``<case>.kept``: % of the messages sent before the signal that are in the bag (goal >= 99.9);
* ``<case>.sent_before_signal``, ``<case>.rate``: the stream actually achieved under load;
* ``<case>.complete_steps``: 1 if every topic ends at the same step (three-topic cases);
* ``<case>.drain``: seconds the recorder drained after the signal (its own summary line);
* ``sigkill_<storage>.lost_window``: seconds of stream before SIGKILL missing from the bag
  (goal <= the 1 s commit period); ``sigkill_<storage>.complete_steps`` as above (a killed sqlite3
  bag is read as of its last commit, ``ompn_ros.data.reader.journal``);
* with ``--kills N``: ``sigkill_<storage>.whole_steps``, how many of N killed bags (commit period
  0.2 s) end with every topic at the same step.

Run: ``python bench/bench_recorder.py [--quick | --kills N]``; the test suite runs :func:`run_case` without
busy loops (``test/data/test_recorder_drain.py``).  ``--publish`` is the publisher child process.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from ompn_ros.data import messages as m  # noqa: E402
from ompn_ros.data.reader.journal import committed_view  # noqa: E402
from ompn_ros.ros import containment  # noqa: E402

TOPICS_1 = ("observation",)
TOPICS_3 = ("observation", "subtask", "action")


# --- publisher child -------------------------------------------------------------------------------
def publish(ns: str, topics: tuple[str, ...], rate: float, seconds: float, out: Path,
            clock: bool = False) -> int:
    """Publish numbered steps at ``rate`` Hz (one message per topic per step) for ``seconds``.

    With ``clock``, also publish ``/clock`` every step: sim time 1000 s + half the elapsed time.
    """
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float32MultiArray, Int32

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("recorder_bench_pub", namespace=ns)
    qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL,
                     durability=DurabilityPolicy.VOLATILE, depth=1)
    pubs = [node.create_publisher(Float32MultiArray if t == "observation" else Int32, t, qos) for t in topics]
    clock_pub = node.create_publisher(Clock, "/clock", 10) if clock else None
    tick = Clock()
    deadline = time.monotonic() + 30
    while any(p.get_subscription_count() < 1 for p in pubs) and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)  # the recorder's other subscriptions settle
    n_max = int(rate * seconds) + 1
    stamps = np.zeros((len(topics), n_max), dtype=np.int64)
    stop: list[int] = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))  # before the harness can send it
    print("publishing", flush=True)
    period = 1.0 / rate
    t0 = time.perf_counter()
    n = 0
    try:
        while n < n_max and not stop:
            if clock_pub is not None:
                sim = int(1000e9 + 0.5e9 * (time.perf_counter() - t0))
                tick.clock.sec, tick.clock.nanosec = divmod(sim, 1_000_000_000)
                clock_pub.publish(tick)
            for k, (topic, pub) in enumerate(zip(topics, pubs)):
                raw = (m.encode_float32_array(np.full(8, n, np.float32), "obs") if topic == "observation"
                       else m.encode_int32(n))
                try:
                    pub.publish(raw)
                    stamps[k, n] = time.time_ns()
                except Exception:  # a killed recorder leaves a full KEEP_ALL history: publish times out
                    stamps[k, n] = np.iinfo(np.int64).max  # never counts as sent
            n += 1
            wait = t0 + n * period - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
    finally:
        np.save(out, stamps[:, :n])
    time.sleep(1.0)  # reliable delivery of the tail
    node.destroy_node()
    rclpy.try_shutdown()
    # The harness's SIGTERM may arrive while the interpreter shuts down, when CPython has already put
    # a Python-level handler back to the default action (exit code -15); an ignored signal stays ignored.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return 0


# --- harness ---------------------------------------------------------------------------------------
class CaseResult(NamedTuple):
    """What one recording kept (see the module docstring)."""

    sent_before: int  # messages whose publish returned before the signal
    kept_before: int  # of those, in the bag
    in_bag: int
    bag: Path
    rate: float  # achieved messages per second (all topics)
    complete_steps: bool  # every topic ends at the same step
    drain_s: float
    lost_window_s: float  # stream time before the signal missing from the bag (0 when none)
    recorder_out: str

    @property
    def kept_pct(self) -> float:
        return 100.0 * self.kept_before / max(self.sent_before, 1)


def _spawn(args: list[str], env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, cwd=ROOT)


def _busy(seconds: float) -> subprocess.Popen[bytes]:
    code = f"import time\nt = time.monotonic() + {seconds}\nwhile time.monotonic() < t:\n    pass\n"
    return subprocess.Popen([sys.executable, "-c", code])


def bag_seqs(bag: Path, ns: str, topics: tuple[str, ...]) -> dict[str, set[int]]:
    """Sequence numbers per topic in a bag, closed or killed (sqlite rows / mcap records)."""
    seqs: dict[str, set[int]] = {t: set() for t in topics}
    names = {f"{ns}/{t}": t for t in topics}

    def add(topic: str, data: bytes) -> None:
        t = names.get(topic)
        if t is not None:
            seqs[t].add(int(m.parse_float32_array(data)[0]) if t == "observation" else m.parse_int32(data))

    with committed_view(bag) as (view, _):  # a kill inside a transaction leaves a journal to roll back
        for db in view.glob("*.db3"):
            con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
            try:
                tids = dict(con.execute("SELECT id, name FROM topics"))
                for tid, data in con.execute("SELECT topic_id, data FROM messages"):
                    add(tids[tid], bytes(data))
            finally:
                con.close()
    for mc in bag.glob("*.mcap"):
        from mcap.records import Channel, Message
        from mcap.stream_reader import StreamReader

        channels: dict[int, str] = {}
        with open(mc, "rb") as fh:
            try:
                for rec in StreamReader(fh, validate_crcs=True).records:
                    if isinstance(rec, Channel):
                        channels[rec.id] = rec.topic
                    elif isinstance(rec, Message):
                        add(channels[rec.channel_id], rec.data)
            except Exception:  # a killed recording ends mid-record: keep what precedes
                pass
    return seqs


def run_case(tmp: Path, *, storage: str, topics: tuple[str, ...], rate: float, stop: signal.Signals,
             signal_after: float, busy: bool, recorder_args: tuple[str, ...] = (),
             sim_clock: bool = False) -> CaseResult:
    """One recording stopped by ``stop`` ``signal_after`` seconds into the stream (module docstring)."""
    env = containment.contain(dict(os.environ))
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    ns = f"/recbench_{uuid.uuid4().hex[:8]}"
    out = tmp / f"bag_{ns[1:]}"
    times = tmp / f"pub_{ns[1:]}.npy"
    recorder = _spawn(["-m", "ompn_ros.nodes.bag_recorder", "--ros-args", "-r", f"__ns:={ns}",
                       "-p", f"output:={out}", "-p", f"storage:={storage}",
                       "-p", f"topics:=[{','.join(topics)}]", *recorder_args], env)
    loads = [_busy(signal_after + 25.0) for _ in range(2)] if busy else []
    publisher = None
    try:
        publisher = _spawn([__file__, "--publish", "--ns", ns, "--rate", str(rate), "--topics",
                            str(len(topics)), "--seconds", str(signal_after + 2.0), "--out", str(times),
                            *(["--clock"] if sim_clock else [])], env)
        assert publisher.stdout is not None
        line = publisher.stdout.readline()
        if "publishing" not in line:
            raise RuntimeError(f"publisher did not start: {line}{publisher.stdout.read()}")
        time.sleep(signal_after)
        signal_ns = time.time_ns()
        recorder.send_signal(stop)
        rec_out, _ = recorder.communicate(timeout=90)
        publisher.send_signal(signal.SIGTERM)
        pub_out, _ = publisher.communicate(timeout=60)
        if publisher.returncode != 0:
            raise RuntimeError(f"publisher failed (exit code {publisher.returncode}): {pub_out}")
    finally:
        for proc in (recorder, publisher, *loads):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    stamps = np.load(times)
    seqs = bag_seqs(out, ns, topics)
    before = stamps < signal_ns
    kept = sum(int(np.isin(np.flatnonzero(before[k]), list(seqs[t])).sum()) for k, t in enumerate(topics))
    missing_t = [stamps[k][i] for k, t in enumerate(topics) for i in np.flatnonzero(before[k])
                 if i not in seqs[t]]
    span = (stamps.max() - stamps.min()) / 1e9 if stamps.size else 0.0
    drain = re.search(r"drained ([0-9.]+) s", rec_out)
    ends = {max(s) if s else -1 for s in seqs.values()}
    return CaseResult(
        sent_before=int(before.sum()), kept_before=kept, in_bag=sum(len(s) for s in seqs.values()), bag=out,
        rate=float(stamps.size / span) if span else 0.0, complete_steps=len(ends) == 1,
        drain_s=float(drain.group(1)) if drain else float("nan"),
        lost_window_s=(signal_ns - min(missing_t)) / 1e9 if missing_t else 0.0, recorder_out=rec_out)


CASES = [  # name, storage, topics, step rate (Hz), stop signal
    ("mcap_2000hz_sigint", "mcap", TOPICS_1, 2000.0, signal.SIGINT),
    ("sqlite3_2000hz_sigterm", "sqlite3", TOPICS_1, 2000.0, signal.SIGTERM),
    ("mcap_1khz_3topics_sigterm", "mcap", TOPICS_3, 1000.0, signal.SIGTERM),
    ("sqlite3_1khz_3topics_sigint", "sqlite3", TOPICS_3, 1000.0, signal.SIGINT),
]


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    import tempfile

    after = 2.0 if quick else 5.0
    figures: dict[str, tuple[float, str]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_recorder_") as tmp:
        for name, storage, topics, rate, stop in (CASES[1:3] if quick else CASES):
            r = run_case(Path(tmp), storage=storage, topics=topics, rate=rate, stop=stop,
                         signal_after=after, busy=True)
            figures[f"{name}.kept"] = (r.kept_pct, "% of sent before signal")
            figures[f"{name}.sent_before_signal"] = (float(r.sent_before), "messages")
            figures[f"{name}.rate"] = (r.rate, "msg/s achieved")
            figures[f"{name}.drain"] = (r.drain_s, "s")
            if len(topics) > 1:
                figures[f"{name}.complete_steps"] = (float(r.complete_steps), "1 = same last step")
        for storage in ("sqlite3", "mcap"):
            r = run_case(Path(tmp), storage=storage, topics=TOPICS_3, rate=1000.0, stop=signal.SIGKILL,
                         signal_after=after, busy=True)
            figures[f"sigkill_{storage}.lost_window"] = (r.lost_window_s, "s before SIGKILL")
            figures[f"sigkill_{storage}.kept"] = (r.kept_pct, "% of sent before SIGKILL")
            figures[f"sigkill_{storage}.complete_steps"] = (float(r.complete_steps), "1 = same last step")
    return figures


def run_kills(repeats: int, commit_period: float = 0.2) -> dict[str, tuple[float, str]]:
    """``repeats`` SIGKILLs per storage under load (1 kHz × 3 topics, two busy loops, 2 s in): how
    many killed bags end with whole steps."""
    import tempfile

    figures: dict[str, tuple[float, str]] = {}
    for storage in ("sqlite3", "mcap"):
        whole = 0
        for _ in range(repeats):
            with tempfile.TemporaryDirectory(prefix="bench_recorder_") as tmp:
                r = run_case(Path(tmp), storage=storage, topics=TOPICS_3, rate=1000.0, stop=signal.SIGKILL,
                             signal_after=2.0, busy=True,
                             recorder_args=("-p", f"commit_period:={commit_period}"))
                whole += r.complete_steps
        figures[f"sigkill_{storage}.whole_steps"] = (float(whole), f"of {repeats} killed bags")
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--publish", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--ns", default="/recbench")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--topics", type=int, choices=(1, 3), default=3)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--out", type=Path, default=Path("pub_times.npy"))
    parser.add_argument("--clock", action="store_true", help="also publish /clock (sim time)")
    parser.add_argument("--kills", type=int, default=0, metavar="N",
                        help="instead: N SIGKILLs per storage (commit period 0.2 s), count whole-step bags")
    args = parser.parse_args(argv)
    if args.publish:
        topics = TOPICS_1 if args.topics == 1 else TOPICS_3
        return publish(args.ns, topics, args.rate, args.seconds, args.out, clock=args.clock)
    figures = run_kills(args.kills) if args.kills > 0 else run(quick=args.quick)
    for name, (value, unit) in figures.items():
        print(f"{name:<42} {value:>12.4g}  {unit}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
