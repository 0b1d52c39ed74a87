"""ompn_interfaces builds from the repository's tracked files in a venv of the ROS wheels (the
`make setup` path), and rclpy publishes and receives its messages through the built type support."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

PUBSUB = """
import sys, time
import rclpy
import ompn_interfaces
from ompn_interfaces.msg import EpisodeMarker, SubtaskBoundary, SubtaskState
assert ompn_interfaces.__file__.startswith(sys.argv[1]), ompn_interfaces.__file__
rclpy.init()
node = rclpy.create_node("interfaces_probe")
got = {}
for cls, topic in ((SubtaskBoundary, "probe_boundary"), (SubtaskState, "probe_state"),
                   (EpisodeMarker, "probe_marker")):
    node.create_subscription(cls, topic, lambda m, t=topic: got.setdefault(t, m), 10)
pubs = [node.create_publisher(SubtaskBoundary, "probe_boundary", 10),
        node.create_publisher(SubtaskState, "probe_state", 10),
        node.create_publisher(EpisodeMarker, "probe_marker", 10)]
marker = EpisodeMarker(kind=EpisodeMarker.END, episode=2, task="dial", seed=-1, sketch=[3, 1, 4, 1],
                       steps=120, success=True)
marker.header.stamp.sec = 9
boundary = SubtaskBoundary(node="/a/ompn_node", episode=3, step=41, subtask=2, subtask_id=7, score=0.25,
                           memory_level=2, decided_step=42, final=True)
boundary.header.frame_id = "base_link"
boundary.header.stamp.sec = 12
boundary.decided_stamp.nanosec = 5
state = SubtaskState(episode=3, step=41, pi=[0.5, 0.25, 0.25], expected_position=1.75, pi_end=0.125)
deadline = time.monotonic() + 20
while len(got) < 3 and time.monotonic() < deadline:
    pubs[0].publish(boundary)
    pubs[1].publish(state)
    pubs[2].publish(marker)
    rclpy.spin_once(node, timeout_sec=0.1)
assert got.get("probe_boundary") == boundary, got
assert got.get("probe_state") == state, got
assert got.get("probe_marker") == marker, got
print("roundtrip ok")
"""


@pytest.mark.skipif(shutil.which("cmake") is None, reason="needs cmake and a C/C++ compiler")
def test_builds_from_tracked_files_and_rclpy_publishes_it(tmp_path: Path, ros_env: dict[str, str]):
    tracked = subprocess.run(["git", "ls-files", "ompn_interfaces"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.split()
    assert "ompn_interfaces/msg/SubtaskBoundary.msg" in tracked
    for name in tracked:  # a fresh clone's copy of the package: nothing ignored or untracked
        (tmp_path / "src" / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, tmp_path / "src" / name)
    prefix = tmp_path / "prefix"
    built = subprocess.run(
        [sys.executable, str(tmp_path / "src/ompn_interfaces/build_venv.py"), "--prefix", str(prefix),
         "--build-dir", str(tmp_path / "build")],
        env=ros_env, capture_output=True, text=True, timeout=280,
    )
    assert built.returncode == 0, built.stderr
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    env = dict(ros_env)
    env["PYTHONPATH"] = str(site)
    env["LD_LIBRARY_PATH"] = f"{prefix / 'lib'}:{env.get('LD_LIBRARY_PATH', '')}"
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # the child sets its library path up afresh
    done = subprocess.run([sys.executable, "-c", PUBSUB, str(site)], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0 and "roundtrip ok" in done.stdout, done.stderr[-3000:]


def test_a_missing_tool_is_one_line_and_exit_2(tmp_path: Path, ros_env: dict[str, str]):
    env = dict(ros_env)
    env["PATH"] = str(tmp_path)  # neither cmake nor a compiler
    done = subprocess.run([sys.executable, str(ROOT / "ompn_interfaces/build_venv.py"), "--prefix",
                           str(tmp_path / "p"), "--build-dir", str(tmp_path / "b")],
                          env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == ["ompn_interfaces: 'cmake' not found; install CMake and a "
                                                "C/C++ compiler (e.g. apt install cmake build-essential) "
                                                "and run again"]
