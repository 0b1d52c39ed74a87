"""The synthetic hierarchical tasks produce valid episodes with the intended ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.train.errors import SyntheticError
from ompn_ros.train.synthetic import (
    CRAFT_OBS_DIM,
    USE,
    generate_continuous_episode,
    generate_discrete_episode,
    make_dataset,
    synthetic_spec,
)


def test_discrete_episode_structure() -> None:
    ep = generate_discrete_episode(0, corridor=8, n_goals=4)
    assert ep.observations.shape == (ep.length + 1, synthetic_spec("discrete")[0])
    # every subtask ends with USE, and the ground-truth boundaries are exactly the USE steps
    np.testing.assert_array_equal(ep.boundaries, np.flatnonzero(ep.actions == USE))
    assert len(ep.boundaries) == 4 and ep.boundaries[-1] == ep.length - 1
    pos = ep.observations[:, :8].argmax(axis=1)
    np.testing.assert_array_equal(pos[ep.boundaries], ep.sketch)  # USE happens at the goal cell
    assert ep.observations[-1, 16:].sum() == 4  # all reached flags set in the final observation


def test_continuous_episode_structure() -> None:
    ep = generate_continuous_episode(1)
    obs_dim, action_type, action_dim, _ = synthetic_spec("continuous")
    assert ep.observations.shape == (ep.length + 1, obs_dim) and ep.actions.shape == (ep.length, action_dim)
    assert action_type == "continuous" and len(ep.boundaries) == 4
    # the reached flags switch on at the "press" step that ends each subtask; it barely moves
    flags = ep.observations[:-1, 4:].sum(axis=1)
    np.testing.assert_array_equal(np.flatnonzero(np.diff(flags)) + 1, ep.boundaries)
    assert np.all(np.abs(ep.actions[ep.boundaries]) < 0.5)


def test_datasets_are_deterministic_and_craft_shaped() -> None:
    a, b = make_dataset("discrete", 3, seed=5), make_dataset("discrete", 3, seed=5)
    assert all(np.array_equal(x.observations, y.observations) for x, y in zip(a, b))
    craft = make_dataset("craft_shaped", 2)
    assert craft[0].observations.shape[1] == CRAFT_OBS_DIM
    with pytest.raises(SyntheticError, match="unknown synthetic kind"):
        make_dataset("maze", 2)  # type: ignore[arg-type]
    with pytest.raises(SyntheticError, match="corridor"):
        generate_discrete_episode(0, corridor=3, min_dist=2)
