"""Environment for child processes that start rclpy (ROS-free: only environment variables)."""

from __future__ import annotations

import os

from ompn_ros import containment


def child_env() -> dict[str, str]:
    """A copy of this process's environment for ROS child processes.

    Keeps ``LD_LIBRARY_PATH`` (the ROS wheels need it), confines DDS to loopback and shared memory
    (:func:`ompn_ros.containment.contain`) and keeps the caller's ``ROS_DOMAIN_ID`` (or picks one
    in 1..100) so parent and children share a domain.
    """
    env = dict(os.environ)
    containment.contain(env)
    env["PYTHONUNBUFFERED"] = "1"
    return env
