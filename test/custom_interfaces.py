"""A lab's own interface package, ``my_robot_msgs``, built from its ``.msg`` files the way
``ompn_interfaces`` is built in the venv of the ROS wheels (CMake + rosidl generators, installed into a
prefix), for the tests that run ``ompn_node`` on a custom message type.

:func:`build` writes the package (the ``.msg`` files of :data:`type_corpus.MSG_FILES`), configures,
builds (one job) and installs it into ``<root>/prefix``; :func:`environment` is what a child process
needs to import and publish its messages.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import type_corpus as tc

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "my_robot_msgs"
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>my_robot_msgs</name>
  <version>0.1.0</version>
  <description>A lab's arm state</description>
  <maintainer email="lab@example.com">lab</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>std_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
CMAKE = """cmake_minimum_required(VERSION 3.8)
project(my_robot_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(std_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/GripperState.msg" "msg/ArmState.msg" DEPENDENCIES std_msgs)
include(cmake/drop_missing_include_dirs.cmake)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""


def build(root: Path, env: dict[str, str]) -> Path:
    """Build and install ``my_robot_msgs`` under ``root``; returns the install prefix."""
    src = root / "src" / PACKAGE
    (src / "msg").mkdir(parents=True)
    (src / "cmake").mkdir()
    shutil.copy2(ROOT / "ompn_interfaces" / "cmake" / "drop_missing_include_dirs.cmake", src / "cmake")
    (src / "package.xml").write_text(PACKAGE_XML)
    (src / "CMakeLists.txt").write_text(CMAKE)
    for name, text in tc.MSG_FILES.items():
        (src / "msg" / f"{name.rsplit('/', 1)[1]}.msg").write_text(text)
    prefix, build_dir = root / "prefix", root / "build"
    env = dict(env)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(p for p in (sys.prefix, env.get("AMENT_PREFIX_PATH", "")) if p)
    env["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), env.get("PATH", "")))
    steps = [
        [
            "cmake",
            "-S",
            str(src),
            "-B",
            str(build_dir),
            "-DBUILD_TESTING=OFF",
            "-DCMAKE_BUILD_TYPE=Release",
            f"-DCMAKE_INSTALL_PREFIX={prefix}",
            f"-DCMAKE_PREFIX_PATH={sys.prefix}",
            f"-DPython3_EXECUTABLE={sys.executable}",
        ],
        ["cmake", "--build", str(build_dir), "--parallel", "1"],
        ["cmake", "--install", str(build_dir)],
    ]
    for cmd in steps:
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[:2])} failed: {(done.stdout + done.stderr)[-3000:]}")
    return prefix


def environment(prefix: Path, env: dict[str, str]) -> dict[str, str]:
    """``env`` with the package importable (PYTHONPATH), loadable (LD_LIBRARY_PATH) and found by its
    share folder (AMENT_PREFIX_PATH)."""
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    out = dict(env)
    out["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH", "")) if p)
    out["LD_LIBRARY_PATH"] = os.pathsep.join(
        p for p in (str(prefix / "lib"), env.get("LD_LIBRARY_PATH", "")) if p
    )
    out["AMENT_PREFIX_PATH"] = os.pathsep.join(
        p for p in (str(prefix), env.get("AMENT_PREFIX_PATH", "")) if p
    )
    out.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # the child sets its library path up afresh
    return out
