"""A checkpoint fault at start-up is one line naming it and exit code 2 (README: every tool), not an
[ERROR] and a [FATAL] line with exit code 1."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from node_process import node_command

from ompn_ros.checkpoints import shipped_checkpoint

CASES = {
    "missing": (["checkpoint:=/nonexistent/ckpt"],
                "ompn_node: cannot start: checkpoint '/nonexistent/ckpt' is not a directory"),
    "other_domain": ([f"checkpoint:={shipped_checkpoint('craft')}", "domain:=dial"],
                     "ompn_node: cannot start: checkpoint action_dim=5 does not fit domain 'dial' "
                     "(action_dim=9)"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_checkpoint_fault_is_one_line_and_exit_2(case: str, ros_env: dict[str, str],
                                                   tmp_path: Path) -> None:
    args, line = CASES[case]
    done = subprocess.run(node_command(*args), env=ros_env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=240)
    assert done.returncode == 2, done.stdout + done.stderr
    problems = [x for x in (done.stdout + done.stderr).splitlines() if "[INFO]" not in x]
    assert problems == [line], problems
