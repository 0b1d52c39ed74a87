"""ompn_node on typed episode markers, and on a sim's two forms of each marker (counted once).

A fake sim publishes Dial-sized observations with every marker twice: as
``ompn_interfaces/EpisodeMarker`` on ``episode_marker`` and as the deprecated ``DiagnosticArray`` on
``episode`` (what the sims publish for one release), or typed only.  The node must start and end each
episode once: its ``markers`` counter counts each marker once and each episode ends with one final
boundary.  The fake sim runs in a child process (the probe below), like the node; it needs an
``ompn_interfaces`` built with EpisodeMarker.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROBE = """
import json, os, subprocess, sys, time
from pathlib import Path
import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray
from ompn_interfaces.msg import EpisodeMarker, SubtaskBoundary
from ompn_ros import layout
from ompn_ros.data import messages as m
ROOT = Path.cwd()
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
forms = sys.argv[1]
ros_env = dict(os.environ)
"""


@pytest.mark.parametrize("forms", ["both", "typed"])
def test_node_starts_and_ends_each_episode_once(ros_env: dict[str, str], forms: str) -> None:
    probe = subprocess.run([sys.executable, "-c", "from ompn_interfaces.msg import EpisodeMarker"],
                           env=ros_env, capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip("ompn_interfaces was built before EpisodeMarker: rebuild it (build_venv.py)")
    done = subprocess.run([sys.executable, "-c", PROBE + BODY, forms], env=ros_env, cwd=ROOT,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    counts = json.loads(done.stdout.split("COUNTS", 1)[1].strip().splitlines()[0])
    assert counts == [4, 2, 2, 2], counts  # markers, episode starts, episodes ended, final boundaries


BODY = """
ns = f"mk_{os.getpid()}_{forms}"
command = [sys.executable, "-m", "ompn_ros.nodes.ompn_node", "--ros-args", "-r", f"__ns:=/{ns}",
           "-p", "domain:=dial", "-p", "diagnostics_period:=0.1"]
proc = subprocess.Popen(command, env=ros_env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                        text=True)
ctx = rclpy.context.Context()
rclpy.init(context=ctx)
try:
    sim = rclpy.create_node("fake_sim", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(sim)
    obs_pub = sim.create_publisher(Float32MultiArray, f"/{ns}/{layout.OBSERVATION}", RELIABLE)
    typed_pub = sim.create_publisher(EpisodeMarker, f"/{ns}/{layout.EPISODE_MARKER}", RELIABLE)
    legacy_pub = sim.create_publisher(DiagnosticArray, f"/{ns}/{layout.EPISODE}", RELIABLE)
    events, diags = [], []
    status = f"/{ns}/ompn_node: segmenter"
    sim.create_subscription(SubtaskBoundary, f"/{ns}/ompn_node/boundary", events.append, EVENTS)
    sim.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: diags.extend(
        {kv.key: kv.value for kv in s.values} for s in msg.status if s.name == status), 10)

    def pump(cond, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
            if cond():
                return True
            assert proc.poll() is None, f"ompn_node exited: {proc.communicate()[0]}"
        return bool(cond())

    def marker(kind, values):
        typed_pub.publish(m.encode_typed_marker(kind, 0, values))
        if forms == "both":
            legacy_pub.publish(m.serialize(m.episode_marker(kind, 0, values)))

    assert pump(lambda: bool(diags) and obs_pub.get_subscription_count() > 0
                and typed_pub.get_subscription_count() > 0, 60), "ompn_node did not come up"
    rng = np.random.default_rng(0)
    for episode in range(2):
        marker(layout.EPISODE_START, m.start_marker_values(episode, "dial", episode, None))
        assert pump(lambda e=episode: int(diags[-1]["episode_starts"]) >= e + 1, 10)
        for _ in range(12):
            obs_pub.publish(Float32MultiArray(data=rng.normal(size=39).astype(np.float32).tolist()))
            pump(lambda: False, 0.02)
        marker(layout.EPISODE_END, m.end_marker_values(episode, "dial", episode, 11, True))
        assert pump(lambda e=episode: sum(ev.final for ev in events) == e + 1, 10), events
    pump(lambda: False, 1.0)  # late twins would arrive now
    last = diags[-1]
    counts = (int(last["markers"]), int(last["episode_starts"]), int(last["episodes_ended"]))
    print("COUNTS", json.dumps([*counts, sum(ev.final for ev in events)]))
finally:
    proc.terminate()
    proc.wait(timeout=30)
    rclpy.shutdown(context=ctx)
"""
