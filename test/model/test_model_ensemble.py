"""Ensemble checkpoints: manifest round trip, averaged streaming outputs, clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.ensemble import ENSEMBLE_FILE, EnsembleStepper, read_ensemble, write_ensemble
from ompn_ros.model.errors import CheckpointError, EnsembleError
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.model.streaming import StreamingPolicy
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.train.evaluation import teacher_forced_p_hat
from ompn_ros.train.synthetic import make_dataset, synthetic_spec

torch.set_num_threads(1)


def _checkpoint(path: Path, seed: int, **overrides: object) -> Path:
    torch.manual_seed(seed)
    fields = {"obs_dim": 6, "action_type": "discrete", "action_dim": 3, "n_slots": 3, "slot_size": 16}
    fields.update(overrides)
    save_checkpoint(path, OMPNPolicy(OMPNConfig(**fields)))  # type: ignore[arg-type]
    return path


@pytest.fixture
def members(tmp_path: Path) -> list[Path]:
    return [_checkpoint(tmp_path / f"m{i}", seed=i) for i in range(3)]


def test_manifest_round_trip_with_relative_paths(tmp_path: Path, members: list[Path]) -> None:
    target = write_ensemble(tmp_path / "ens", members, {"note": "three seeds"})
    doc = json.loads(target.read_text())
    assert doc["members"] == ["../m0", "../m1", "../m2"]  # relative: the directory tree can move
    paths, extra = read_ensemble(tmp_path / "ens")
    assert [p.resolve() for p in paths] == [m.resolve() for m in members] and extra == {"note": "three seeds"}


def test_ensemble_step_averages_the_members(tmp_path: Path, members: list[Path]) -> None:
    write_ensemble(tmp_path / "ens", members)
    ensemble = stepper_from_checkpoint(tmp_path / "ens")
    assert isinstance(ensemble, EnsembleStepper) and len(ensemble.members) == 3
    singles = [StreamingPolicy.from_checkpoint(m) for m in members]
    rng = np.random.default_rng(0)
    for obs in rng.normal(size=(12, 6)).astype(np.float32):
        out = ensemble.step(obs)
        each = [s.step(obs) for s in singles]
        np.testing.assert_allclose(out.p_hat, np.mean([e.p_hat for e in each], axis=0), atol=1e-6)
        assert out.pi_end == pytest.approx(np.mean([e.pi_end for e in each]), abs=1e-6)
        slots = out.p_hat[1:][::-1]
        np.testing.assert_allclose(out.pi, slots / slots.sum(), atol=1e-6)
        probs = np.mean([np.exp(e.action_logits) / np.exp(e.action_logits).sum() for e in each], axis=0)
        assert out.action == int(probs.argmax())
        np.testing.assert_allclose(np.exp(out.action_logits), probs, rtol=1e-5)


def test_continuous_ensemble_averages_the_gaussian_means(tmp_path: Path) -> None:
    paths = [_checkpoint(tmp_path / f"c{i}", seed=10 + i, action_type="continuous") for i in range(2)]
    write_ensemble(tmp_path / "ens", paths)
    ensemble = stepper_from_checkpoint(tmp_path / "ens")
    singles = [StreamingPolicy.from_checkpoint(p) for p in paths]
    obs = np.linspace(-1, 1, 6).astype(np.float32)
    out = ensemble.step(obs)
    np.testing.assert_allclose(out.action, np.mean([s.step(obs).action for s in singles], axis=0), atol=1e-6)
    assert out.action_logits is None


def test_streaming_ensemble_matches_the_offline_average(tmp_path: Path) -> None:
    """The node's ensemble and python -m lab.reproduce's offline ensemble see the same p_hat."""
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    paths = [_checkpoint(tmp_path / f"s{i}", seed=20 + i, obs_dim=obs_dim, action_dim=action_dim,
                         action_type=action_type) for i in range(2)]
    write_ensemble(tmp_path / "ens", paths)
    episode = make_dataset("discrete", 1, seed=5)[0]
    from ompn_ros.model.checkpoint import load_checkpoint

    offline = np.mean([teacher_forced_p_hat(load_checkpoint(p)[0], [episode])[0][0] for p in paths], axis=0)
    ensemble = stepper_from_checkpoint(tmp_path / "ens")
    ensemble.reset()
    online = np.array([ensemble.step(x).p_hat for x in episode.observations[: episode.length]])
    np.testing.assert_allclose(online, offline, atol=1e-5)


def test_segmenter_runs_an_ensemble(tmp_path: Path, members: list[Path]) -> None:
    write_ensemble(tmp_path / "ens", members[:2])
    segmenter = StreamingSegmenter(stepper_from_checkpoint(tmp_path / "ens"))
    outputs = [segmenter.step(x) for x in np.random.default_rng(1).normal(size=(5, 6))]
    assert [o.step_index for o in outputs] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="obs_dim"):
        segmenter.step(np.zeros(5))


def test_members_that_disagree_are_named(tmp_path: Path, members: list[Path]) -> None:
    other = _checkpoint(tmp_path / "wide", seed=5, obs_dim=7)
    with pytest.raises(EnsembleError, match=r"wide has obs_dim=7, but member .*m0 has 6"):
        write_ensemble(tmp_path / "ens", [members[0], other])
    assert not (tmp_path / "ens").exists()  # nothing written
    with pytest.raises(EnsembleError, match="at least 2"):
        write_ensemble(tmp_path / "ens", members[:1])
    with pytest.raises(CheckpointError, match="missing"):
        write_ensemble(tmp_path / "ens", [members[0], tmp_path / "nowhere"])


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"format": "other", "format_version": 1, "members": ["a", "b"]}), "'format'"),
        (json.dumps({"format": "ompn_ros.ensemble", "format_version": 9, "members": ["a", "b"]}),
         "format_version 9"),
        (json.dumps({"format": "ompn_ros.ensemble", "format_version": 1, "members": ["../m0"]}),
         "at least 2"),
        (json.dumps({"format": "ompn_ros.ensemble", "format_version": 1, "members": ["../m0", "../gone"]}),
         "member '../gone' is not a checkpoint directory"),
    ],
)
def test_bad_manifest_is_a_clear_error(
    tmp_path: Path, members: list[Path], content: str, message: str
) -> None:
    (tmp_path / "ens").mkdir()
    (tmp_path / "ens" / ENSEMBLE_FILE).write_text(content)
    with pytest.raises(EnsembleError, match=message):
        stepper_from_checkpoint(tmp_path / "ens")


def test_ompn_segment_names_a_broken_ensemble(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ompn_ros.cli import segment

    (tmp_path / "ens").mkdir()
    (tmp_path / "ens" / ENSEMBLE_FILE).write_text("[]")
    code = segment.main(["--checkpoint", str(tmp_path / "ens"), "--generate", "1", "--domain", "craft"])
    assert code == 2
    assert "--checkpoint" in capsys.readouterr().err


def test_ompn_ensemble_cli_writes_a_loadable_ensemble(
    tmp_path: Path, members: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from ompn_ros.cli import ensemble as cli

    assert cli.main(["--out", str(tmp_path / "ens"), *map(str, members[:2])]) == 0
    assert "2 members" in capsys.readouterr().out
    assert isinstance(stepper_from_checkpoint(tmp_path / "ens"), EnsembleStepper)
    # the ensemble directory carries detector settings (the first member's until tuned for it)
    from ompn_ros.detect.settings import detector_file, load_detector_settings

    assert detector_file(tmp_path / "ens").is_file()
    assert load_detector_settings(tmp_path / "ens").online == load_detector_settings(members[0]).online
    other = _checkpoint(tmp_path / "sketchy", seed=9, sketch_mode="sum", sketch_vocab=4)
    assert cli.main(["--out", str(tmp_path / "bad"), str(members[0]), str(other)]) == 2
    assert "sketch_mode='sum'" in capsys.readouterr().err and not (tmp_path / "bad").exists()
