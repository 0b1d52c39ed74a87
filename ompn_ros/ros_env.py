"""Environment for child processes that start rclpy (ROS-free: only environment variables)."""

from __future__ import annotations

import os
import time


def child_env() -> dict[str, str]:
    """A copy of this process's environment for ROS child processes.

    Keeps ``LD_LIBRARY_PATH`` (the ROS wheels need it), forces DDS discovery onto loopback and keeps
    the caller's ``ROS_DOMAIN_ID`` (or picks one in 1..100) so parent and children share a domain.
    """
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", str(1 + int(time.time()) % 100))
    env["PYTHONUNBUFFERED"] = "1"
    return env
