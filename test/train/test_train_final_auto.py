"""final_observation: auto: one run per option of final_options on the same split, the one whose online
detector validation prefers (one standard error, then the other metric) published into the run
directory; the first option alone when nothing can be chosen.  Each run's checkpoints name the option
they were trained with, and a replay of an auto spec reads later bags with it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from ompn_ros.app.errors import ReplayError, TrainSetupError
from ompn_ros.app.final_choice import FINAL_DIR, OptionRun, Validated, choose, train_auto
from ompn_ros.app.final_record import RECORD_FILE, record_final, resolve_final, trained_final
from ompn_ros.app.training import load_config
from ompn_ros.cli.segment import main as segment_main
from ompn_ros.cli.train import main
from ompn_ros.data.errors import ReaderSpecError
from ompn_ros.data.reader import ReaderSpec, read_episodes

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["--quiet", "--set", "model.n_slots=2", "--set", "model.slot_size=16", "--set", "train.batch_size=8",
         "--set", "train.eval_every=1", "--set", "train.threads=1", "--set", "train.iterations=2",
         "--set", "train.candidates_no_final=1"]


def _auto_spec(path: Path, options: list[str]) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "reader_craft.yaml").read_text())
    body = doc.get("reader", doc)
    body.update({"final_observation": "auto", "final_options": options})
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from lab.strip import strip_final_observations
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train.synthetic import make_dataset

    root = tmp_path_factory.mktemp("auto")
    write_episodes(root / "bag", make_dataset("craft_shaped", 8, seed=3), "craft")
    strip_final_observations(root / "bag", root / "stripped")
    return root / "bag", root / "stripped"


def _args(bag: Path, spec: Path, out: Path, *extra: str) -> list[str]:
    return ["--bags", str(bag), "--config", str(ROOT / "config" / "train_craft.yaml"), "--out", str(out),
            "--set", f"data.reader_spec={spec}", *SMALL, *extra]


def _kept_by_rule(rows: list[dict], objective: str) -> str:
    """The rule recomputed from final_observation.json: the best objective, the options within its
    standard error tied, the other metric decides (then the objective, then the first)."""
    first, second = ("val_f1_1", "val_align") if objective == "f1" else ("val_align", "val_f1_1")
    top = max(range(len(rows)), key=lambda g: (rows[g][first], rows[g][second], -g))
    near = [g for g, r in enumerate(rows) if r[first] >= rows[top][first] - rows[top]["standard_error"]]
    return rows[max(near, key=lambda g: (rows[g][second], rows[g][first], -g))]["option"]


def test_stripped_bags_train_every_option_and_publish_the_one_validation_keeps(
    tmp_path: Path, bags: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    spec, out = _auto_spec(tmp_path / "reader.yaml", ["blank", "duplicate"]), tmp_path / "run"
    assert main(_args(bags[1], spec, out)) == 0
    captured = capsys.readouterr()
    shown = json.loads(captured.out.strip().splitlines()[-1])
    doc = json.loads((out / RECORD_FILE).read_text())
    assert [r["option"] for r in doc["options"]] == ["blank", "duplicate"] and doc["objective"] == "f1"
    assert shown["final_observation"] == doc["chosen"] == _kept_by_rule(doc["options"], "f1")
    assert "row T read as 'blank'" in captured.err and "row T read as 'duplicate'" in captured.err
    for option, guess in (("blank", "zeros"), ("duplicate", "the last observation")):
        assert guess in (out / FINAL_DIR / option / "read_report.txt").read_text()
        assert (out / FINAL_DIR / option / "best" / "detector.json").is_file()
    won = out / FINAL_DIR / doc["chosen"]
    for name in ("best/model.safetensors", "last/model.safetensors", "log.jsonl", "read_report.txt"):
        assert (out / name).read_bytes() == (won / name).read_bytes()
    summary = json.loads((out / "summary.json").read_text())
    parts = [json.loads((out / FINAL_DIR / o / "summary.json").read_text()) for o in ("blank", "duplicate")]
    assert summary["final_observation"] == doc["chosen"]
    assert summary["frames"] == sum(p["frames"] for p in parts)
    assert trained_final(out / "best") == trained_final(out / "last") == doc["chosen"]
    for option, guess in (("blank", "zeros"), ("duplicate", "the last observation")):
        assert trained_final(out / FINAL_DIR / option / "best") == option
        # a replay of the auto spec reads row T as the checkpoint was trained, not as the first option
        replayed = tmp_path / f"segment_{option}"
        assert segment_main(["--bag", str(bags[1]), "--checkpoint", str(out / FINAL_DIR / option / "best"),
                             "--reader-config", str(spec), "--out", str(replayed),
                             "--plot-episodes", "0"]) == 0
        assert guess in (replayed / "read_report.txt").read_text()
    assert main(_args(bags[1], spec, out, "--overwrite", "--set", "train.seed=4")) == 0
    assert json.loads((out / RECORD_FILE).read_text())["options"] != doc["options"]  # retrained afresh


def test_nothing_to_choose_trains_the_first_option_alone(
    tmp_path: Path, bags: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    spec = _auto_spec(tmp_path / "reader.yaml", ["duplicate", "blank"])
    assert main(_args(bags[0], spec, tmp_path / "complete")) == 0  # every final observation recorded
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["final_observation"] == "duplicate"
    assert not (tmp_path / "complete" / FINAL_DIR).exists()
    assert not (tmp_path / "complete" / RECORD_FILE).exists()
    assert trained_final(tmp_path / "complete" / "best") == "duplicate"
    assert main(_args(bags[1], spec, tmp_path / "unlabelled", "--set", "train.labels=none")) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["final_observation"] == "duplicate"
    assert not (tmp_path / "unlabelled" / FINAL_DIR).exists()  # no labels: runs cannot be ranked
    assert "the last observation" in (tmp_path / "unlabelled" / "read_report.txt").read_text()


def test_torchrun_is_refused_in_one_line(tmp_path: Path, bags: tuple[Path, Path],
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WORLD_SIZE", "2")
    spec = ReaderSpec.from_yaml(_auto_spec(tmp_path / "reader.yaml", ["blank", "duplicate"]))
    with pytest.raises(TrainSetupError, match="torchrun"):
        train_auto([str(bags[1])], load_config(None), spec, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_checkpoint_record_sets_auto_and_a_bad_one_is_refused_in_one_line(tmp_path: Path) -> None:
    auto = ReaderSpec(final_observation="auto", final_options=("extrapolate", "duplicate"))
    assert resolve_final(auto, None) == auto and resolve_final(auto, tmp_path) == auto  # no record
    record_final(tmp_path, "blank")  # outside final_options: training's option still wins
    assert resolve_final(auto, tmp_path).final_guess == "blank"
    fixed = ReaderSpec(final_observation="duplicate")
    assert resolve_final(fixed, tmp_path) == fixed  # a fixed option is the user's choice
    for text in ("{", json.dumps({"format": "other", "final_observation": "blank"}),
                 json.dumps({"format": "ompn_ros.final_observation", "chosen": "auto"})):
        (tmp_path / RECORD_FILE).write_text(text)
        with pytest.raises(ReplayError, match=RECORD_FILE):
            trained_final(tmp_path)


def test_the_choice_has_one_record_beside_a_checkpoint_and_with_the_comparison(tmp_path: Path) -> None:
    record_final(tmp_path, "duplicate")
    (tmp_path / "out").mkdir()
    record_final(tmp_path / "out", "blank", {"objective": "f1", "options": [{"option": "blank"}]})
    plain, compared = (json.loads((d / RECORD_FILE).read_text()) for d in (tmp_path, tmp_path / "out"))
    assert plain["format"] == compared["format"] == "ompn_ros.final_observation"
    assert (plain["chosen"], compared["chosen"]) == ("duplicate", "blank")
    assert compared["options"] == [{"option": "blank"}] and "options" not in plain
    assert (trained_final(tmp_path), trained_final(tmp_path / "out")) == ("duplicate", "blank")
    assert not list(tmp_path.glob("final_guess*"))  # one file name for the choice


def test_other_readers_read_auto_as_the_first_option(tmp_path: Path, bags: tuple[Path, Path]) -> None:
    spec = ReaderSpec.from_yaml(_auto_spec(tmp_path / "reader.yaml", ["blank", "duplicate"]))
    assert spec.final_guess == "blank" and spec.with_final("duplicate").final_guess == "duplicate"
    eps = read_episodes(bags[1], spec=spec).episodes
    assert all(not ep.observations[-1].any() for ep in eps)  # row T blank
    copied = read_episodes(bags[1], spec=spec.with_final("duplicate")).episodes
    assert all(np.array_equal(ep.observations[-1], ep.observations[-2]) for ep in copied)


def test_final_options_are_validated_and_round_trip() -> None:
    spec = ReaderSpec.from_dict({"final_observation": "auto", "final_options": ["duplicate", "extrapolate"]})
    assert spec.final_options == ("duplicate", "extrapolate")
    assert ReaderSpec.from_dict(spec.to_dict()) == spec
    assert ReaderSpec().final_options == ("extrapolate", "duplicate")
    assert ReaderSpec().final_guess == "duplicate"  # not auto: final_observation itself
    for bad in ([], ["drop_last_step"], ["blank", "blank"], ["zeros"]):
        with pytest.raises(ReaderSpecError, match="final_options"):
            ReaderSpec(final_observation="auto", final_options=bad)  # type: ignore[arg-type]
    with pytest.raises(ReaderSpecError, match="not one of final_options"):
        spec.with_final("blank")


def _validated(f1: list[float], align: list[float]) -> Validated:
    per = [{"f1_tol1": f, "align_strict": a, "delay_mean": 0.0} for f, a in zip(f1, align, strict=True)]
    pooled = {"f1_tol1": float(np.mean(f1)), "align_strict": float(np.mean(align)), "delay_mean": 0.0}
    return Validated(pooled, per, [10] * len(f1), "align")


def _run(option: str, validated: Validated) -> OptionRun:
    return OptionRun(option, Path(option), {}, validated)


def test_a_tie_within_one_standard_error_goes_to_the_other_metric() -> None:
    noisy = _run("extrapolate", _validated([0.3, 0.4, 0.5, 0.2], [0.90, 0.70, 0.95, 0.80]))  # align .8375
    steady = _run("duplicate", _validated([0.8, 0.7, 0.9, 0.8], [0.82, 0.80, 0.84, 0.83]))  # align .8225
    assert choose([noisy, steady]) == 1  # .015 below, well within noisy's error; F1@1 decides
    far = _run("blank", _validated([0.9, 0.9, 0.9, 0.9], [0.50, 0.52, 0.48, 0.50]))
    assert choose([noisy, far]) == 0  # outside the error: the objective decides
    short = OptionRun("blank", Path("b"), {},
                      Validated(steady.validated.metrics, steady.validated.per_episode, [9] * 4, "align"))
    with pytest.raises(TrainSetupError, match="differ in length"):
        choose([noisy, short])


def test_the_dial_preset_chooses_on_validation_and_craft_keeps_blank() -> None:
    dial = ReaderSpec.from_yaml(ROOT / "config" / "reader_dial.yaml")
    assert dial == ReaderSpec.for_domain("dial")  # the YAML is the preset
    assert (dial.final_observation, dial.final_options) == ("auto", ("extrapolate", "duplicate"))
    assert ReaderSpec.for_domain("craft").final_observation == "blank"
    example = ReaderSpec.from_yaml(ROOT / "config" / "reader_jointstate_example.yaml")
    assert example.final_guess == "extrapolate"  # label-free: the first option
