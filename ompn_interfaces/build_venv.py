"""Build and install ompn_interfaces into a Python venv of the ROS 2 Jazzy wheels (``make setup``).

With a ROS install, build it as usual (``colcon build``, see README.md).  In a venv the ROS wheels
provide ament_cmake and the rosidl generators (``requirements-venv.txt``); this script runs CMake on
them and installs the messages' Python package, C libraries and type supports into the venv's prefix,
whose ``lib/`` the wheels already put on ``LD_LIBRARY_PATH``.  Needs ``cmake`` and a C/C++ compiler.

    python ompn_interfaces/build_venv.py [--prefix PREFIX] [--build-dir DIR]

Exits 2 with one line when a tool is missing or a step fails (the step's log is kept in DIR).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


class BuildError(Exception):
    """A known failure: a missing tool or a failed CMake step (one line, exit code 2)."""


def _run(step: str, cmd: list[str], env: dict[str, str], log: Path) -> None:
    with log.open("a") as out:
        out.write(f"$ {' '.join(cmd)}\n")
        out.flush()
        done = subprocess.run(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, check=False)
    if done.returncode != 0:
        tail = log.read_text(errors="replace").strip().splitlines()[-15:]
        print("\n".join(tail), file=sys.stderr)
        raise BuildError(f"ompn_interfaces: {step} failed (exit {done.returncode}); full log: {log}")


def build(prefix: Path, build_dir: Path) -> None:
    """Configure, build and install the package into ``prefix`` (the ROS wheels are in ``sys.prefix``)."""
    for tool in ("cmake", "cc", "c++"):
        if shutil.which(tool) is None:
            raise BuildError(f"ompn_interfaces: '{tool}' not found; install CMake and a C/C++ compiler "
                             "(e.g. apt install cmake build-essential) and run again")
    build_dir.mkdir(parents=True, exist_ok=True)
    log = build_dir / "build.log"
    log.write_text("")
    env = dict(os.environ)
    wheels = sys.prefix
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(p for p in (wheels, env.get("AMENT_PREFIX_PATH", "")) if p)
    env["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), env.get("PATH", "")))
    _run("configure", [
        "cmake", "-S", str(PACKAGE), "-B", str(build_dir), "-DBUILD_TESTING=OFF",
        "-DCMAKE_BUILD_TYPE=Release", f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DCMAKE_PREFIX_PATH={wheels}",
        f"-DPython3_EXECUTABLE={sys.executable}",
    ], env, log)  # fmt: skip
    jobs = str(max(1, min(4, os.cpu_count() or 1)))
    _run("build", ["cmake", "--build", str(build_dir), "--parallel", jobs], env, log)
    _run("install", ["cmake", "--install", str(build_dir)], env, log)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", type=Path, default=Path(sys.prefix), help="install prefix (the venv)")
    parser.add_argument("--build-dir", type=Path, default=PACKAGE.parent / "build" / "venv_ompn_interfaces",
                        help="CMake build directory (default: build/venv_ompn_interfaces of the repository)")
    args = parser.parse_args(argv)
    try:
        build(args.prefix.resolve(), args.build_dir.resolve())
    except BuildError as exc:
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
