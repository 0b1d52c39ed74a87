"""DDS containment: rclpy must only ever run with discovery restricted to localhost."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_pytest_session_is_contained():
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert 1 <= int(os.environ["ROS_DOMAIN_ID"]) <= 100


def test_rclpy_context_sees_localhost_discovery_range():
    """What rcl actually applies, read back from a live context, not just the environment."""
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
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_guard_fails_when_discovery_is_widened(tmp_path: Path):
    """The autouse guard in conftest.py must turn a widened range into a failing test."""
    (tmp_path / "conftest.py").write_text((ROOT / "test" / "conftest.py").read_text())
    (tmp_path / "test_widen.py").write_text(
        "import os\n"
        "import rclpy  # noqa: F401\n"
        "def test_widen():\n"
        "    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'\n"
    )
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, env=dict(os.environ),
    )
    assert result.returncode != 0, result.stdout
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE is not LOCALHOST" in result.stdout


def test_makefile_exports_containment():
    makefile = (ROOT / "Makefile").read_text()
    assert "export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST" in makefile
    assert "export ROS_DOMAIN_ID" in makefile
