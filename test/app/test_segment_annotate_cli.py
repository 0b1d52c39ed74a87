"""``ompn_segment --annotate OUT``: the replayed bag comes back as an mcap copy with the node's topics."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

pytest.importorskip("torch")
mcap_reader = pytest.importorskip("mcap.reader")

from ompn_ros import layout  # noqa: E402
from ompn_ros.cli.segment import main  # noqa: E402
from ompn_ros.data.recorder.bag_writer import write_episodes  # noqa: E402
from ompn_ros.train import synthetic  # noqa: E402


def _topics(bag: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for file in sorted(bag.glob("*.mcap")):
        with open(file, "rb") as fh:
            for _, channel, _ in mcap_reader.make_reader(fh).iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_annotate_writes_pi_and_segments_beside_the_robot_data(
    tmp_path: Path, synthetic_checkpoint: Path
) -> None:
    episodes = synthetic.make_dataset("discrete", 3, seed=5)
    domain = dataclasses.replace(layout.CRAFT, obs_dim=episodes[0].observations.shape[1])
    write_episodes(tmp_path / "bag", episodes, domain)
    out = tmp_path / "annotated"
    code = main(["--bag", str(tmp_path / "bag"), "--checkpoint", str(synthetic_checkpoint),
                 "--out", str(tmp_path / "seg"), "--plot-episodes", "0", "--annotate", str(out)])
    assert code == 0
    counts = _topics(out)
    steps = sum(ep.length for ep in episodes)
    original = _topics(tmp_path / "bag")
    assert {t: counts[t] for t in original} == original  # every original message is kept
    # one pi and one segment per replayed observation (the done step included, as live)
    assert counts["/ompn_node/pi"] == counts["/ompn_node/segment"]
    assert steps <= counts["/ompn_node/pi"] <= steps + len(episodes)
    assert counts["/ompn_node/boundary"] >= len(episodes)  # at least the episode ends


def test_annotate_without_a_bag_is_one_clear_error(
    tmp_path: Path, synthetic_checkpoint: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["--generate", "2", "--domain", "craft", "--checkpoint", str(synthetic_checkpoint),
                 "--out", str(tmp_path / "seg"), "--annotate", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and "ompn_segment: error:" in err and "--annotate" in err
    assert not (tmp_path / "a").exists()
