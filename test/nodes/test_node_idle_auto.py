"""``ompn_node``'s ``idle_speed: auto``: the idle rule's threshold live, where there is no bag to measure.

The arm of ``test_idle_user_arm`` (6 joints at 50 Hz, positions and velocities with encoder noise, three
demonstrations between still periods) streamed into the node with ``idle_s`` 1 s.  With the record
``ompn_train`` writes beside the checkpoint, the node runs that read's threshold; without one it holds
the first 10 s of the stream, derives the threshold from them as the reader derives it from a bag, and
then cuts exactly as a node given that number from the start.

Was: ``idle_speed`` was a number only (``auto`` refused at start-up), defaulting to 0.01, which the
encoder noise of this arm exceeds at every step: the whole stream read as one episode."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

from arm_bags import JOINTS, _arm_stream, _spec, arm_bag  # noqa: E402, F401 (the fixture)
from driver_streams import events, msg  # noqa: E402
from node_in_process import active_node  # noqa: E402 (publishers that record)

from ompn_ros.app.idle_record import RECORD_FILE, read_idle_speed, trained_idle_speed  # noqa: E402
from ompn_ros.data import read_episodes  # noqa: E402
from ompn_ros.data.reader import BagFacts  # noqa: E402
from ompn_ros.model.checkpoint import save_checkpoint  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.model.errors import CheckpointError  # noqa: E402
from ompn_ros.model.policy import OMPNPolicy  # noqa: E402

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[2]
ARM_PARAMS = {"obs_source": "joint_state", "joint_fields": ["position", "velocity"], "joint_names": JOINTS,
              "idle_s": 1.0, "max_stamp_lead": 0.0}


def _checkpoint(path: Path) -> Path:
    torch.manual_seed(12)
    save_checkpoint(path, OMPNPolicy(OMPNConfig(obs_dim=12, action_type="continuous", action_dim=6,
                                                n_slots=3, slot_size=16)))
    return path


def _stream_into(node: Any) -> None:
    stamps, rows, _, _ = _arm_stream(np.random.default_rng(56))  # the stream of the arm bag
    for t, row in zip(stamps, rows, strict=True):
        node.inputs.joint_states.on_joint_state(msg(int(t), JOINTS, row[:6], row[6:]))


def test_auto_runs_the_threshold_the_training_read_recorded(ctx, arm_bag: tuple[Path, list],  # noqa: F811
                                                            tmp_path: Path) -> None:
    """``ompn_train`` on the arm's bag (``split: idle``, ``idle_speed: auto``) records the threshold its
    read derived beside ``best/``; the node given that checkpoint runs it and cuts the demonstrations."""
    import yaml

    from ompn_ros.cli.train import main

    path, demos = arm_bag
    spec_file = tmp_path / "reader.yaml"
    spec_file.write_text(yaml.safe_dump(_spec().to_dict()))
    out = tmp_path / "run"
    sets = ["data.domain=custom", f"data.reader_spec={spec_file}", "train.iterations=1", "train.threads=1",
            "model.slot_size=16"]
    config = str(ROOT / "config" / "train_dial.yaml")
    assert main(["--bags", str(path), "--config", config, "--out", str(out), "--quiet",
                 *[arg for s in sets for arg in ("--set", s)]]) == 0
    read = read_episodes(path, spec=_spec()).report
    record = read_idle_speed(read.facts())  # what the read used
    assert record is not None and record.on.startswith("joint position and velocity")
    assert 0.01 < record.speed < 1.0 and f"idle_speed auto -> {record.speed:.4g} on" in read.summary()
    assert trained_idle_speed(out / "best") == record == trained_idle_speed(out / "last")
    node = active_node(ctx, out / "best", **ARM_PARAMS)  # idle_speed: auto, the default
    assert node.stream.limits.idle_speed == pytest.approx(record.speed)
    _stream_into(node)
    counters = node.counters()
    assert counters["episodes"] == len(demos) and counters["episodes_ended"] == len(demos)
    node.destroy_node()


def test_the_record_is_the_median_of_the_bags_at_full_precision() -> None:
    on = "joint position (rad/s for revolute joints)"
    facts = [BagFacts("a", 1, 10, idle_speed=0.5123456789, idle_on=on), BagFacts("b", 1, 10, idle_speed=0.25,
             idle_on=on), BagFacts("c", 1, 10, idle_speed=1e-09, idle_on=on), BagFacts("d", 1, 10)]
    record = read_idle_speed(facts)
    assert record is not None and record.speed == 0.25
    assert record.on == on and "median of 3 bags" in record.source
    assert read_idle_speed(facts[:1]).speed == 0.5123456789  # type: ignore[union-attr]
    assert read_idle_speed(facts[-1:]) is None


def test_auto_without_a_record_measures_the_stream_then_cuts_as_if_known(ctx, tmp_path: Path) -> None:
    ckpt = _checkpoint(tmp_path / "ckpt")
    lines: list[str] = []
    probing = active_node(ctx, ckpt, idle_speed="auto", **ARM_PARAMS)
    probing.get_logger().info = lambda text, *a, **k: lines.append(text)  # type: ignore[method-assign]
    _stream_into(probing)
    derived = probing.stream.limits.idle_speed
    found = f"idle_speed auto -> {derived:.4g}"
    assert any(line.startswith(found) and line.endswith("from the stream's first 501 observations")
               for line in lines), lines  # 10 s at 50 Hz
    known = active_node(ctx, ckpt, idle_speed=derived, **ARM_PARAMS)
    _stream_into(known)
    assert probing.counters()["episodes_ended"] == 3
    assert events(probing) == events(known) and probing.counters() == known.counters()
    old = active_node(ctx, ckpt, idle_speed=0.01, **ARM_PARAMS)  # the former default
    _stream_into(old)
    assert old.counters()["episodes"] == 1 and old.counters()["episodes_ended"] == 0
    for node in (probing, known, old):
        node.destroy_node()


def test_a_bad_record_fails_configure_in_one_line(tmp_path: Path) -> None:
    ckpt = _checkpoint(tmp_path / "ckpt")
    (ckpt / RECORD_FILE).write_text('{"format": "ompn_ros.idle_speed", "idle_speed": "fast"}')
    with pytest.raises(CheckpointError, match=f"{RECORD_FILE}: expected format") as err:
        trained_idle_speed(ckpt)
    assert "\n" not in str(err.value)


def test_the_parameter_takes_auto_or_a_number_and_refuses_the_rest(ctx, tmp_path: Path) -> None:
    from rclpy.parameter import Parameter

    node = active_node(ctx, _checkpoint(tmp_path / "ckpt"), **ARM_PARAMS)
    node.trigger_deactivate()
    for good in ("auto", 0.6, 2):
        assert node.set_parameters([Parameter("idle_speed", value=good)])[0].successful, good
    for bad in ("fast", -1.0):
        result = node.set_parameters([Parameter("idle_speed", value=bad)])[0]
        assert not result.successful and "'auto' or a number >= 0" in result.reason
    node.destroy_node()
