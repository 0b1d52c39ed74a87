"""ompn_train command line: configs, overrides, synthetic smoke run, resume, errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ompn_ros.app.errors import TrainSetupError
from ompn_ros.app.training import apply_overrides, load_config
from ompn_ros.cli.train import main
from ompn_ros.layout import DOMAINS
from ompn_ros.model.config import OMPNConfig
from ompn_ros.train.config import TrainConfig

ROOT = Path(__file__).resolve().parents[2]
SMALL = [
    "--quiet",
    "--set",
    "model.n_slots=2",
    "--set",
    "model.slot_size=16",
    "--set",
    "train.batch_size=8",
    "--set",
    "train.eval_every=2",
    "--set",
    "train.threads=1",
]


@pytest.mark.parametrize(("name", "n_slots", "lr", "batch"), [("craft", 2, 1e-3, 256), ("dial", 2, 5e-4, 64)])
def test_shipped_configs_are_valid(name: str, n_slots: int, lr: float, batch: int) -> None:
    config = load_config(str(ROOT / "config" / f"train_{name}.yaml"))
    domain = DOMAINS[config["data"]["domain"]]
    model = OMPNConfig.from_dict(
        {
            **config["model"],
            "obs_dim": domain.obs_dim,
            "action_type": domain.action_type,
            "action_dim": domain.action_dim,
        }
    )
    train = TrainConfig.from_dict(config["train"])
    assert (model.n_slots, train.lr, train.batch_size, train.clip_norm, train.bptt) == (
        n_slots,
        lr,
        batch,
        0.2,
        64,
    )
    assert model.slot_size == (128 if name == "craft" else 64)


def test_overrides_parse_yaml_values() -> None:
    config = load_config(None)
    apply_overrides(config, ["train.lr=5e-4", "model.no_top_down=true", "data.domain=dial"])
    assert config["train"]["lr"] == 5e-4 and config["model"]["no_top_down"] is True
    with pytest.raises(TrainSetupError, match="section"):
        apply_overrides(config, ["optim.lr=1"])
    with pytest.raises(TrainSetupError, match=r"section\.key=value"):
        apply_overrides(config, ["lr"])


def test_synthetic_smoke_run_and_resume(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    args = [
        "--synthetic",
        "discrete",
        "--episodes",
        "12",
        "--config",
        str(ROOT / "config" / "train_craft.yaml"),
        "--out",
        str(out),
        *SMALL,
    ]
    assert main([*args, "--set", "train.iterations=2", "--set", "train.tensorboard=true"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["iterations"] == 2
    assert (out / "best" / "config.json").exists() and (out / "last" / "model.safetensors").exists()
    assert list((out / "tb").glob("events.out.tfevents.*"))  # TensorBoard scalars
    assert main([*args, "--set", "train.iterations=3", "--resume"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["iterations"] == 3
    assert len((out / "log.jsonl").read_text().splitlines()) == 2  # evals at 2, then 3 after resuming


def test_errors_exit_with_code_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("optimizer: {lr: 1}\n")
    assert main(["--synthetic", "discrete", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "unknown section 'optimizer'" in capsys.readouterr().err
    assert main(["--synthetic", "discrete", "--out", str(tmp_path / "o"), "--set", "train.lr=-1"]) == 2
    assert "TrainConfig.lr" in capsys.readouterr().err
    assert main(["--synthetic", "discrete", "--out", str(tmp_path / "o"), "--set", "model.n_slots=0"]) == 2
    assert "n_slots" in capsys.readouterr().err
    teacher = tmp_path / "no_teacher"
    assert main(["--synthetic", "discrete", "--episodes", "8", "--out", str(tmp_path / "d"), *SMALL,
                 "--set", f"train.distill_from=[{teacher}]", "--set", "train.distill_weight=1"]) == 2
    err = capsys.readouterr().err
    assert f"distill_from '{teacher}'" in err and "Traceback" not in err


def test_train_from_a_bag(tmp_path: Path) -> None:
    bag_writer = pytest.importorskip("ompn_ros.data.recorder.bag_writer")
    pytest.importorskip("ompn_ros.data.reader")
    from ompn_ros.train.synthetic import make_dataset

    bag_writer.write_episodes(tmp_path / "bag", make_dataset("craft_shaped", 6, seed=0), "craft")
    args = ["--bags", str(tmp_path / "bag"), "--config", str(ROOT / "config" / "train_craft.yaml")]
    assert main([*args, "--out", str(tmp_path / "out"), *SMALL, "--set", "train.iterations=1"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["iterations"] == 1 and summary["frames"] > 0


def test_train_from_a_users_bag_with_a_reader_spec(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag that is not one of our domains: sizes come from the data and the reader YAML."""
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train.synthetic import make_dataset

    write_episodes(tmp_path / "bag", make_dataset("craft_shaped", 6, seed=1), "craft")
    args = ["--bags", str(tmp_path / "bag"), "--config", str(ROOT / "config" / "train_craft.yaml"),
            "--set", "data.domain=custom",
            "--set", f"data.reader_spec={ROOT / 'config' / 'reader_craft.yaml'}"]
    # discrete actions cannot be sized from the data alone: a clear error names the missing key
    assert main([*args, "--out", str(tmp_path / "bad"), *SMALL, "--set", "train.iterations=1"]) == 2
    assert "data.action_dim" in capsys.readouterr().err
    assert main([*args, "--set", "data.action_dim=5", "--out", str(tmp_path / "out"), *SMALL,
                 "--set", "train.iterations=1"]) == 0
    config = json.loads((tmp_path / "out" / "best" / "config.json").read_text())
    assert (config["obs_dim"], config["action_type"], config["action_dim"]) == (1075, "discrete", 5)


def test_a_non_empty_out_dir_needs_resume_or_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    args = ["--synthetic", "discrete", "--episodes", "12", "--out", str(out), *SMALL,
            "--set", "train.iterations=1"]
    assert main(args) == 0
    weights = (out / "best" / "model.safetensors").read_bytes()
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "is not empty" in err and "--overwrite" in err and "Traceback" not in err
    assert (out / "best" / "model.safetensors").read_bytes() == weights  # untouched
    (out / "notes.txt").write_text("mine")
    assert main([*args, "--overwrite", "--set", "train.seed=7"]) == 0
    assert (out / "best" / "model.safetensors").read_bytes() != weights  # trained again from scratch
    assert (out / "notes.txt").read_text() == "mine"  # only ompn_train's own outputs are replaced
    with pytest.raises(SystemExit, match="2"):  # argparse: the two exclude each other
        main([*args, "--overwrite", "--resume"])


def test_the_read_report_is_printed_and_stored_with_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train.synthetic import make_dataset

    write_episodes(tmp_path / "bag", make_dataset("craft_shaped", 6, seed=0), "craft")
    out = tmp_path / "out"
    args = ["--bags", str(tmp_path / "bag"), "--config", str(ROOT / "config" / "train_craft.yaml"),
            "--out", str(out), *SMALL, "--set", "train.iterations=1", "--set", "data.on_error=skip_tail"]
    assert main(args) == 0
    assert "6 episode(s)" in capsys.readouterr().err
    report = json.loads((out / "read_report.json").read_text())
    assert report["episodes"] == 6 and report["on_error"] == "skip_tail"
    assert report["summary"].startswith("read 1 bag(s): 6 episode(s)")
    assert (out / "read_report.txt").read_text().strip() == report["summary"]


def test_bags_without_their_final_observation_train_two_candidates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The Craft config's candidates_no_final (2) applies exactly when the reader guessed row T."""
    from lab.strip import strip_final_observations
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train.synthetic import make_dataset

    write_episodes(tmp_path / "bag", make_dataset("craft_shaped", 8, seed=2), "craft")
    strip_final_observations(tmp_path / "bag", tmp_path / "stripped")
    args = ["--config", str(ROOT / "config" / "train_craft.yaml"), *SMALL, "--set", "train.iterations=2"]
    assert main(["--bags", str(tmp_path / "stripped"), "--out", str(tmp_path / "a"), *args]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["candidates"] == 2
    doc = json.loads((tmp_path / "a" / "candidates.json").read_text())
    assert [c["candidate"] for c in doc["candidates"]] == [0, 1] and doc["selection"] == "align"
    assert (tmp_path / "a" / "candidates" / "1" / "best" / "detector.json").is_file()
    assert main(["--bags", str(tmp_path / "bag"), "--out", str(tmp_path / "b"), *args]) == 0
    assert not (tmp_path / "b" / "candidates.json").exists()  # complete bags: one run
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["candidates"] == 1
    hidden = [*args, "--set", "train.labels=none"]  # no labels to compare candidates by: one run
    assert main(["--bags", str(tmp_path / "stripped"), "--out", str(tmp_path / "c"), *hidden]) == 0
    assert not (tmp_path / "c" / "candidates.json").exists()
    assert main(["--bags", str(tmp_path / "stripped"), "--out", str(tmp_path / "a"), "--overwrite", *args,
                 "--set", "train.candidates_no_final=1"]) == 0
    assert not (tmp_path / "a" / "candidates").exists()  # --overwrite removed the earlier candidates


def test_train_config_keeps_its_recorded_key_order() -> None:
    from dataclasses import fields

    from ompn_ros.train.config import RECORDED_ORDER

    names = {f.name for f in fields(TrainConfig)}
    assert set(RECORDED_ORDER) == names, "a new TrainConfig field is missing from RECORDED_ORDER"
    config = TrainConfig(restart_at=40, ema_decay=0.5, obs_dropout_range=[1, 3])
    stored = config.to_dict()
    assert list(stored) == list(RECORDED_ORDER)  # the key order of meta.json's train_config
    assert TrainConfig.from_dict(stored) == config
