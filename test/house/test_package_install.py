"""The package installs the way `ros2 run` expects: colcon build, ament index, console scripts."""

from __future__ import annotations

import ast
import json
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = Path(sys.executable).parent


def _own_topic() -> str:
    """A remap rule giving one test its own topic: a process left over from another test is never its peer."""
    return f"-r smoke:=smoke_{uuid.uuid4().hex[:12]}"


def _console_scripts() -> list[str]:
    """Names of the console scripts declared in setup.py (parsed, not imported)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    return [elt.value.split("=")[0].strip() for elt in value.elts]  # type: ignore[attr-defined]
    raise AssertionError("setup.py declares no console_scripts")


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory) -> Path:
    """A fresh `colcon build` of this package and its interface package (as `make colcon`: the ROS
    wheels of the venv are the underlay); returns the install base."""
    work = tmp_path_factory.mktemp("colcon")
    colcon = VENV_BIN / "colcon"
    if not colcon.exists():
        pytest.fail("colcon is not installed in the venv; run `make setup`")
    env = dict(os.environ)
    env["PATH"] = f"{VENV_BIN}:{env.get('PATH', '')}"
    env["AMENT_PREFIX_PATH"] = env["CMAKE_PREFIX_PATH"] = sys.prefix
    result = subprocess.run(
        [str(colcon), "build", "--base-paths", str(ROOT), str(ROOT / "ompn_interfaces"),
         "--build-base", str(work / "build"), "--install-base", str(work / "install")],
        cwd=work, env=env, capture_output=True, text=True, timeout=480,
    )
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout}\n{result.stderr}"
    return work / "install"


def _in_setup_bash(install: Path, command: str, **kwargs) -> subprocess.CompletedProcess:
    """Run `command` in bash after sourcing install/setup.bash, as a ROS user would."""
    env = dict(os.environ)
    env["PATH"] = f"{VENV_BIN}:{env.get('PATH', '')}"
    return subprocess.run(
        ["bash", "-c", f"source {install}/setup.bash && {command}"],
        env=env, capture_output=True, text=True, **kwargs,
    )


def test_ament_index_resolves_package_and_share(colcon_install: Path):
    probe = (
        "from ament_index_python.packages import get_package_prefix, get_package_share_directory;"
        "import json, os;"
        "share = get_package_share_directory('ompn_ros');"
        "print(json.dumps({'prefix': get_package_prefix('ompn_ros'), 'share': share,"
        " 'files': sorted(os.listdir(share)), 'config': sorted(os.listdir(os.path.join(share, 'config')))}))"
    )
    result = _in_setup_bash(colcon_install, f"python -c \"{probe}\"", timeout=60)
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout.strip().splitlines()[-1])
    assert Path(info["prefix"]) == colcon_install / "ompn_ros"
    assert "package.xml" in info["files"]
    shipped = sorted(p.name for pattern in ("*.yaml", "*.xml") for p in (ROOT / "config").glob(pattern))
    assert shipped and info["config"] == shipped


def test_the_interface_package_is_installed_beside_it(colcon_install: Path):
    probe = ("import ompn_interfaces, rclpy.serialization as s;"
             "from ompn_interfaces.msg import SubtaskBoundary;"
             "m = SubtaskBoundary(step=3, final=True);"
             "assert s.deserialize_message(s.serialize_message(m), SubtaskBoundary) == m;"
             "print(ompn_interfaces.__file__)")
    result = _in_setup_bash(colcon_install, f"python -c \"{probe}\"", timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().startswith(str(colcon_install / "ompn_interfaces")), result.stdout


def test_every_console_script_is_where_ros2_run_looks(colcon_install: Path):
    lib = colcon_install / "ompn_ros" / "lib" / "ompn_ros"
    scripts = _console_scripts()
    assert {"ompn_node", "craft_sim", "dial_sim", "bag_recorder", "ompn_train"} <= set(scripts)
    for name in scripts:
        path = lib / name
        assert path.is_file(), f"console script {name} missing from {lib}"
        assert os.access(path, os.X_OK), f"{path} is not executable"


def test_installed_executables_talk_across_processes_and_stop_on_sigint(colcon_install: Path):
    """smoke_listener and smoke_talker from install/lib/ompn_ros exchange messages over DDS."""
    lib = colcon_install / "ompn_ros" / "lib" / "ompn_ros"
    params = colcon_install / "ompn_ros" / "share" / "ompn_ros" / "config" / "smoke.yaml"
    remap = _own_topic()
    listener = subprocess.Popen(
        ["bash", "-c", f"source {colcon_install}/setup.bash && exec {lib}/smoke_listener "
         f"--ros-args --params-file {params} {remap} -p count:=30 -p timeout:=15.0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PATH": f"{VENV_BIN}:{os.environ['PATH']}"},
    )
    try:
        talker = _in_setup_bash(
            colcon_install,
            f"exec {lib}/smoke_talker --ros-args --params-file {params} {remap} "
            "-p count:=30 -p wait_for_subscriber:=15.0",
            timeout=60,
        )
        assert talker.returncode == 0, talker.stderr
        out, err = listener.communicate(timeout=30)
    finally:
        listener.kill()
    assert listener.returncode == 0, f"listener failed:\n{out}\n{err}"
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["received"] == 30 and summary["lost"] == 0
    sent = json.loads(talker.stdout.strip().splitlines()[-1])
    assert sent["published"] == 30 and sent["matched"] >= 1 and sent["acked"] is True, sent
    assert sent["topic"].startswith("/smoke_"), sent  # the remap reached the node


def test_installed_talker_exits_cleanly_on_sigint(colcon_install: Path):
    """SIGINT while publishing: exit 0, no traceback, the shutdown summary printed."""
    lib = colcon_install / "ompn_ros" / "lib" / "ompn_ros"
    params = colcon_install / "ompn_ros" / "share" / "ompn_ros" / "config" / "smoke.yaml"
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ['PATH']}"}
    remap = _own_topic()
    proc = subprocess.Popen(
        ["bash", "-c", f"source {colcon_install}/setup.bash && exec {lib}/smoke_talker "
         f"--ros-args --params-file {params} {remap} -p count:=1000000 -p rate:=100.0 "
         "-p wait_for_subscriber:=0.0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        # The signal must arrive while the talker publishes (not during its start-up): a listener that
        # received 5 of its messages proves it is in its publishing loop, however loaded the machine is.
        listener = _in_setup_bash(
            colcon_install,
            f"exec {lib}/smoke_listener --ros-args --params-file {params} {remap} "
            "-p count:=5 -p timeout:=60.0",
            timeout=120,
        )
        assert listener.returncode == 0, f"no messages from the talker:\n{listener.stdout}\n{listener.stderr}"
        assert proc.poll() is None, f"talker died early: {proc.communicate()}"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, f"exit {proc.returncode}:\n{out}\n{err}"
    assert "Traceback" not in err
    assert json.loads(out.strip().splitlines()[-1])["published"] > 0  # its shutdown summary
