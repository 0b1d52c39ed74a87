"""README's "Real ROS 2 Jazzy install" section works when followed literally in a fresh venv.

The fenced shell block under that heading is run line by line in bash with ``HOME`` in a temporary
directory (so ``~/ws`` is fresh) and a fresh ``python3 -m venv`` activated first.  Lines that need a
ROS 2 installation (``ros2 ...``, ``source /opt/ros/...``) are left out: ROS 2 is not installable
here.  ``git clone <repo> ompn_ros`` clones this checkout (its committed HEAD).  Afterwards the
workspace must hold the colcon install of ompn_ros, and its console scripts must run with every
runtime dependency from the fresh venv: one Dial episode is collected into an mcap bag and read back.
The interface package (ament_cmake) needs the ROS build tools: in place of ``source
/opt/ros/jazzy/setup.bash`` an underlay venv gets the ROS 2 wheels and ompn_interfaces' build
requirements, and the same variables setup.bash sets point at it (:data:`UNDERLAY`).

Slow (it downloads and installs torch, mujoco, dm_control, ...): ``pytest -m slow``.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEADING = re.compile(r"^##\s+.*real ros 2 jazzy install.*$", re.IGNORECASE | re.MULTILINE)
FENCE = re.compile(r"^```(?:bash|sh|shell)?\s*\n(.*?)^```", re.DOTALL | re.MULTILINE)
SKIPPED = ("ros2 ", "source /opt/ros")
CLONE = re.compile(r"git clone\s+(<[^>]*>|\S+)")

# The stand-in for `source /opt/ros/jazzy/setup.bash`: the ROS 2 wheels in a venv of their own, and the
# variables a ROS setup.bash sets (prefix paths, Python path, library path) pointing at it.
UNDERLAY = r"""
python3 -m venv ~/ros_underlay
~/ros_underlay/bin/python -m pip install --quiet 'ros-jazzy-rclpy[fastrtps]==7.1.6' \
    'ros-jazzy-common-interfaces==5.3.6' numpy==2.4.6 -r {repo}/ompn_interfaces/requirements-venv.txt
U=~/ros_underlay; SITE=$(echo $U/lib/python3*/site-packages); LIBS=$(ls -d $SITE/ros_*.libs | tr '\n' ':')
export AMENT_PREFIX_PATH=$U CMAKE_PREFIX_PATH=$U PYTHONPATH=$SITE LD_LIBRARY_PATH=$U/lib:$LIBS
"""

# After the block: cwd is the workspace and install/setup.bash is sourced (the block's last steps).
CHECKS = r"""
test -x install/ompn_ros/lib/ompn_ros/ompn_node
test -x install/ompn_ros/lib/ompn_ros/dial_sim
ls install/ompn_ros/share/ompn_ros/launch/ompn_node.launch.py
ls install/ompn_ros/share/ompn_ros/config/ompn_node_dial.yaml
python - <<'PY'
import os, sys
import dm_control, gymnasium, matplotlib, mujoco, numba, rosbags, safetensors, scipy, torch, tqdm, yaml
import ompn_ros, sim_nodes
assert sys.prefix != sys.base_prefix, "no venv is active"
assert ompn_ros.__file__.startswith(os.getcwd()), f"ompn_ros imported from {ompn_ros.__file__}"
print("imports ok", sys.prefix, torch.__version__)
PY
install/ompn_ros/lib/ompn_ros/ompn_collect --domain dial --episodes 1 --seed 0 --out "$HOME/bags/dial" --quiet
python - <<'PY'
import os
from ompn_ros.data.reader import read_episodes
eps = read_episodes(os.path.expanduser("~/bags/dial")).episodes
assert len(eps) == 1 and len(eps[0].actions) > 0, eps
print("bag ok", len(eps[0].actions))
PY
"""


class ReadmeSectionError(AssertionError):
    """README.md has no usable install section."""


def install_block(readme: str) -> str:
    """The first fenced shell block under the "Real ROS 2 Jazzy install" heading."""
    heading = HEADING.search(readme)
    if heading is None:
        raise ReadmeSectionError("README.md has no '## Real ROS 2 Jazzy install' section")
    section = readme[heading.end():]
    following = re.search(r"^## ", section, re.MULTILINE)
    section = section[: following.start()] if following else section
    fence = FENCE.search(section)
    if fence is None:
        raise ReadmeSectionError("the 'Real ROS 2 Jazzy install' section has no fenced shell block")
    return fence.group(1)


def runnable_lines(block: str, repo: Path) -> list[str]:
    """The block's commands without the ROS-only lines; the clone source becomes ``repo``."""
    lines = []
    for raw in block.splitlines():
        line = raw.strip()
        if line.startswith("source /opt/ros"):
            lines.append(UNDERLAY.format(repo=shlex.quote(str(repo))).strip())
            continue
        if not line or line.startswith("#") or line.startswith(SKIPPED):
            continue
        lines.append(CLONE.sub(f"git clone {shlex.quote(str(repo))}", line))
    return lines


def _fresh_env(home: Path) -> dict[str, str]:
    """os.environ without this venv and without PYTHONPATH, HOME in tmp."""
    env = dict(os.environ)
    for name in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME"):
        env.pop(name, None)
    ours = str(Path(sys.executable).parent)
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if p != ours)
    env["HOME"] = str(home)
    env["PYTHONNOUSERSITE"] = "1"
    return env


def run_install(block: str, repo: Path, home: Path, timeout: float = 3000.0) -> subprocess.CompletedProcess:
    """Run the block's commands (then CHECKS) in bash inside a fresh venv under ``home``."""
    home.mkdir(parents=True, exist_ok=True)
    venv = home / "fresh-venv"
    script = [f"python3 -m venv {shlex.quote(str(venv))}",
              f"source {shlex.quote(str(venv / 'bin' / 'activate'))}", "cd ~"]
    for line in runnable_lines(block, repo):
        shown = shlex.quote(line)
        # an `a && b` line fails as a whole: stop at the first line that does not succeed
        script += [f"echo + {shown} >&2", line,
                   f"rc=$?; if [ $rc -ne 0 ]; then echo FAILED with $rc: {shown} >&2; exit $rc; fi"]
    script += ["set -eo pipefail", CHECKS]
    return subprocess.run(["bash", "-c", "\n".join(script)], cwd=home, env=_fresh_env(home),
                          capture_output=True, text=True, timeout=timeout)


def test_block_extraction_drops_ros_lines_and_points_clone_here(tmp_path: Path):
    readme = (
        "# x\n## Real ROS 2 Jazzy install\n```bash\nsource /opt/ros/jazzy/setup.bash\n"
        "git clone <this repo> ompn_ros  # the package\npip install -r ompn_ros/requirements.txt\n"
        "ros2 launch ompn_ros dial_sim.launch.py\n```\n## Next\n```bash\nnot this\n```\n"
    )
    lines = runnable_lines(install_block(readme), tmp_path)
    expected = [UNDERLAY.format(repo=shlex.quote(str(tmp_path))).strip(),  # for `source /opt/ros/...`
                f"git clone {tmp_path} ompn_ros  # the package", "pip install -r ompn_ros/requirements.txt"]
    assert lines == expected
    with pytest.raises(ReadmeSectionError, match="no '## Real ROS 2 Jazzy install' section"):
        install_block("# x\n## Install\n```bash\nls\n```\n")
    with pytest.raises(ReadmeSectionError, match="no fenced shell block"):
        install_block("## Real ROS 2 Jazzy install\ntext only\n## Next\n```bash\nls\n```\n")


def test_readme_section_names_the_launch_files_and_requirements():
    block = install_block((ROOT / "README.md").read_text())
    assert "requirements.txt" in block
    assert "colcon build" in block
    assert re.search(r"ros2 launch ompn_ros \w+\.launch\.py", block), "the block shows no `ros2 launch`"


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_readme_install_section_works_in_a_fresh_venv(tmp_path: Path):
    if not (ROOT / ".git").exists():
        pytest.skip("the section clones the repository: this is no git checkout")
    block = install_block((ROOT / "README.md").read_text())
    result = run_install(block, ROOT, tmp_path / "home")
    tail = "\n".join((result.stdout + "\n" + result.stderr).splitlines()[-60:])
    assert result.returncode == 0, f"the README install section failed:\n{tail}"
    assert "imports ok" in result.stdout and "bag ok" in result.stdout, tail
