"""``ompn_collect --demonstrator human``: bags with the human-like demonstrator's dropped and duplicated
observation messages, and what the reader makes of them (docs/craft.md §2.6)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.app.collect import episode_seed
from ompn_ros.cli import collect as collect_cli
from ompn_ros.data.episode import observation_copies
from ompn_ros.data.errors import AlignmentError
from ompn_ros.data.reader import read_episodes
from ompn_ros.data.reader.spec import ReaderSpec
from sim_nodes.registry import expert_episode, parse_human

HUMAN = ["drop_rate=0.08", "duplicate_rate=0.08", "pause_rate=0.1"]


def _collect(out: Path, *extra: str) -> int:
    argv = ["--domain", "craft", "--task", "makebed,makeaxe", "--episodes", "6", "--seed", "4",
            "--out", str(out), "--quiet", *extra]  # fmt: skip
    return collect_cli.main(argv)


def test_human_bags_are_read_back(tmp_path: Path) -> None:
    out = tmp_path / "bags"
    assert _collect(out, "--demonstrator", "human", *[f"--human={h}" for h in HUMAN]) == 0
    manifest = json.loads((out / "collect.json").read_text())
    assert manifest["settings"]["demonstrator"] == "human"
    assert manifest["settings"]["human"]["drop_rate"] == 0.08
    human = parse_human("craft", HUMAN)
    sources = [expert_episode("craft", episode_seed(4, i), task=("makebed", "makeaxe")[i % 2], human=human)
               for i in range(6)]  # fmt: skip
    copies = [observation_copies(ep) for ep in sources]
    dropped, duplicated = sum(int((c == 0).sum()) for c in copies), sum(int((c == 2).sum()) for c in copies)
    assert dropped > 0 and duplicated > 0
    assert manifest["parts"][0]["dropped_observations"] == dropped
    assert manifest["parts"][0]["duplicated_observations"] == duplicated

    # the preset is strict: a dropped observation leaves two partners on the step before, an error
    # naming the message and the fix
    with pytest.raises(AlignmentError, match=r"second partner .* 'strict: false'"):
        read_episodes(out, spec=ReaderSpec.for_domain("craft"))
    spec = dataclasses.replace(ReaderSpec.for_domain("craft"), strict=False)
    result = read_episodes(out, spec=spec)
    assert len(result.episodes) == 6
    for src, got, c in zip(sources, result.episodes, copies, strict=True):
        kept = np.flatnonzero(c[:-1] > 0)  # a dropped observation's step is lost, a duplicate read once
        assert got.length == len(kept) == src.length - int((c == 0).sum())
        np.testing.assert_array_equal(got.actions, src.actions[kept])
        np.testing.assert_array_equal(got.subtask, src.subtask[kept])
        np.testing.assert_array_equal(got.observations, src.observations[[*kept, src.length]])
    report = result.report  # counted: the steps of dropped observations, the second copy of duplicates
    assert report.total("duplicates") == {"/action": dropped, "/subtask": dropped, "/observation": duplicated}
    assert report.total("missing") == {}
    assert sum(b.dropped_steps for b in report.bags) == 0


def test_human_bags_with_duplicates_only_read_with_the_preset(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture) -> None:
    """Was: the first copy of a duplicated observation had no action, an error of the strict preset."""
    out = tmp_path / "bags"
    human = ["drop_rate=0", "duplicate_rate=0.1"]
    assert collect_cli.main(["--domain", "craft", "--task", "makebed", "--episodes", "4", "--seed", "5",
                             "--out", str(out), "--demonstrator", "human",
                             *[f"--human={h}" for h in human]]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert "0 observation messages dropped" in printed and "the presets read them" in printed
    sources = [expert_episode("craft", episode_seed(5, i), task="makebed", human=parse_human("craft", human))
               for i in range(4)]  # fmt: skip
    duplicated = sum(int((observation_copies(ep) == 2).sum()) for ep in sources)
    result = read_episodes(out, spec=ReaderSpec.for_domain("craft"))
    assert duplicated > 0 and len(result.episodes) == 4
    for src, got in zip(sources, result.episodes, strict=True):
        np.testing.assert_array_equal(got.observations, src.observations)
        np.testing.assert_array_equal(got.actions, src.actions)
        np.testing.assert_array_equal(got.subtask, src.subtask)
    assert result.report.total("duplicates") == {"/observation": duplicated}


def test_human_parameters_need_the_human_demonstrator(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert _collect(tmp_path / "a", "--human", "pause_rate=0.1") == 2
    assert "--demonstrator human" in capsys.readouterr().err
    assert _collect(tmp_path / "b", "--demonstrator", "human", "--human", "pause_rate=7") == 2
    err = capsys.readouterr().err.strip()
    assert "'pause_rate'" in err and len(err.splitlines()) == 1 and "Traceback" not in err
