"""Test-wide setup: DDS containment before anything can import rclpy."""

from __future__ import annotations

import os
import random
import sys

# Fast DDS must never send discovery traffic off this machine, and concurrent runs must not
# see each other. This runs before any test module imports rclpy, so a bare `pytest` is contained.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
if not os.environ.get("ROS_DOMAIN_ID", "").isdigit() or not 1 <= int(os.environ["ROS_DOMAIN_ID"]) <= 100:
    os.environ["ROS_DOMAIN_ID"] = str(random.randint(1, 100))
os.environ.setdefault("MUJOCO_GL", "egl")

import pytest


@pytest.fixture(autouse=True)
def _dds_stays_on_loopback():
    """Fail any test that leaves rclpy in use with discovery widened beyond localhost."""
    yield
    if "rclpy" in sys.modules:
        assert os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST", (
            "rclpy is in use but ROS_AUTOMATIC_DISCOVERY_RANGE is not LOCALHOST: "
            "DDS discovery would leave the machine"
        )


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for child processes that start rclpy (keeps LD_LIBRARY_PATH and containment)."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    return env
