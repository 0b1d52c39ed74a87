"""The reproduction pipeline end to end on a tiny budget: bags -> training -> held-out tables."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lab import data, ensembles, reproduce, spec
from lab.scoring import DURATION_DELAYS
from ompn_ros.data.episode import Episode
from ompn_ros.paths import config_file

pytestmark = pytest.mark.slow  # the lab's pipeline trains real (tiny) runs; the product's reproduction
# path is checked fast in test/lab/test_reproduce_product.py


def _episode(task: str, seed: int) -> Episode:
    obs, actions = np.zeros((3, 2), np.float32), np.zeros(2, np.int64)
    return Episode(observations=obs, actions=actions, task=task, seed=seed)


def test_held_out_split_is_disjoint_stratified_and_seeded():
    episodes = [_episode(task, s) for task in ("a", "b") for s in range(10)]
    train, test = data.held_out_split(episodes, 0.2, seed=3)
    assert len(test) == 4 and len(train) == 16
    assert sorted(ep.task for ep in test) == ["a", "a", "b", "b"]
    assert not {(e.task, e.seed) for e in train} & {(e.task, e.seed) for e in test}
    again = data.held_out_split(episodes, 0.2, seed=3)[1]
    assert [(e.task, e.seed) for e in again] == [(e.task, e.seed) for e in test]


def _labelled(subtask: list[int]) -> Episode:
    steps = len(subtask)
    return Episode(observations=np.zeros((steps + 1, 2), np.float32), actions=np.zeros(steps, np.int64),
                   task="t", seed=0, subtask=np.asarray(subtask, np.int64))


def _p_hat(expand_at: list[int], steps: int) -> np.ndarray:
    """[pi_end, top, bottom] rows: bottom everywhere, a full expansion to the top at ``expand_at``."""
    p = np.tile([0.0, 0.0, 1.0], (steps, 1))
    p[expand_at] = [0.0, 1.0, 0.0]
    return p


def test_ensemble_averages_p_hat_over_seeds_before_decoding():
    episode = _labelled([0, 0, 0, 1, 1, 1])  # boundaries 2 and 5
    right, wrong = _p_hat([2, 5], 6), _p_hat([1, 5], 6)
    assert ensembles.ensemble_scores("craft", [[right], [right]], [episode])["f1_tol0"] == 1.0
    # two seeds that disagree at step 1 vs 2 tie; a third that agrees with `right` breaks the tie
    two = ensembles.ensemble_scores("craft", [[wrong], [wrong]], [episode])
    three = ensembles.ensemble_scores("craft", [[right], [wrong], [right]], [episode])
    assert two["f1_tol0"] == 0.5 and three["f1_tol0"] == 1.0 and three["align_acc"] == 1.0
    assert two["align_acc"] == pytest.approx(5 / 6)
    with pytest.raises(spec.ReproduceError, match="at least 2 models"):
        ensembles.ensemble_scores("craft", [[right]], [episode])


def test_unknown_extra_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    code = reproduce.main(["craft", "--extras", "ksweeps", "--work", str(tmp_path / "work"),
                           "--results", str(tmp_path / "results")])
    assert code == 2
    assert "unknown extras ['ksweeps']" in capsys.readouterr().err
    assert not (tmp_path / "work").exists()  # rejected before any collection


def test_craft_pipeline_writes_results_in_the_documented_shape(tmp_path: Path):
    results = tmp_path / "results"
    code = reproduce.main([
        "craft", "--settings", "full_nosketch", "--seeds", "2", "--episodes", "8", "--iterations", "2",
        "--extras", "ksweep,ensemble,online_lag", "--threads", "1", "--work", str(tmp_path / "work"),
        "--results", str(results),
    ])
    assert code == 0
    table = json.loads((results / "craft_lab.json").read_text())
    row = table["full_nosketch"]
    for metric in ("align_acc", "f1_tol1", "f1_tol0", "online_f1_tol1", "online_align_strict",
                   "constrained_align", "constrained_f1_tol1"):
        cell = row[metric]
        assert set(cell) == {"mean", "std", "n"} and cell["n"] == 2
        assert 0.0 <= cell["mean"] <= 1.0
    for delay in DURATION_DELAYS:  # the duration decoder within every mean delay, tuned on validation
        cell = row[f"online_hsmm_d{delay}_align_strict"]
        assert cell["n"] == 2 and 0.0 <= cell["mean"] <= 1.0
        assert 0.1 <= row[f"online_hsmm_d{delay}_threshold"]["mean"] <= 0.99
    extras = json.loads((results / "craft_extras.json").read_text())
    assert list(extras["extras"]) == ["k_sweep", "ensemble_of_seeds", "online_lag"]
    lag_rows = extras["extras"]["online_lag"]["rows"]
    assert (lag_rows["full_nosketch: online, hsmm, mean delay <= 4"]["align"]
            == row["online_hsmm_d4_align_strict"])
    assert lag_rows["full_nosketch: offline, paper's detector"]["align"] == row["align"]
    decoder = lag_rows["full_nosketch: online, hsmm, mean delay <= 15"]
    assert decoder["at_end_share"] == row["online_hsmm_d15_at_end_share"]  # how many wait for the end
    assert 0.0 <= decoder["at_end_share"]["mean"] <= 1.0
    assert lag_rows["full_nosketch: offline, paper's detector"]["at_end_share"] is None
    assert extras["extras"]["k_sweep"]["title"] == "K sweep (full_nosketch, seed 0, tol=1)"
    sweep = extras["extras"]["k_sweep"]["rows"]
    assert list(sweep) == ["K=2", "K=3", "K=4", "K=5", "K=6"]
    assert extras["extras"]["ensemble_of_seeds"]["title"].startswith("Ensemble of the 2 seeds")
    ensemble = extras["extras"]["ensemble_of_seeds"]["rows"]
    assert set(ensemble["full_nosketch"]) == {"align_acc", "f1_tol1", "f1_tol0", "constrained_align",
                                              "constrained_f1_tol1", "constrained_f1_tol0"}
    assert all(0.0 <= v <= 1.0 for v in ensemble["full_nosketch"].values())
    # recall can only grow with K (more predictions, same ground truth)
    recalls = [sweep[k]["recall_tol1"] for k in sweep]
    assert recalls == sorted(recalls)
    assert extras["meta"]["n_test"] == {"full": 6}  # 20 % of 3 tasks x 8 episodes
    assert "| full_nosketch |" in (results / "README.md").read_text()
    assert len(list((results / "figures").glob("*.png"))) == 3
    # the bags are rosbag2 directories that the reader accepted
    assert list((tmp_path / "work" / "bags" / "craft_full").glob("part_*/metadata.yaml"))


def test_unknown_setting_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    code = reproduce.main(["dial", "--settings", "full_nosketch", "--work", str(tmp_path),
                           "--results", str(tmp_path)])
    assert code == 2
    assert "unknown settings ['full_nosketch'] for dial" in capsys.readouterr().err


def _tiny_craft(tmp_path: Path, *extra: str) -> int:
    return reproduce.main([
        "craft", "--settings", "full_nosketch", "--seeds", "1", "--episodes", "8", "--iterations", "2",
        "--extras", "none", "--threads", "1", "--work", str(tmp_path / "work"),
        "--results", str(tmp_path / "results"), *extra,
    ])


def test_reevaluate_reuses_the_checkpoints_and_keeps_the_training_figures(tmp_path: Path):
    assert _tiny_craft(tmp_path) == 0
    trained = json.loads((tmp_path / "results" / "craft_lab.json").read_text())["full_nosketch"]
    run_dir = tmp_path / "work" / "runs" / "full_nosketch_seed0"
    detector_file = run_dir / "ompn_node_craft.yaml"
    assert "detector_high" in detector_file.read_text()  # tuned on this run's validation episodes
    detector_file.unlink()
    weights = (run_dir / "best" / "model.safetensors").read_bytes()

    assert _tiny_craft(tmp_path, "--reevaluate") == 0
    again = json.loads((tmp_path / "results" / "craft_lab.json").read_text())["full_nosketch"]
    assert (run_dir / "best" / "model.safetensors").read_bytes() == weights  # nothing was retrained
    assert detector_file.is_file()
    for metric in ("align_acc", "f1_tol1", "online_f1_tol1", "online_shipped_f1_tol1"):
        assert again[metric]["mean"] == pytest.approx(trained[metric]["mean"], abs=1e-9)
    assert again["train_seconds"] == trained["train_seconds"]
    meta = json.loads((tmp_path / "results" / "craft_extras.json").read_text())["meta"]
    assert "--reevaluate" in meta["command"] and "--reevaluate" not in meta["trained"]["command"]
    assert any(stage.startswith("train+eval") for stage in meta["trained"]["stages"])
    assert "Re-evaluated without training" in (tmp_path / "results" / "README.md").read_text()
    # runs added to the work directory later (e.g. more seeds) keep their command through re-evaluation
    extras_file = tmp_path / "results" / "craft_extras.json"
    doc = json.loads(extras_file.read_text())
    later = [["python -m lab.reproduce", "craft", "--seeds", "5", "--skip-trained"]]
    doc["meta"]["trained"]["later_commands"] = later
    extras_file.write_text(json.dumps(doc))
    assert _tiny_craft(tmp_path, "--reevaluate") == 0
    meta = json.loads(extras_file.read_text())["meta"]
    assert meta["trained"]["later_commands"] == later
    quote = ("added or trained again later, on the same bags and split, by: "
             "`python -m lab.reproduce craft --seeds 5 --skip-trained`")
    assert quote in (tmp_path / "results" / "README.md").read_text()


def test_reevaluate_without_checkpoints_names_the_missing_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    assert _tiny_craft(tmp_path, "--reevaluate") == 2
    assert "no usable checkpoint for full_nosketch_seed0" in capsys.readouterr().err


def test_lstm_baseline_config_trains_and_evaluates(tmp_path: Path):
    config = tmp_path / "lstm.yaml"
    base = (Path(config_file("train_craft.yaml"))).read_text()
    config.write_text(base.replace("model:\n", "model:\n  arch: lstm\n", 1))
    assert _tiny_craft(tmp_path, "--config", str(config)) == 0
    row = json.loads((tmp_path / "results" / "craft_lab.json").read_text())["full_nosketch"]
    assert 0.0 <= row["online_f1_tol1"]["mean"] <= 1.0


def test_skip_trained_evaluates_finished_runs_and_trains_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    assert _tiny_craft(tmp_path) == 0
    weights = tmp_path / "work" / "runs" / "full_nosketch_seed0" / "best" / "model.safetensors"
    before = weights.read_bytes()
    capsys.readouterr()
    assert _tiny_craft(tmp_path, "--skip-trained") == 0
    assert "trained to iteration 2 already" in capsys.readouterr().out
    assert weights.read_bytes() == before
    # a longer schedule than the finished run is trained again
    code = reproduce.main([
        "craft", "--settings", "full_nosketch", "--seeds", "1", "--episodes", "8", "--iterations", "3",
        "--extras", "none", "--threads", "1", "--work", str(tmp_path / "work"),
        "--results", str(tmp_path / "results"), "--skip-trained",
    ])
    assert code == 0 and "already" not in capsys.readouterr().out
    # a finished run trained with another configuration is not taken for this one
    config = tmp_path / "other.yaml"
    base = Path(config_file("train_craft.yaml")).read_text()
    config.write_text(base.replace("weight_decay: 1.0", "weight_decay: 0.5", 1))
    assert "weight_decay: 0.5" in config.read_text()
    trained = weights.read_bytes()
    code = reproduce.main([
        "craft", "--settings", "full_nosketch", "--seeds", "1", "--episodes", "8", "--iterations", "3",
        "--extras", "none", "--threads", "1", "--work", str(tmp_path / "work"),
        "--results", str(tmp_path / "results"), "--skip-trained", "--config", str(config),
    ])
    assert code == 0
    out = capsys.readouterr().out
    assert "finished with another configuration (train.weight_decay), training again" in out
    assert "already" not in out and weights.read_bytes() != trained


def test_without_a_validation_split_the_detector_is_not_tuned_on_training_episodes(tmp_path: Path):
    config = tmp_path / "no_val.yaml"
    base = Path(config_file("train_craft.yaml")).read_text()
    config.write_text(base.replace("val_ratio: 0.2", "val_ratio: 0.0", 1))
    assert "val_ratio: 0.0" in config.read_text()
    assert _tiny_craft(tmp_path, "--config", str(config)) == 0
    row = json.loads((tmp_path / "results" / "craft_lab.json").read_text())["full_nosketch"]
    assert row["online_f1_tol1"] == row["online_shipped_f1_tol1"]  # the shipped detector, not a tuned one
    assert not (tmp_path / "work" / "runs" / "full_nosketch_seed0" / "ompn_node_craft.yaml").exists()


def test_ensemble_with_one_seed_is_skipped_with_a_message(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    assert _tiny_craft(tmp_path, "--extras", "ensemble") == 0
    assert "ensemble extra skipped" in capsys.readouterr().out
    extras = json.loads((tmp_path / "results" / "craft_extras.json").read_text())["extras"]
    assert "ensemble_of_seeds" not in extras and "ensembles_per_seed" not in extras


def test_ensemble_members_share_the_seed_split_and_are_scored_together(tmp_path: Path):
    from ompn_ros.model.checkpoint import load_checkpoint
    from ompn_ros.train.config import TrainConfig
    from ompn_ros.train.trainer import train_val_episodes

    assert _tiny_craft(tmp_path, "--members", "2") == 0
    runs = tmp_path / "work" / "runs"
    configs = {}
    for name in ("full_nosketch_seed0", "full_nosketch_seed0_m1"):
        extra = load_checkpoint(runs / name / "best")[1]
        configs[name] = TrainConfig.from_dict(extra["train_config"])
    member = configs["full_nosketch_seed0_m1"]
    assert member.seed == spec.MEMBER_SEED_STRIDE and member.split_seed == 0
    assert configs["full_nosketch_seed0"].seed == 0
    # the same validation episodes, so the ensemble's detector is tuned on episodes no member saw
    episodes = data.read_bags("craft", tmp_path / "work" / "bags" / "craft_full")
    pool, _ = data.held_out_split(episodes, spec.DEFAULT_TEST_RATIO, 0)
    val_own = train_val_episodes(pool, configs["full_nosketch_seed0"])[1]
    val_member = train_val_episodes(pool, member)[1]
    assert [(e.task, e.seed) for e in val_member] == [(e.task, e.seed) for e in val_own]
    weights = [(runs / n / "best" / "model.safetensors").read_bytes() for n in configs]
    assert weights[0] != weights[1]  # another initialisation
    extras = json.loads((tmp_path / "results" / "craft_extras.json").read_text())["extras"]
    table = extras["ensembles_per_seed"]["rows"]
    row = table["full_nosketch"]
    assert row["members"]["mean"] == 2.0
    assert row["align_acc"]["n"] == 1 and 0.0 <= row["constrained_align"]["mean"] <= 1.0
    from ompn_ros.train.evaluation import MIN_LENGTH_CANDIDATES

    assert row["constrained_min_length"]["mean"] in MIN_LENGTH_CANDIDATES
    assert 0.0 <= row["online_f1_tol1"]["mean"] <= 1.0
    table_md = (tmp_path / "results" / "README.md").read_text().split("### Ensembles per seed")[1]
    row_md = next(line for line in table_md.splitlines() if line.startswith("| full_nosketch |"))
    cells = [c.strip() for c in row_md.strip("|").split("|")]
    columns = list(row)
    assert cells[1 + columns.index("members")] == "2 (0)"  # a count, not a percentage
    delay = row["online_delay_mean"]
    assert cells[1 + columns.index("online_delay_mean")] == f"{delay['mean']:.2f} ({delay['std']:.2f})"
    # the ensemble is written as a checkpoint the node loads, with its tuned detector beside it
    from ompn_ros.model.ensemble import EnsembleStepper, read_ensemble
    from ompn_ros.model.load import stepper_from_checkpoint

    ensemble_dir = runs / "full_nosketch_seed0_ensemble2"
    members, extra = read_ensemble(ensemble_dir)
    assert [m.resolve() for m in members] == [(runs / n / "best").resolve() for n in configs]
    assert extra["constrained_min_length"] == row["constrained_min_length"]["mean"]
    assert isinstance(stepper_from_checkpoint(ensemble_dir), EnsembleStepper)
    assert "detector_high" in (ensemble_dir / "ompn_node_craft.yaml").read_text()


def test_members_spec_is_checked_before_any_collection(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    assert spec.parse_members("3", ["a", "b"]) == {"a": 3, "b": 3}
    assert spec.parse_members("b=5", ["a", "b"]) == {"a": 1, "b": 5}
    for members, message in (("0", "must be >= 1"), ("two", "integer M or SETTING=M"),
                              ("partial_nosketch=2", "'partial_nosketch', which is not among the settings"),
                              ("full_nosketch=x", "must be an integer")):
        assert _tiny_craft(tmp_path, "--members", members) == 2
        assert message in capsys.readouterr().err, members
    assert not (tmp_path / "work").exists()


def test_evaluate_names_a_directory_that_is_no_single_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    ensemble = tmp_path / "ensemble"
    ensemble.mkdir()
    (ensemble / "ensemble.json").write_text("{}")
    assert _tiny_craft(tmp_path, "--evaluate", str(ensemble)) == 2
    err = capsys.readouterr().err
    assert "--evaluate takes one checkpoint directory" in err and "config.json" in err


def test_distill_extra_trains_a_student_on_each_seeds_members(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from lab import pipeline
    from ompn_ros.model.checkpoint import load_checkpoint
    from ompn_ros.train.config import TrainConfig

    shipped: list[tuple[Path, dict]] = []
    monkeypatch.setattr(pipeline, "ship", lambda domain, checkpoint, provenance: shipped.append(
        (checkpoint, provenance)) or checkpoint)  # the package's own checkpoint stays as it is
    assert _tiny_craft(tmp_path, "--extras", "distill") == 0  # no members: nothing to distil from
    assert "distill extra skipped" in capsys.readouterr().out
    added = ("--members", "2", "--extras", "distill,online_lag", "--skip-trained", "--ship")
    assert _tiny_craft(tmp_path, *added) == 0
    runs = tmp_path / "work" / "runs"
    student = runs / f"full_nosketch_distill{spec.DISTILL_WEIGHT:g}_seed0"
    assert [c for c, _ in shipped] == [student / "best"]  # --ship takes seed 0's student
    assert shipped[0][1]["model"] == "distilled from the seed's 2 members"
    cfg = TrainConfig.from_dict(load_checkpoint(student / "best")[1]["train_config"])
    teachers = [str((runs / n / "best").resolve()) for n in ("full_nosketch_seed0", "full_nosketch_seed0_m1")]
    assert cfg.distill_from == teachers
    assert cfg.distill_weight == spec.DISTILL_WEIGHT and cfg.seed == 0
    extras = json.loads((tmp_path / "results" / "craft_extras.json").read_text())["extras"]
    assert extras["distilled"]["title"].startswith("Distilled: one OMPN per seed")
    row = extras["distilled"]["rows"]["full_nosketch"]
    assert row["align"]["n"] == 1 and 0.0 <= row["constrained_align"]["mean"] <= 1.0
    assert set(row) == set(pipeline.DISTILLED_CELLS)  # the decoder's cells go to the online_lag table
    lag_rows = extras["online_lag"]["rows"]  # the students' decoder beside the single models'
    student_row = lag_rows["full_nosketch, distilled: online, hsmm, mean delay <= 6"]
    assert 0.0 <= student_row["align"]["mean"] <= 1.0 and student_row["align"]["n"] == 1
    assert lag_rows["full_nosketch, distilled: offline, paper's detector"]["align"] == row["align"]
    assert "full_nosketch: online, hsmm, mean delay <= 6" in lag_rows
    assert "### Distilled" in (tmp_path / "results" / "README.md").read_text()


def test_extras_only_adds_tables_and_keeps_the_main_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _tiny_craft(tmp_path, "--extras", "ksweep") == 0
    results = tmp_path / "results"
    main_before = (results / "craft_lab.json").read_bytes()
    figures_before = {p.name: p.read_bytes() for p in (results / "figures").iterdir()}
    added = ("--members", "2", "--extras", "distill", "--extras-only", "--skip-trained")
    assert _tiny_craft(tmp_path, *added) == 0
    assert (results / "craft_lab.json").read_bytes() == main_before
    assert {p.name: p.read_bytes() for p in (results / "figures").iterdir()} == figures_before
    doc = json.loads((results / "craft_extras.json").read_text())
    assert list(doc["extras"]) == ["k_sweep", "ensembles_per_seed", "distilled"]  # kept, then added
    doc["extras"]["distilled"]["rows"]["other_setting"] = doc["extras"]["distilled"]["rows"]["full_nosketch"]
    (results / "craft_extras.json").write_text(json.dumps(doc))
    assert _tiny_craft(tmp_path, *added) == 0  # again: its rows replaced, the other rows kept
    doc = json.loads((results / "craft_extras.json").read_text())
    assert sorted(doc["extras"]["distilled"]["rows"]) == ["full_nosketch", "other_setting"]
    later = doc["meta"].get("trained", doc["meta"])["later_commands"]
    assert sum("--extras-only" in c for c in later) == 1  # written after every setting, listed once
    assert "Runs added or trained again later" in (results / "README.md").read_text()
    empty = tmp_path / "empty"
    code = reproduce.main(["craft", "--settings", "full_nosketch", "--seeds", "1", "--episodes", "8",
                           "--iterations", "2", "--extras", "none", "--threads", "1", "--work",
                           str(tmp_path / "work"), "--results", str(empty), *added[-2:]])
    assert code == 2 and "--extras-only: no finished result files" in capsys.readouterr().err
