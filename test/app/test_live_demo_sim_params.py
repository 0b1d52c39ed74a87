"""``--sim-param``: the live demo passes sim parameters (e.g. Craft's partial observation) to the sim."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest

from ompn_ros.app import live
from ompn_ros.cli import live_demo


def test_sim_params_are_parsed_and_the_demos_own_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    args = live_demo.build_parser().parse_args(
        ["--domain", "craft", "--sim-param", "full_obs:=false", "--sim-param", "task:=makeaxe"]
    )
    assert args.sim_param == ["full_obs:=false", "task:=makeaxe"]
    assert live_demo.build_parser().parse_args([]).sim_param == []
    for bad, reason in (("full_obs=false", "is not NAME:=VALUE"), ("rate:=5.0", "rate is set by the demo")):
        with pytest.raises(SystemExit) as exc:
            live_demo.build_parser().parse_args(["--sim-param", bad])
        assert exc.value.code == 2
        assert reason in capsys.readouterr().err


def test_launch_hands_the_sim_params_to_the_sim_only(monkeypatch: pytest.MonkeyPatch) -> None:
    commands: list[list[str]] = []

    class FakePopen:
        def __init__(self, cmd: list[str], **_: Any) -> None:
            commands.append(list(cmd))

    monkeypatch.setattr(subprocess, "Popen", FakePopen)
    live.launch("craft", Path("ckpt"), 50.0, 7, 2, "ompn_node", sim_params=["full_obs:=false"])
    node_cmd, sim_cmd = commands
    assert "sim_nodes.craft.node" in sim_cmd
    position = sim_cmd.index("full_obs:=false")
    assert sim_cmd[position - 1] == "-p" and position > sim_cmd.index("mode:=expert")
    assert "full_obs:=false" not in node_cmd
