"""lab.human_gap (docs/experiments.md §54): its perturbation families are valid human-like settings
that differ from the defaults in what they name, and a tiny run scores the shipped Craft checkpoint."""

from __future__ import annotations

import dataclasses

import pytest

from lab import human_gap as hg
from lab.data import HUMAN_VARIANTS
from lab.own_data import ARMS
from sim_nodes.human import human_defaults, parse_human


@pytest.mark.parametrize("domain", ["craft", "dial"])
def test_each_family_changes_only_what_it_names(domain: str) -> None:
    base = human_defaults(domain)
    names = [f.name for f in dataclasses.fields(base)]
    fams = hg.families(domain)
    assert fams["expert"] is None and fams["human-like"] == ()
    assert ("tempo only" in fams) == (domain == "dial")
    for name in hg.perturbations(domain):
        without = parse_human(domain, fams[f"human-like without {name}"] or ())
        changed = {n for n in names if getattr(base, n) != getattr(without, n)}
        assert changed and changed <= {c.split("=")[0] for c in hg._OFF[name]}
        alone = parse_human(domain, fams[f"{name} only"] or ())
        kept = {n for n in names if getattr(base, n) == getattr(alone, n)}
        assert {c.split("=")[0] for c in hg._OFF[name]} <= kept  # its own parameters at the defaults
        assert alone.drop_rate == alone.duplicate_rate == 0.0


def test_the_variant_arms_train_on_their_own_bag_sets() -> None:
    variants = [a for a in ARMS.values() if a.demonstrator not in ("expert", "human")]
    assert variants and {a.demonstrator for a in variants} == set(HUMAN_VARIANTS) - {"human"}
    assert all(a.data == f"craft_full_{a.demonstrator}" for a in variants
               if a.demonstrator != "human_boundaries")
    boundaries = {a.data for a in variants if a.demonstrator == "human_boundaries"}
    assert boundaries == {"craft_full_human_boundaries", "craft_partial_human_boundaries",
                          "dial_full_human_boundaries"}
    assert all(a.still == "auto" for a in variants if a.demonstrator == "human_boundaries")
    assert ARMS["human_craft_full_complete_seed10"].data == "craft_full_human"
    noidle = [a for a in ARMS.values() if not a.idle]
    assert {a.data for a in noidle} == {"craft_full_human", "craft_partial_human"}


def test_quirks_scores_the_shipped_craft_checkpoint() -> None:
    from ompn_ros.checkpoints import shipped_checkpoint

    rows = hg.quirks("craft", shipped_checkpoint("craft"), 6, partial=False)
    assert [r["family"] for r in rows] == list(hg.families("craft"))
    for row in rows:
        assert 0.0 <= row["align"] <= 100.0 and 0.0 <= row["f1_tol1"] <= 100.0
    steps = {r["family"]: r["mean_steps"] for r in rows}
    assert steps["human-like"] > steps["expert"]  # pauses and detours lengthen the episodes
    assert steps["noise only"] == steps["expert"]  # noise alone changes no step


def test_collapse_idle_drops_the_steps_whose_action_changed_nothing() -> None:
    import numpy as np

    from lab.data import collapse_idle
    from ompn_ros.data.episode import Episode

    obs = np.array([[1, 0], [0, 1], [0, 1], [0, 1], [1, 1], [1, 1]], dtype=np.float32)  # T = 5
    obs[2] += 0.05  # noise below the tolerance
    ep = Episode(obs, np.array([0, 4, 4, 1, 4]), np.array([0, 0, 1, 1, 1]))
    short, kept = collapse_idle(ep)
    assert kept.tolist() == [0, 3, 4]  # steps 1 and 2 idle (observations 1-3 equal); the last kept
    assert short.length == 3 and short.actions.tolist() == [0, 1, 4] and short.subtask.tolist() == [0, 1, 1]
    assert np.array_equal(short.observations[-1], obs[-1])


def test_collapse_idle_can_watch_the_first_features_only() -> None:
    import numpy as np

    from lab.data import collapse_idle
    from ompn_ros.data.episode import Episode

    obs = np.zeros((4, 3), dtype=np.float32)
    obs[:, 2] = [0.0, 1.0, 2.0, 3.0]  # an unwatched feature moves every step
    obs[2:, 0] = 1.0  # the watched one moves once, between observations 1 and 2
    ep = Episode(obs, np.zeros(3, dtype=np.int64))
    assert collapse_idle(ep, 0.5)[1].tolist() == [0, 1, 2]
    assert collapse_idle(ep, 0.5, features=2)[1].tolist() == [1, 2]


def test_the_still_arms_train_with_the_products_rule(tmp_path) -> None:
    from lab.own_data import STILL_TOLERANCE, arm_configs

    still = [a for a in ARMS.values() if a.still and a.still != "auto"]
    assert {a.data for a in still} == {"craft_full_human", "craft_partial_human"} and len(still) == 10
    model, _ = arm_configs(ARMS["human_craft_full_still_seed10"], tmp_path, 1)
    assert model.still_tolerance == STILL_TOLERANCE > 0
    auto = [a for a in ARMS.values() if a.still == "auto"]  # chosen from the pool when training (§57)
    assert len(auto) == 25 and arm_configs(auto[0], tmp_path, 1)[0].still_tolerance == 0
    assert arm_configs(ARMS["human_craft_full_complete_seed10"], tmp_path, 1)[0].still_tolerance == 0


def test_replayed_scores_a_checkpoint_as_the_node_runs_it(tmp_path) -> None:
    import json
    import shutil

    from lab.replayed import replayed_figures
    from ompn_ros.checkpoints import shipped_checkpoint

    eps = hg.episodes("craft", (), 4)
    plain = replayed_figures(shipped_checkpoint("craft"), "craft", eps)
    still_dir = tmp_path / "still"
    shutil.copytree(shipped_checkpoint("craft"), still_dir)
    config = json.loads((still_dir / "config.json").read_text())
    (still_dir / "config.json").write_text(json.dumps({**config, "still_tolerance": 0.2}))
    still = replayed_figures(still_dir, "craft", eps)
    assert plain["still_tolerance"] == 0 and still["still_tolerance"] == 0.2
    figures = ("offline_align", "offline_f1_1", "online_align", "online_f1_1")
    for got in (plain, still):
        assert all(0 <= got[k] <= 100 for k in figures)
    assert plain != {**still, "still_tolerance": 0.0}  # the pauses of these episodes were not stepped
