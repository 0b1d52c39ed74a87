"""``python -m lab.fresh``: a reproduction's runs on newly generated episodes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lab import fresh, reproduce


@pytest.mark.slow  # a lab study that trains
def test_runs_are_scored_on_new_episodes_with_their_own_validation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    work = tmp_path / "work"
    assert reproduce.main([
        "craft", "--settings", "full_nosketch", "--seeds", "1", "--episodes", "8", "--iterations", "2",
        "--extras", "none", "--threads", "1", "--work", str(work), "--results", str(tmp_path / "results"),
    ]) == 0
    out = tmp_path / "fresh.json"
    common = ["--work", str(work), "--setting", "full_nosketch", "--episodes", "2", "--reproduced", "8", "0"]
    assert fresh.main([*common, "--seeds", "1", "--data-seed", "7", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())
    label = "full_nosketch (6 new episodes, data seed 7)"
    decoder = rows[f"{label}: online, hsmm, mean delay <= 6"]
    assert decoder["align"]["n"] == 1 and 0.0 <= decoder["align"]["mean"] <= 1.0
    assert 0.0 <= decoder["at_end_share"]["mean"] <= 1.0
    assert rows[f"{label}: offline, paper's detector"]["delay_mean"] is None
    manifest = json.loads((work / "fresh" / "seed7" / "bags" / "craft_full" / "collect.json").read_text())
    assert manifest["settings"]["seed"] == 7  # new demonstrations, not the reproduction's
    assert f"{label}: online, threshold" in capsys.readouterr().out

    assert fresh.main([*common, "--seeds", "2", "--data-seed", "7", "--out", str(out)]) == 2
    assert "run full_nosketch_seed1" in capsys.readouterr().err  # never trained: named, no traceback
    with pytest.raises(SystemExit) as exc:
        fresh.main([*common, "--data-seed", "0", "--out", str(out)])
    assert exc.value.code == 2 and "must differ" in capsys.readouterr().err
