"""Every ompn_* command: a known error is one line on stderr and exit code 2 (a traceback only with
--debug); help texts show a default and no markup; --help has no side effects."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from synthetic_episodes import make_episodes

from lab import reproduce
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.cli import closed_loop, collect, demo, ensemble, live_demo, segment, train
from ompn_ros.cli._common import missing_default_texts
from ompn_ros.data import write_episodes
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig

ROOT = Path(__file__).resolve().parents[2]
CLIS = {
    "ompn_train": train,
    "ompn_collect": collect,
    "ompn_segment": segment,
    "ompn_ensemble": ensemble,
    "python -m lab.reproduce": reproduce,
    "ompn_closed_loop": closed_loop,
    "ompn_demo": demo,
    "ompn_live_demo": live_demo,
}


def _one_line_error(err: str, prog: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, err)


def test_a_missing_bag_is_one_line_and_exit_2_in_a_real_process(tmp_path: Path, ros_env: dict[str, str]):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "ompn_ros.cli.train",
            "--bags",
            str(tmp_path / "no_such_bag"),
            "--config",
            str(ROOT / "config" / "train_craft.yaml"),
            "--out",
            str(tmp_path / "out"),
        ],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert result.returncode == 2, result.stderr
    _one_line_error(result.stderr, "ompn_train", "no_such_bag")


@pytest.fixture(scope="module")
def truncated_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag = tmp_path_factory.mktemp("corrupt") / "bag"
    write_episodes(
        bag, make_episodes("craft", 25, seed=5, min_steps=30, max_steps=30), "craft", storage="mcap"
    )
    file = next(p for p in bag.iterdir() if p.suffix == ".mcap")
    with open(file, "r+b") as fh:
        fh.truncate(file.stat().st_size * 3 // 4)
    return bag


def test_a_corrupt_bag_is_one_line_or_its_good_part_with_skip_tail(
    truncated_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    args = [
        "--bag",
        str(truncated_bag),
        "--checkpoint",
        str(shipped_checkpoint("craft")),
        "--domain",
        "craft",
        "--plot-episodes",
        "0",
        "--out",
        str(tmp_path / "out"),
    ]
    assert segment.main(args) == 2
    _one_line_error(capsys.readouterr().err, "ompn_segment", ".mcap")
    assert segment.main([*args, "--on-error", "skip_tail"]) == 0
    err = capsys.readouterr().err
    assert "dropped episodes" in err  # the read report, printed
    stored = json.loads((tmp_path / "out" / "read_report.json").read_text())
    assert stored["on_error"] == "skip_tail" and 1 <= stored["episodes"] < 25 and stored["errors"]
    assert "dropped episodes" in (tmp_path / "out" / "read_report.txt").read_text()
    replayed = json.loads((tmp_path / "out" / "boundaries.json").read_text())["episodes"]
    assert len(replayed) == stored["episodes"]


def test_a_wrong_checkpoint_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    (tmp_path / "empty").mkdir()
    assert (
        segment.main(["--checkpoint", str(tmp_path / "empty"), "--generate", "1", "--domain", "craft"]) == 2
    )
    _one_line_error(capsys.readouterr().err, "ompn_segment", "--checkpoint")
    code = ensemble.main(["--out", str(tmp_path / "ens"), str(tmp_path / "empty"), str(tmp_path / "empty")])
    assert code == 2
    _one_line_error(capsys.readouterr().err, "ompn_ensemble")


def test_a_model_that_produces_nan_names_the_episode(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    config = OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5, n_slots=2, slot_size=8)
    policy = build_policy(config)
    with torch.no_grad():
        for parameter in policy.parameters():
            parameter.fill_(float("nan"))
    save_checkpoint(tmp_path / "nan", policy)
    args = ["--checkpoint", str(tmp_path / "nan"), "--generate", "1", "--domain", "craft"]
    for mode in (["--out", str(tmp_path / "out")], ["--tune"]):  # replay and tuning
        assert segment.main([*args, *mode]) == 2
        _one_line_error(capsys.readouterr().err, "ompn_segment", "episode 0", "non-finite p_hat")


def test_an_invalid_config_is_one_line_and_debug_shows_the_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    args = ["--synthetic", "discrete", "--out", str(tmp_path / "o"), "--set", "model.n_slots=0"]
    assert train.main(args) == 2
    _one_line_error(capsys.readouterr().err, "ompn_train", "n_slots")
    with pytest.raises(ValueError, match="n_slots"):
        train.main([*args, "--debug"])
    assert reproduce.main(["craft", "--test-ratio", "1.5", "--work", str(tmp_path / "w")]) == 2
    _one_line_error(capsys.readouterr().err, "python -m lab.reproduce", "--test-ratio")
    assert reproduce.main([]) == 2
    _one_line_error(capsys.readouterr().err, "python -m lab.reproduce", "domain")
    assert not (tmp_path / "w").exists()


BUG_OR_KNOWN = """
import sys
from ompn_ros.app import training
from ompn_ros.app.errors import TrainSetupError
from ompn_ros.cli import train

def load_config(path):
    raise {error}("load_config failed")

# patched where ompn_train looks it up: the command imports its services when it runs (--help loads
# no torch), from ompn_ros.app.training
training.load_config = load_config
sys.exit(train.main(["--synthetic", "discrete", "--out", sys.argv[1]]))
"""


@pytest.mark.parametrize(("error", "code"), [("ValueError", 1), ("TrainSetupError", 2)])
def test_a_bug_keeps_its_traceback_and_a_known_error_is_one_line(
    error: str, code: int, tmp_path: Path, ros_env: dict[str, str]
):
    result = subprocess.run(
        [sys.executable, "-c", BUG_OR_KNOWN.format(error=error), str(tmp_path / "out")],
        env=ros_env, capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )
    assert result.returncode == code, result.stderr
    if error == "ValueError":  # a plain ValueError is a bug, not a user's mistake
        assert "Traceback" in result.stderr and "ValueError: load_config failed" in result.stderr
    else:
        _one_line_error(result.stderr, "ompn_train", "load_config failed")


def test_a_bad_data_entry_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    args = ["--synthetic", "discrete", "--out", str(tmp_path / "o"), "--set", "data.synthetic_seed=abc"]
    assert train.main(args) == 2
    _one_line_error(capsys.readouterr().err, "ompn_train", "data.synthetic_seed", "'abc'")


@pytest.mark.parametrize("prog", sorted(CLIS))
def test_every_flag_has_help_with_its_default_and_no_markup(prog: str):
    parser = CLIS[prog].build_parser()
    assert parser.prog == prog
    assert isinstance(parser.formatter_class, type)
    assert issubclass(parser.formatter_class, argparse.ArgumentDefaultsHelpFormatter)
    for action in parser._actions:
        assert action.help, (prog, action.dest)
    assert missing_default_texts(parser) == [], "say what the option does when it is not given"
    text = parser.format_help()
    assert "``" not in text and ":mod:" not in text and ":func:" not in text
    if any(a.default not in (None, False) and a.option_strings for a in parser._actions if a.dest != "help"):
        assert "(default: " in text


@pytest.mark.parametrize("prog", sorted(CLIS))
def test_help_has_no_side_effects(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        CLIS[prog].main(["--help"])
    assert info.value.code == 0
    assert "usage:" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []


def test_the_commands_do_not_import_each_other():
    import ast

    for path in sorted((ROOT / "ompn_ros" / "cli").glob("*.py")):
        tree = ast.parse(path.read_text())
        imported = {
            node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module
        }
        imported |= {
            f"ompn_ros.cli.{a.name}"
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module == "ompn_ros.cli"
            for a in node.names
        }
        # private modules (``_common``, ``_batch``) are helpers of the commands, not commands
        others = {m for m in imported
                  if m.startswith("ompn_ros.cli.") and not m.rpartition(".")[2].startswith("_")}
        assert not others, (path.name, others)
