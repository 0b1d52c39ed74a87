"""``model.still_tolerance: auto`` (``ompn_train``'s default): T from the training episodes' own noise floor,
without labels (ompn_ros.data.cuts.choose_tolerance, docs/design.md#still-observations).

Designed on Craft full observation (expert and human-like defaults); the sims' other families here were
kept out of its design: Craft partial observation, Dial (expert and human-like), pauses at subtask
changes, and the synthetic episodes below."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ompn_ros.app.errors import TrainSetupError
from ompn_ros.app.training import TrainingData, build_configs
from ompn_ros.data.cuts.still import AUTO_MIN_STILL_SHARE, choose_tolerance, drop_still
from ompn_ros.data.episode import Episode
from sim_nodes.human import BOUNDARY_MODE, parse_human
from sim_nodes.registry import default_tasks, expert_episode


def one_hot_episodes(noise: float, pause: float, count: int = 30, seed: int = 0
                     ) -> tuple[list[Episode], list]:
    """Quantised features (one-hot position on a 20-cell line, 0/1) with Gaussian sensor noise; with
    probability ``pause`` a step holds the position (a pause).  Returns the episodes and, per episode,
    the rows that are pauses."""
    rng = np.random.default_rng(seed)
    eps, paused = [], []
    for i in range(count):
        cells, held, cell = [], [], 10
        for t in range(40):
            if t and rng.random() < pause:
                held.append(t)
            elif t:
                step = int(rng.choice((-1, 1)))
                cell = cell + step if 0 <= cell + step <= 19 else cell - step  # a wall turns it back
            cells.append(cell)
        obs = np.eye(20, dtype=np.float32)[cells] + rng.normal(0, noise, (40, 20)).astype(np.float32)
        labels = np.repeat(np.arange(3), 13)[:39]
        eps.append(Episode(obs, rng.integers(0, 2, 39), labels, None, "line", i, True))
        paused.append(held)
    return eps, paused


def test_noise_free_data_keeps_every_step() -> None:
    """A scripted demonstrator on a noise-free sim: its exact repeats are no pause; T = 0."""
    eps, _ = one_hot_episodes(noise=0.0, pause=0.1)
    choice = choose_tolerance(eps)
    assert choice.tolerance == 0.0 and "no noise floor" in choice.reason


def test_pauses_under_sensor_noise_are_found_and_moves_kept() -> None:
    eps, paused = one_hot_episodes(noise=0.02, pause=0.15)
    choice = choose_tolerance(eps)
    assert 0.02 < choice.tolerance < 0.5  # above the noise, far below a move (1)
    for ep, held in zip(eps, paused, strict=True):
        _, firsts = drop_still(ep, choice.tolerance)
        still = sorted(set(range(ep.length)) - set(firsts.tolist()))
        assert still == [t for t in held if t < ep.length]
    assert choice.still_share == pytest.approx(0.15, abs=0.04)


def test_slow_motion_under_noise_is_off() -> None:
    """A continuous signal that often moves by a few noise floors a step: pauses cannot be told from it."""
    rng = np.random.default_rng(3)
    eps = []
    for i in range(20):
        speed = np.repeat(rng.uniform(0.0, 0.03, 8), 10)  # rad per step, held pauses at speed ~0
        speed[rng.random(80) < 0.2] = 0.0
        obs = np.cumsum(speed)[:, None] * np.ones((1, 6)) + rng.normal(0, 0.002, (80, 6))
        eps.append(Episode(obs.astype(np.float32), np.zeros((79, 6), np.float32), None, None, "arm", i, True))
    choice = choose_tolerance(eps)
    assert choice.tolerance == 0.0 and "slow moves look like pauses" in choice.reason


def test_noise_without_pauses_is_off() -> None:
    eps, _ = one_hot_episodes(noise=0.02, pause=0.0)
    choice = choose_tolerance(eps)
    assert choice.tolerance == 0.0 and choice.still_share < AUTO_MIN_STILL_SHARE and choice.noise > 0


def _sim(domain: str, changes: tuple[str, ...] | None, count: int, partial: bool = False) -> list[Episode]:
    tasks = default_tasks(domain)
    like = None if changes is None else parse_human(domain, changes)
    return [expert_episode(domain, 91000 + i, task=tasks[i % len(tasks)], partial=partial, human=like)
            for i in range(count)]


def test_families_kept_out_of_the_design() -> None:
    """The expert of Craft partial observation (4 % exact repeats) and of Dial keep T = 0; the
    human-like Craft partial and the pauses-at-boundaries family get the Craft T; Dial's human-like
    family keeps 0 too: its slow approach moves by a few noise floors a step, as a held arm's noise
    does, so a tolerance would thin moving steps as well."""
    assert choose_tolerance(_sim("craft", None, 30, partial=True)).tolerance == 0.0
    craft = choose_tolerance(_sim("craft", (), 30, partial=True))
    bounded = choose_tolerance(_sim("craft", BOUNDARY_MODE, 30))
    assert 0.1 < craft.tolerance < 0.3 and 0.1 < bounded.tolerance < 0.3 and bounded.still_share > 0.05
    assert choose_tolerance(_sim("dial", None, 2)).tolerance == 0.0
    dial = choose_tolerance(_sim("dial", BOUNDARY_MODE, 2))
    assert dial.tolerance == 0.0 and dial.noise > 0.002 and "slow moves look like pauses" in dial.reason


def _config(model: dict) -> dict:
    return {"model": model, "train": {"iterations": 1, "progress": False}, "data": {}}


def test_ompn_train_resolves_auto_by_default_and_reports_it(tmp_path: Path) -> None:
    eps, _ = one_hot_episodes(noise=0.02, pause=0.15)
    fields = {"obs_dim": 20, "action_type": "discrete", "action_dim": 2}
    data = TrainingData(eps, fields, None, {"summary": "read 1 bag(s)"})
    model, _ = build_configs(_config({}), data, tmp_path, False, True)
    assert model.still_tolerance > 0
    assert model.still_tolerance == pytest.approx(choose_tolerance(eps).tolerance)
    assert "still_tolerance: auto -> " in data.report["summary"] and data.report["still"]["still_share"] > 0.1
    assert '"still_tolerance": ' + repr(model.still_tolerance) in model.to_json().replace("\n", "")
    fixed, _ = build_configs(_config({"still_tolerance": 0.3}), data, tmp_path, False, True)
    assert fixed.still_tolerance == 0.3
    with pytest.raises(TrainSetupError, match="still_tolerance must be 'auto'"):
        build_configs(_config({"still_tolerance": "often"}), data, tmp_path, False, True)
