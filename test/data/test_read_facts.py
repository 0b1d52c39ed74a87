"""The read's facts as data: the cache keeps them beside the summary text, and training uses them.

The arm of ``test_idle_user_arm`` (6 joints at 50 Hz with encoder noise, ``split: idle``, ``idle_speed:
auto``) read into the cache and trained on.  The idle speed recorded beside the checkpoint comes from the
facts the reader produced, at full precision, whatever words the summary uses for people.

Was: the cache kept only the summary text and the trainer parsed the idle rule's threshold back out of
each bag's line with a pattern that had to follow its wording (at the 4 digits it printed): a reworded
line recorded no idle speed at all.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from arm_bags import _spec, arm_bag  # noqa: F401 (the fixture)
from lerobot_support import write_dataset

from ompn_ros.app.idle_record import trained_idle_speed
from ompn_ros.data import read_episodes
from ompn_ros.data.cache import INDEX, load_arrays, load_dataset_arrays
from ompn_ros.data.reader import BagFacts, BagReport

ROOT = Path(__file__).resolve().parents[2]


def _train(bag: Path, out: Path) -> None:
    from ompn_ros.cli.train import main

    spec_file = out.parent / "reader.yaml"
    spec_file.write_text(yaml.safe_dump(_spec().to_dict()))
    sets = ["data.domain=custom", f"data.reader_spec={spec_file}", "train.iterations=1", "train.threads=1",
            "model.slot_size=16"]
    config = str(ROOT / "config" / "train_dial.yaml")
    assert main(["--bags", str(bag), "--config", config, "--out", str(out), "--quiet",
                 *[arg for s in sets for arg in ("--set", s)]]) == 0


def test_a_reworded_summary_line_records_the_same_idle_speed(arm_bag: tuple[Path, list],  # noqa: F811
                                                              tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    bag, _ = arm_bag
    (facts,) = read_episodes(bag, spec=_spec()).report.facts()
    assert facts.idle_speed is not None and facts.idle_on.startswith("joint position and velocity")
    monkeypatch.setenv("OMPN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(BagReport, "line", lambda self: f"{self.path}: read by idle ({self.split})")
    _train(bag, tmp_path / "run")
    record = trained_idle_speed(tmp_path / "run" / "best")
    assert record is not None and record.speed == facts.idle_speed and record.on == facts.idle_on
    assert "idle_speed" not in (tmp_path / "run" / "read_report.txt").read_text()  # the words changed


def test_the_cache_keeps_the_facts_and_rebuilds_an_entry_whose_facts_do_not_hold(
        arm_bag: tuple[Path, list], tmp_path: Path) -> None:  # noqa: F811
    bag, _ = arm_bag
    want = read_episodes(bag, spec=_spec()).report.facts()
    built = load_arrays(bag, spec=_spec(), cache_dir=tmp_path)
    hit = load_arrays(bag, spec=_spec(), cache_dir=tmp_path)
    assert not built.cache_hit and hit.cache_hit and built.facts == hit.facts == want
    assert want[0].episodes == len(hit) and want[0].final_guessed == len(hit)  # duplicated row T
    assert isinstance(want[0].idle_speed, float) and hit.cache_path is not None
    index = json.loads((hit.cache_path / INDEX).read_text())
    index["facts"][0]["idle_speed"] = "0.05"  # a number in words: never read as one
    (hit.cache_path / INDEX).write_text(json.dumps(index))
    again = load_arrays(bag, spec=_spec(), cache_dir=tmp_path)
    assert not again.cache_hit and again.facts == want
    assert len(again.notes) == 1 and "idle_speed do not hold" in again.notes[0], again.notes


def test_a_lerobot_dataset_has_the_facts_of_one_source(arm_bag: tuple[Path, list],  # noqa: F811
                                                       tmp_path: Path) -> None:
    """A dataset is read as one source: its episodes and steps, no row T guessed, no idle rule."""
    episodes = read_episodes(arm_bag[0], spec=_spec()).episodes
    root = write_dataset(tmp_path / "dataset", episodes, fps=50, labels=False)
    arrays = load_dataset_arrays(root, cache_dir=tmp_path / "cache")
    steps = sum(e.length for e in episodes)
    assert arrays.facts == (BagFacts(str(arrays.facts[0].path), len(episodes), steps),)
    assert Path(arrays.facts[0].path).resolve() == root.resolve()
    assert load_dataset_arrays(root, cache_dir=tmp_path / "cache").facts == arrays.facts  # from the entry


@pytest.mark.parametrize("doc", [None, {"path": "a"}, {**BagFacts("a").__dict__, "steps": -1},
                                 {**BagFacts("a").__dict__, "idle_speed": True},
                                 {**BagFacts("a").__dict__, "idle_speed": float("nan")},
                                 {**BagFacts("a").__dict__, "extra": 1}])
def test_facts_that_do_not_hold_are_refused(doc: object) -> None:
    with pytest.raises(ValueError, match="read facts"):
        BagFacts.from_dict(doc)
    assert BagFacts.from_dict(BagFacts("a", 2, 9, 1, 0.5, "x").__dict__) == BagFacts("a", 2, 9, 1, 0.5, "x")
