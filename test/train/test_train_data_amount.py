"""Is the data likely enough: the read summary's ``data:`` block and ompn_train's closing lines."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.app.data_amount import FEWEST_LABEL_FREE, FEWEST_LABELLED, data_amount, expectation
from ompn_ros.cli.train import main
from ompn_ros.data.episode import Episode

ROOT = Path(__file__).resolve().parents[2]


def _episode(lengths: list[int]) -> Episode:
    labels = np.concatenate([np.full(n, k) for k, n in enumerate(lengths)]).astype(np.int64)
    steps = len(labels)
    return Episode(observations=np.zeros((steps + 1, 3), np.float32), actions=np.zeros(steps, np.int64),
                   subtask=labels)


def test_counts_demonstrations_split_and_steps_per_subtask() -> None:
    episodes = [_episode([10, 20, 30]) for _ in range(10)]
    amount = data_amount(episodes, val_ratio=0.2, labelled=True)
    assert (amount.demonstrations, amount.train, amount.validation) == (10, 8, 2)
    assert amount.subtasks == 30 and amount.steps_per_subtask == 20.0
    assert not amount.likely_enough
    text = "\n".join(amount.lines())
    assert "10 demonstration(s), 8 for training and 2 for validation, with labels" in text
    assert "20 steps per subtask" in text
    assert f"fewer than {FEWEST_LABELLED} training" in text and "record more" in text


def test_enough_against_the_smallest_measured_runs() -> None:
    many = [_episode([5, 5]) for _ in range(FEWEST_LABELLED + 31)]
    assert data_amount(many, 0.1, labelled=True).likely_enough  # 270 train, 30 validation
    assert not data_amount(many, 0.1, labelled=False).likely_enough  # label-free: measured from 576
    label_free = [_episode([5, 5]) for _ in range(FEWEST_LABEL_FREE + 64)]
    assert data_amount(label_free, 0.1, labelled=False).likely_enough


def test_expectation_explains_a_label_free_agreement() -> None:
    amount = data_amount([_episode([4, 4, 4]) for _ in range(3)], 0.1, labelled=False)
    lines = expectation(amount, "agreement", {"agreement": 0.51})
    assert lines[0].startswith("label-free agreement 0.51: ")
    assert "not whether the segmentation is right" in lines[0]
    assert lines[1].startswith("3 training demonstration(s): fewer than any measured run")
    assert expectation(data_amount([_episode([5])] * 700, 0.1, True), "align", {"align": 0.9}) == [
        "validation alignment 0.90 on 70 labelled demonstration(s): the share of steps given the right "
        "subtask"]


def test_ompn_train_says_whether_the_data_is_enough(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: the read summary and the final output said nothing about the amount of data."""
    from ompn_ros.data.recorder.bag_writer import write_episodes
    from ompn_ros.train.synthetic import make_dataset

    write_episodes(tmp_path / "bag", make_dataset("craft_shaped", 4, seed=0), "craft")
    out = tmp_path / "out"
    args = ["--bags", str(tmp_path / "bag"), "--config", str(ROOT / "config" / "train_craft.yaml"),
            "--out", str(out), "--quiet"]
    settings = ["model.n_slots=2", "model.slot_size=16", "train.batch_size=8", "train.iterations=1",
                "train.threads=1", "train.labels=none", "train.boundary_head=false",
                "train.agreement_warmup=0"]
    assert main([*args, *[part for item in settings for part in ("--set", item)]]) == 0
    err = capsys.readouterr().err
    assert "data: 4 demonstration(s), 3 for training and 1 for validation, without labels" in err
    assert "likely too few" in err
    assert "label-free agreement" in err and "3 training demonstration(s): fewer than any measured run" in err
    report = json.loads((out / "read_report.json").read_text())
    assert report["data_amount"]["train"] == 3 and report["data_amount"]["likely_enough"] is False
    assert "likely too few" in (out / "read_report.txt").read_text()
