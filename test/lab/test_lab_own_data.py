"""The own-data study driver (arms, configs, collation) and its README sections (fixtures only)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from own_data_rows import _row

from lab import own_data, report, report_own
from lab.runs import load_train_config, pin_fixed_length
from lab.spec import REPRODUCTION_ITERATIONS
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainStateError


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_shipped_configs_stop_early_and_the_reproduction_pins_its_fixed_length(domain: str) -> None:
    base = load_train_config(domain, None)
    shipped = TrainConfig.from_dict(base["train"])
    assert shipped.patience > 0 and shipped.iterations > REPRODUCTION_ITERATIONS[domain]
    pin_fixed_length(base, domain, shipped=True)
    pinned = TrainConfig.from_dict(base["train"])
    assert (pinned.patience, pinned.iterations) == (0, REPRODUCTION_ITERATIONS[domain])
    custom = load_train_config(domain, None)
    custom["train"]["iterations"] = 7
    pin_fixed_length(custom, domain, shipped=False)  # a user's config keeps its own length
    assert (custom["train"]["patience"], custom["train"]["iterations"]) == (0, 7)


def test_arm_configs_follow_the_arm(tmp_path: Path) -> None:
    _, free = own_data.arm_configs(own_data.ARMS["labels_dial"], tmp_path, threads=1)
    assert free.labels == "none" and free.patience > 0 and free.threads == 1
    _, fixed = own_data.arm_configs(own_data.ARMS["final_craft_full_duplicate"], tmp_path, threads=1)
    assert (fixed.labels, fixed.patience, fixed.iterations) == ("auto", 0, REPRODUCTION_ITERATIONS["craft"])
    assert fixed.out_dir == str(tmp_path / "runs" / "final_craft_full_duplicate")
    _, seed1 = own_data.arm_configs(own_data.ARMS["labels_craft_full_seed1"], tmp_path, threads=1)
    assert seed1.seed == 1
    with pytest.raises(own_data.ReproduceError, match="unknown arm"):
        own_data.arm_by_name("labels_mars")


def test_collate_writes_the_results_and_reuses_the_fixed_run_as_the_complete_arm(tmp_path: Path) -> None:
    arms = tmp_path / "work" / "arms"
    arms.mkdir(parents=True)
    rows = {
        "labels_dial": _row("labels_dial", label_free_online_f1_1=0.80, online_f1_1=0.83),
        "length_dial_fixed": _row("length_dial_fixed", online_f1_1=0.70, online_align=0.60),
        "final_dial_duplicate": _row("final_dial_duplicate", online_f1_1=0.50, online_align=0.40),
        # read from a larger collection of the same bag set: its split is listed apart
        "final_dial_extrapolate_seed1": _row("final_dial_extrapolate_seed1", train_episodes=80,
                                             val_episodes=10, test_episodes=20),
    }
    for name, row in rows.items():
        (arms / f"{name}.json").write_text(json.dumps(row))
    results = tmp_path / "results"
    assert (
        own_data.main(
            ["--work", str(tmp_path / "work"), "collate", "--results", str(results), "--note", "A note."]
        )
        == 0
    )
    doc = json.loads((results / "own_data.json").read_text())
    names = [r["arm"] for r in doc["rows"]]
    assert names == ["labels_dial", "length_dial_fixed", "final_dial_complete", "final_dial_duplicate",
                     "final_dial_extrapolate_seed1"]
    complete = doc["rows"][2]
    assert complete["study"] == "final_observation" and complete["online_f1_1"] == 0.70
    assert doc["meta"]["episodes"] == {"dial_full": {"train": 8, "val": 2, "test": 3},
                                       "dial_full (110 episodes)": {"train": 80, "val": 10, "test": 20}}
    assert "A note." not in doc["meta"]["command"] and doc["meta"]["notes"] == ["A note."]
    assert doc["meta"]["seeds"] == [0, 1]
    text = (results / "README.md").read_text()
    assert text == report.render_readme(results)
    assert "| Dial, seed 0 | 400 (200) | 83.0 / 75.0 | 80.0 / 77.0 | -3.0 / +2.0 |" in text
    assert "| Dial, seed 0 | duplicate | 50.0 / 40.0 | -20.0 / -20.0 |" in text
    assert "A note." in text


def test_collate_without_arms_is_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert own_data.main(["--work", str(tmp_path), "collate", "--results", str(tmp_path / "r")]) == 2
    assert "no arm results" in capsys.readouterr().err


def test_own_robot_table_is_rendered_when_its_file_exists(tmp_path: Path) -> None:
    doc = {
        "meta": {"command": ["python", "examples/own_robot.py"]},
        "rows": [
            {
                "observation": "joint_state",
                "obs_dim": 18,
                "train_episodes": 250,
                "test_episodes": 50,
                "online_f1_1": 0.61,
                "online_align": 0.72,
                "offline_f1_1": 0.655,
                "offline_align": 0.8,
                "live_f1_1": None,
                "live_align": None,
            },
        ],
    }
    assert report_own.own_markdown(tmp_path) == []
    (tmp_path / report_own.OWN_ROBOT).write_text(json.dumps(doc))
    text = report.render_readme(tmp_path)
    assert "| joint_state | 18 | 250 / 50 | 61.0 / 72.0 | 65.5 / 80.0 | – / – |" in text
    assert "`python examples/own_robot.py`" in text


def test_final_observation_means_pair_each_seed_with_its_complete_arm(tmp_path: Path) -> None:
    rows = [
        _row("final_craft_full_complete", online_f1_1=0.90, online_align=0.80),
        _row("final_craft_full_blank", online_f1_1=0.88, online_align=0.70, offline_align=0.70),
        _row("final_craft_full_complete_seed1", online_f1_1=0.92, online_align=0.76),
        _row("final_craft_full_blank_seed1", online_f1_1=0.90, online_align=0.74, offline_align=0.80),
        _row("final_craft_full_blank_seed2", online_f1_1=0.10, online_align=0.10),  # no complete twin
        _row("final_dial_complete"),
        _row("final_dial_duplicate", online_f1_1=0.50),  # one seed: no mean
        # best of two initialisations: paired with the complete arm trained the same way (not seed 10's
        # single run, which scores differently)
        _row("final_craft_full_complete_seed10", offline_align=0.10),
        _row("final_craft_full_complete_best2_seed10", offline_align=0.90),
        _row("final_craft_full_blank_best2_seed10", offline_align=0.92),
        _row("final_craft_full_complete_best2_seed11", offline_align=0.88),
        _row("final_craft_full_blank_best2_seed11", offline_align=0.88),
    ]
    doc = {"meta": {"command": ["x"]}, "rows": rows}
    (tmp_path / report_own.OWN_DATA).write_text(json.dumps(doc))
    text = report.render_readme(tmp_path)
    lines = text.splitlines()
    assert "| Craft full, blank, 2 seeds (seeds 0–1) | 89.0 / 72.0 | -2.0 / -6.0 | 90.0 / 75.0 | " \
        "+0.0 / -5.0 |" in lines
    assert "| Craft full, blank, best of 2, 2 seeds (seeds 10–11) | 85.0 / 75.0 | +0.0 / +0.0 | " \
        "90.0 / 90.0 | +0.0 / +1.0 |" in lines
    assert "| Craft full, seed 10, best of 2 | blank | 85.0 / 75.0 | +0.0 / +0.0 | 90.0 / 92.0 | " \
        "+0.0 / +2.0 |" in lines
    assert "Dial, duplicate, 1 seeds" not in text and "Dial, duplicate, 2 seeds" not in text
    assert "| Craft full, complete, best of 2, 2 seeds (seeds 10–11) | 85.0 / 75.0 | – | 90.0 / 89.0 | – |" \
        in lines  # the complete arms' own means, no gap
    doc["rows"] = [r for r in rows if r["arm"] not in ("final_craft_full_blank_seed1",
                                                       "final_craft_full_complete_seed1",
                                                       "final_craft_full_complete_seed10",
                                                       "final_craft_full_blank_best2_seed11",
                                                       "final_craft_full_complete_best2_seed11")]
    (tmp_path / report_own.OWN_DATA).write_text(json.dumps(doc))
    assert "Means over seeds" not in report.render_readme(tmp_path)


def test_restarts_are_counted_from_the_run_and_its_candidates(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "candidates" / "0").mkdir(parents=True)
    (run / "candidates" / "1").mkdir()
    assert own_data.restarts_of(run) == 0
    (run / "attempt.json").write_text('{"attempt": 1, "seed": 100003, "reason": "x"}')
    (run / "candidates" / "1" / "attempt.json").write_text('{"attempt": 1, "seed": 110010, "reason": "x"}')
    assert own_data.restarts_of(run) == 2
    # records of the rule that abandoned the first initialisation name no kept attempt
    assert own_data.abandoned_of(run) == 2
    kept = {"attempt": 1, "seed": 100003, "reason": "x", "attempts": [], "kept": 0}
    (run / "attempt.json").write_text(json.dumps(kept))
    assert own_data.abandoned_of(run) == 1 and own_data.restarts_of(run) == 2
    (run / "attempt.json").write_text("{broken")
    with pytest.raises(TrainStateError, match="is not a restart record"):
        own_data.abandoned_of(run)


def test_a_rescored_arm_keeps_how_it_was_trained(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    arm = own_data.arm_by_name("human_craft_full_complete_seed10")
    assert own_data.main(["--work", str(tmp_path), "rescore", arm.name]) == 2  # nothing to rescore yet
    (tmp_path / "arms").mkdir()
    before = {"arm": arm.name, "train_seconds": 812.5, "iterations": 200, "online_align": 0.5}
    (tmp_path / "arms" / f"{arm.name}.json").write_text(json.dumps(before))
    scored: list[Path] = []

    def score(arm_: object, work: Path, checkpoint: Path) -> dict:
        scored.append(checkpoint)
        return {"arm": arm.name, "train_seconds": None, "iterations": 7, "online_align": 0.6}

    monkeypatch.setattr(own_data, "run_arm", score)
    row = own_data.rescore_arm(arm, tmp_path)
    assert scored == [tmp_path / "runs" / arm.name / "best"]
    assert row == {"arm": arm.name, "train_seconds": 812.5, "iterations": 200, "online_align": 0.6}
    assert json.loads((tmp_path / "arms" / f"{arm.name}.json").read_text()) == row


def test_gather_writes_the_rows_and_their_means_over_seeds(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    arms = tmp_path / "arms"
    arms.mkdir()
    names = ["human_craft_full_boundaries_auto_seed10", "human_craft_full_boundaries_auto_seed11",
             "human_dial_boundaries_auto_seed5"]
    figures = [(0.80, 0.90), (0.84, 0.86), (0.70, 0.95)]
    for name, (offline, online) in zip(names, figures, strict=True):
        row = {"arm": name, "seed": int(name.rsplit("seed", 1)[1]), "offline_align": offline,
               "offline_f1_1": offline, "online_align": online, "online_f1_1": online}
        (arms / f"{name}.json").write_text(json.dumps(row))
    out = tmp_path / "results" / "pauses.json"
    assert own_data.main(["--work", str(tmp_path), "gather", *names, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [r["arm"] for r in doc["rows"]] == names
    full = doc["means"]["human_craft_full_boundaries_auto"]
    assert full["seeds"] == [10, 11]
    assert full["offline_align"] == {"mean": 82.0, "std": 2.0}
    assert full["online_align"] == {"mean": 88.0, "std": 2.0}
    assert doc["means"]["human_dial_boundaries_auto"]["online_f1_1"] == {"mean": 95.0, "std": 0.0}
    assert doc["meta"]["command"][:4] == ["python", "-m", "lab.own_data", "--work"]
    (arms / f"{names[2]}.json").unlink()
    assert own_data.main(["--work", str(tmp_path), "gather", *names, "--out", str(out)]) == 2
    assert "human_dial_boundaries_auto_seed5" in capsys.readouterr().err
