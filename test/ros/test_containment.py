"""DDS containment: Fast DDS runs on loopback and shared memory only, and the test suite enforces it.

The socket test reads the sockets of a node process the suite starts (``/proc/<pid>/fd`` and
``/proc/<pid>/net/*``); it sends nothing anywhere.  Its control run (the old setting: discovery range
LOCALHOST, no profile) shows the same check finding sockets bound beyond loopback.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ompn_ros.ros import containment

ROOT = Path(__file__).resolve().parents[2]
NODE = (
    "import time, rclpy\n"
    "from std_msgs.msg import Int32\n"
    "rclpy.init()\n"
    "node = rclpy.create_node('containment_probe')\n"
    "node.create_publisher(Int32, 'containment_probe', 10)\n"
    "node.create_subscription(Int32, 'containment_probe', lambda m: None, 10)\n"
    "print('up', flush=True)\n"
    "end = time.monotonic() + 20\n"
    "while time.monotonic() < end:\n"
    "    rclpy.spin_once(node, timeout_sec=0.1)\n"
)


def test_pytest_session_is_contained():
    assert containment.problems(os.environ) == []
    assert 1 <= int(os.environ["ROS_DOMAIN_ID"]) <= 100
    assert Path(os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"]).is_file()


@pytest.mark.parametrize("domain", ["150", "", "abc", "42", "0", "230", "233"])
def test_child_env_gives_this_process_and_its_children_one_domain(monkeypatch: pytest.MonkeyPatch,
                                                                   capsys: pytest.CaptureFixture[str],
                                                                   domain: str):
    from ompn_ros.ros.env import child_env

    monkeypatch.setenv("ROS_DOMAIN_ID", domain)
    monkeypatch.setenv("ROS_LOCALHOST_ONLY", "1")
    env = child_env()
    assert env["ROS_DOMAIN_ID"] == os.environ["ROS_DOMAIN_ID"]
    assert containment.problems(os.environ) == [] and containment.problems(env) == []
    assert env.get("LD_LIBRARY_PATH") == os.environ.get("LD_LIBRARY_PATH")
    note = capsys.readouterr().err
    if domain in ("42", "0", "230"):  # the user's own domain when ROS can use it (before: 0, 230 replaced)
        assert env["ROS_DOMAIN_ID"] == domain and note == ""
        return
    assert 1 <= int(env["ROS_DOMAIN_ID"]) <= 100
    if domain:
        assert note.count("\n") == 1
        assert f"ROS_DOMAIN_ID={domain} is not a domain ROS can use here (0..101 or 215..232)" in note


def _node_sockets(env: dict[str, str]) -> list[containment.BoundSocket]:
    proc = subprocess.Popen([sys.executable, "-c", NODE], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.strip() == "up", line + proc.stdout.read()
        time.sleep(1.5)  # discovery has opened its channels
        return containment.bound_sockets(proc.pid)
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.skipif(not Path("/proc/self/net/udp").is_file(), reason="needs Linux /proc")
def test_every_socket_of_a_contained_node_is_bound_to_loopback(ros_env: dict[str, str]):
    pytest.importorskip("rclpy")
    sockets = _node_sockets(ros_env)
    assert sockets, "the node holds no UDP/TCP socket: the check would prove nothing"
    outside = [s for s in sockets if not s.loopback]
    assert not outside, f"sockets bound beyond loopback: {outside}"


@pytest.mark.skipif(not Path("/proc/self/net/udp").is_file(), reason="needs Linux /proc")
def test_control_localhost_range_without_profile_binds_beyond_loopback(ros_env: dict[str, str]):
    """The check can fail: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST alone binds 0.0.0.0."""
    pytest.importorskip("rclpy")
    env = dict(ros_env)
    for name in containment.PROFILE_VARS:
        env.pop(name, None)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    sockets = _node_sockets(env)
    assert any(not s.loopback for s in sockets), sockets


def test_socket_addresses_decode() -> None:
    assert containment.BoundSocket("udp", "127.0.0.1", 7400).loopback
    assert not containment.BoundSocket("udp", "0.0.0.0", 7400).loopback
    assert containment.BoundSocket("udp6", "::1", 7400).loopback
    assert containment.BoundSocket("udp6", "::ffff:127.0.0.1", 7400).loopback
    assert containment._decode_address("0100007F") == "127.0.0.1"
    assert containment._decode_address("00000000000000000000000001000000") == "::1"


def test_contain_sets_profile_range_and_clears_peers() -> None:
    env = {"ROS_STATIC_PEERS": "192.0.2.7", "ROS_LOCALHOST_ONLY": "1", "ROS_DOMAIN_ID": "0"}
    containment.contain(env)
    assert containment.problems(env) == []
    assert env["ROS_STATIC_PEERS"] == "" and "ROS_LOCALHOST_ONLY" not in env
    assert 1 <= int(env["ROS_DOMAIN_ID"]) <= 100
    widened = dict(env, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_STATIC_PEERS="192.0.2.7")
    assert len(containment.problems(widened)) == 2


def test_rclpy_context_starts_under_the_profile():
    """A context and node come up with the loopback profile (a broken profile would fail here)."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("containment_probe", context=ctx)
        try:
            assert node.get_parameter("use_sim_time").value is False  # node is alive
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_guard_fails_when_containment_is_undone(tmp_path: Path):
    """The autouse guard in conftest.py must turn a widened discovery range into a failing test."""
    (tmp_path / "conftest.py").write_text((ROOT / "test" / "conftest.py").read_text())
    (tmp_path / "test_widen.py").write_text(
        "import os\n"
        "import rclpy  # noqa: F401\n"
        "def test_widen():\n"
        "    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'\n"
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
    )
    assert result.returncode != 0, result.stdout
    assert "DDS is not contained" in result.stdout and "ROS_AUTOMATIC_DISCOVERY_RANGE" in result.stdout


def test_makefile_exports_containment():
    makefile = (ROOT / "Makefile").read_text()
    for line in ("export FASTRTPS_DEFAULT_PROFILES_FILE := $(CURDIR)/config/fastdds_loopback.xml",
                 "export FASTDDS_DEFAULT_PROFILES_FILE := $(CURDIR)/config/fastdds_loopback.xml",
                 "export ROS_AUTOMATIC_DISCOVERY_RANGE := SYSTEM_DEFAULT",
                 "export ROS_STATIC_PEERS :=",
                 "export ROS_DOMAIN_ID"):
        assert line in makefile, line
