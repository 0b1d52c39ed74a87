"""``ompn_collect``: splitting, manifest, refusing to overwrite, resume after an interruption."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from synthetic_episodes import assert_same_episode, dial_episode

from ompn_ros.app.collect import collect, episode_seed
from ompn_ros.app.errors import CollectError
from ompn_ros.cli import collect as collect_mod
from ompn_ros.cli._common import INTERRUPTED
from ompn_ros.data import ReaderSpec, read_episodes
from ompn_ros.data.episode import Episode


class FakeDial:
    """Deterministic synthetic generator (episode content depends on the seed only)."""

    def __init__(self, fail_after: int | None = None) -> None:
        self.calls = 0
        self.fail_after = fail_after

    def __call__(self, seed: int, task: str, partial: bool) -> Episode:
        if self.fail_after is not None and self.calls >= self.fail_after:
            raise KeyboardInterrupt("simulated interruption")
        self.calls += 1
        rng = np.random.default_rng(seed)
        ep = dial_episode(0, int(rng.integers(3, 8)), rng)
        ep.seed = seed
        return ep


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch) -> FakeDial:
    gen = FakeDial()
    monkeypatch.setattr(collect_mod, "default_generator", lambda domain, human=None: gen)
    return gen


def _argv(out: Path, *extra: str) -> list[str]:
    return ["--domain", "dial", "--episodes", "7", "--seed", "11", "--out", str(out), "--quiet", *extra]


def test_split_and_manifest(tmp_path: Path, fake: FakeDial) -> None:
    out = tmp_path / "out"
    assert collect_mod.main(_argv(out, "--split-every", "3", "--storage", "sqlite3")) == 0
    assert sorted(p.name for p in out.iterdir()) == ["collect.json", "part_000", "part_001", "part_002"]
    manifest = json.loads((out / "collect.json").read_text())
    assert manifest["totals"]["episodes"] == 7 and manifest["totals"]["parts"] == 3
    assert [p["episodes"] for p in manifest["parts"]] == [[0, 1, 2], [3, 4, 5], [6]]
    seeds = [s for p in manifest["parts"] for s in p["seeds"]]
    assert seeds == [episode_seed(11, i) for i in range(7)]
    assert manifest["command"][0] == "ompn_collect" and "--split-every" in manifest["command"]
    # the storage file is named after its part (not hidden, found without metadata.yaml)
    assert [p.name for p in out.glob("part_000/*.db3")] == ["part_000.db3"]
    result = read_episodes(out, spec=ReaderSpec.for_domain("dial"))
    assert [e.seed for e in result.episodes] == seeds
    for seed, ep in zip(seeds, result.episodes):
        assert_same_episode(FakeDial()(seed, "dial", False), ep, joints=True)


def test_refuses_to_overwrite(tmp_path: Path, fake: FakeDial, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert collect_mod.main(_argv(out)) == 0
    before = (out / "collect.json").read_text()
    assert collect_mod.main(_argv(out)) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and "--overwrite" in err and "--resume" in err
    assert (out / "collect.json").read_text() == before
    assert collect_mod.main(_argv(out, "--overwrite", "--seed", "12")) == 0
    assert json.loads((out / "collect.json").read_text())["settings"]["seed"] == 12
    # never deletes a directory that is not ours
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "precious.txt").write_text("keep")
    assert collect_mod.main(_argv(foreign, "--overwrite")) == 2
    assert "refusing to delete" in capsys.readouterr().err
    assert (foreign / "precious.txt").exists()


def test_resume_after_interruption(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    interrupted = FakeDial(fail_after=4)
    monkeypatch.setattr(collect_mod, "default_generator", lambda domain, human=None: interrupted)
    # Ctrl-C ends the command with one line on stderr and exit code 130 (ompn_ros.cli._common)
    assert collect_mod.main(_argv(out, "--split-every", "3")) == INTERRUPTED == 130
    err = capsys.readouterr().err
    assert err.strip() == "ompn_collect: simulated interruption" and "Traceback" not in err
    with pytest.raises(KeyboardInterrupt):  # --debug keeps the traceback
        collect_mod.main(_argv(tmp_path / "debug", "--split-every", "3", "--debug"))
    assert (out / "part_000").is_dir() and not (out / "part_001").exists()
    assert (out / ".part_001.tmp").exists()  # the half-written part, never read
    assert len(read_episodes(out).episodes) == 3

    resumed = FakeDial()
    monkeypatch.setattr(collect_mod, "default_generator", lambda domain, human=None: resumed)
    assert collect_mod.main(_argv(out, "--split-every", "3", "--resume")) == 0
    assert resumed.calls == 4  # parts 1 and 2 only
    assert not (out / ".part_001.tmp").exists()
    result = read_episodes(out, spec=ReaderSpec.for_domain("dial"))
    seeds = [episode_seed(11, i) for i in range(7)]
    assert [e.seed for e in result.episodes] == seeds
    assert json.loads((out / "collect.json").read_text())["totals"]["episodes"] == 7

    with pytest.raises(CollectError, match="settings differ"):
        collect(out, domain="dial", tasks=["dial"], episodes=7, seed=99, split_every=3,
                            resume=True, progress=False)


def test_real_craft_collect(tmp_path: Path) -> None:
    craft = pytest.importorskip("sim_nodes.craft")
    out = tmp_path / "craft"
    code = collect_mod.main(["--domain", "craft", "--task", "makebed,makeaxe", "--episodes", "2",
                             "--seed", "0", "--out", str(out), "--quiet"])
    assert code == 0
    result = read_episodes(out, spec=ReaderSpec.for_domain("craft"))
    assert [e.task for e in result.episodes] == ["makebed", "makeaxe"]
    for i, ep in enumerate(result.episodes):
        expected = craft.generate_episode(episode_seed(0, i), task=ep.task, full_obs=True)
        assert_same_episode(expected, ep)
