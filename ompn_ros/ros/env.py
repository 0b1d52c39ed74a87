"""Environment for child processes that start rclpy (ROS-free: only environment variables)."""

from __future__ import annotations

import os
import sys

from ompn_ros.ros import containment


def child_env() -> dict[str, str]:
    """A copy of this process's environment for ROS child processes, this process contained too.

    Keeps ``LD_LIBRARY_PATH`` (the ROS wheels need it), confines DDS to loopback and shared memory
    (:func:`ompn_ros.ros.containment.contain`) and keeps the caller's ``ROS_DOMAIN_ID`` when ROS can use
    it (0..101 or 215..232, :func:`~ompn_ros.ros.containment.usable_domain`), or picks one in 1..100
    when it is unset or unusable (saying so in one line on stderr).  The same settings are written to
    ``os.environ`` so that this process, when it starts rclpy afterwards, shares the children's domain
    and transports.
    """
    before = os.environ.get("ROS_DOMAIN_ID", "")
    containment.contain(os.environ, keep_user_domain=True)
    if before and before != os.environ["ROS_DOMAIN_ID"]:
        print(f"ROS_DOMAIN_ID={before} is not a domain ROS can use here (0..101 or 215..232); this run "
              f"uses ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}", file=sys.stderr)
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env
