"""train.threads: 'auto' follows the usable cores and the load; Ctrl-C stops ompn_train promptly in one
line and leaves a state that --resume continues."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ompn_ros.app.training import load_config
from ompn_ros.cli.train import main
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError
from ompn_ros.train.threads import auto_threads, resolve_threads, usable_cores

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("cores", "load", "env", "expected"),
    [
        (2, 0.0, {}, 2),  # idle cores: all of them
        (2, 0.3, {}, 1),  # a little load on 2 cores: one thread (the 75 s vs 3.75 s case)
        (2, 5.0, {}, 1),  # overloaded: never fewer than 1
        (16, 3.2, {}, 12),  # the free cores, rounded down
        (4, 0.0, {"WORLD_SIZE": "2"}, 1),  # several processes train: 1 each
        (4, 0.0, {"LOCAL_WORLD_SIZE": "4"}, 1),
        (4, 0.0, {"OMP_NUM_THREADS": "8"}, 4),  # the user's count, never more than the cores
        (4, 3.0, {"OMP_NUM_THREADS": "3"}, 3),
        (4, 0.0, {"OMP_NUM_THREADS": "x"}, 4),  # unreadable: ignored
    ],
)
def test_auto_threads_rule(cores: int, load: float, env: dict[str, str], expected: int) -> None:
    assert auto_threads(cores, load, env) == expected


def test_auto_never_exceeds_the_usable_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert resolve_threads("auto") == usable_cores() == len(os.sched_getaffinity(0))
    assert resolve_threads(3) == 3 and resolve_threads(0) == 0


@pytest.mark.parametrize("name", ["craft", "dial"])
def test_shipped_configs_choose_threads_automatically(name: str) -> None:
    config = load_config(str(ROOT / "config" / f"train_{name}.yaml"))
    assert config["train"]["threads"] == "auto"
    assert TrainConfig.from_dict(config["train"]).threads == "auto"
    assert TrainConfig().threads == "auto"


@pytest.mark.parametrize("bad", [-1, "two", 1.5, True])
def test_bad_threads_name_the_field(bad: object) -> None:
    with pytest.raises(TrainConfigError, match="threads must be 'auto' or an int >= 0"):
        TrainConfig(threads=bad)  # type: ignore[arg-type]


def _args(out: Path, *extra: str) -> list[str]:
    settings = ["model.n_slots=2", "model.slot_size=16", "train.batch_size=8", "train.eval_every=100000",
                "train.iterations=100000", "train.patience=0", "train.progress=false",
                "train.boundary_head=false", *extra]
    config = str(ROOT / "config" / "train_craft.yaml")
    return ["--synthetic", "discrete", "--episodes", "16", "--config", config, "--out", str(out),
            *[part for item in settings for part in ("--set", item)]]


def _train(out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "ompn_ros.cli.train", *_args(out)], text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_ctrl_c_stops_in_one_line_and_resumes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: a KeyboardInterrupt traceback, exit 1, and only the last evaluation's state (none here)."""
    out = tmp_path / "run"
    proc = _train(out)
    assert proc.stderr is not None
    for line in proc.stderr:  # the loop has started once it names its threads
        if "torch threads:" in line:
            break
    time.sleep(1.0)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 130, err
    assert "Traceback" not in err and len(lines) == 1, err
    assert lines[0].startswith("ompn_train: interrupted: the state of iteration ") and "--resume" in lines[0]
    kept = int(lines[0].split("iteration ")[1].split()[0])
    assert 1 <= kept < 100000  # saved at the interrupt, long before the first evaluation
    state = json.loads((out / "train_state" / "LATEST").read_text())["dir"]
    assert state == f"it{kept:08d}"
    resumed = [*_args(out, f"train.iterations={kept + 1}", "train.eval_every=1"), "--resume"]
    assert main(resumed) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["iterations"] == kept + 1
