"""Benchmark of any message type read by field path against the hand-written JointState parser.

A lab's ``my_robot_msgs/msg/ArmState`` (header, ``string[] joint_names``, ``float64[] positions``,
``float64[] velocities``, nested ``GripperState``; its definition registered as a bag's would be) and a
``sensor_msgs/msg/JointState`` carrying the same 7 joints (names, positions, velocities):

1. Bulk (the bag reader): ``FieldReader.vectors`` of ``positions`` over N messages vs the reader's
   JointState path (``decode_joint_states`` + ``joint_vectors``, position); µs per message and the
   ratio (target: at most 2, docs/specs.md).
2. Per message (``ompn_node``'s observation rule): ``FieldReader.values`` of ``positions`` and
   ``gripper.width`` vs ``JointStateParser.parse``; µs per message and the ratio.
3. ``read_episodes`` of a bag whose observation is ArmState (by field path) vs one whose observation is
   JointState (same commands, same message count): seconds and the ratio.

    .venv/bin/python bench/bench_types.py [--quick]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ompn_ros.data import messages as m  # noqa: E402 (after the path insert)

Result = dict[str, tuple[float, str]]
JOINTS = [f"joint_{i}" for i in range(7)]
ARM_MSG = (
    "std_msgs/Header header\nstring[] joint_names\nfloat64[] positions\nfloat64[] velocities\n"
    "GripperState gripper\n" + "=" * 80 + "\nMSG: my_robot_msgs/GripperState\n"
    "float64 width\nfloat32 force\nbool grasped\n"
)
ARM = "my_robot_msgs/msg/ArmState"


def _best(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def _messages(n: int) -> tuple[list[bytes], list[bytes]]:
    """``n`` ArmState and ``n`` JointState messages of the same joints and values."""
    from ompn_ros.data.messages.types import register_definition

    register_definition(ARM, "msg", ARM_MSG)
    store = m.typestore()
    arm, grip = store.types[ARM], store.types["my_robot_msgs/msg/GripperState"]
    rng = np.random.default_rng(0)
    arms, states = [], []
    for k in range(n):
        pos, vel = rng.standard_normal(7), rng.standard_normal(7)
        stamp = 10**9 + k * 1_000_000
        msg = arm(
            header=m.header(stamp, "base_link"),
            joint_names=JOINTS,
            positions=pos,
            velocities=vel,
            gripper=grip(width=0.04, force=1.5, grasped=False),
        )
        arms.append(bytes(store.serialize_cdr(msg, ARM)))
        states.append(m.serialize(m.joint_state(stamp, JOINTS, pos, vel)))
    return arms, states


def bench_decode(n: int, repeats: int) -> Result:
    from ompn_ros import layout
    from ompn_ros.data.messages.fieldpath import FieldReader
    from ompn_ros.data.reader.joints import decode_joint_states, joint_vectors
    from ompn_ros.data.reader.spec import VectorSource

    arms, states = _messages(n)
    stamps = np.arange(n, dtype=np.int64)
    src = VectorSource("/joint_states", layout.JOINT_STATE)
    reader = FieldReader(ARM, ["positions"])
    custom = reader.vectors(arms)[0].astype(np.float32)  # as the reader keeps it
    js = joint_vectors(
        "b", "/joint_states", src, stamps, decode_joint_states("b", "/joint_states", stamps, states)
    )
    np.testing.assert_array_equal(custom, js)  # the same numbers
    t_custom = _best(lambda: reader.vectors(arms)[0].astype(np.float32), repeats) / n * 1e6
    t_js = (
        _best(
            lambda: joint_vectors("b", "/j", src, stamps, decode_joint_states("b", "/j", stamps, states)),
            repeats,
        )
        / n
        * 1e6
    )
    few = min(n, 3000)
    live = FieldReader(ARM, ["positions", "gripper.width"])
    parser = m.JointStateParser()
    t_live = _best(lambda: [live.values(raw) for raw in arms[:few]], repeats) / few * 1e6
    t_parse = _best(lambda: [parser.parse(raw) for raw in states[:few]], repeats) / few * 1e6
    return {
        "custom_bulk_decode": (t_custom, "us/msg"),
        "jointstate_bulk_decode": (t_js, "us/msg"),
        "custom_over_jointstate_bulk": (t_custom / t_js, "x"),
        "custom_per_message_decode": (t_live, "us/msg"),
        "jointstate_per_message_parse": (t_parse, "us/msg"),
        "custom_over_jointstate_per_message": (t_live / t_parse, "x"),
    }


def _bag(path: Path, obs: list[bytes], obs_type: str, n: int) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(
        Stores.ROS2_JAZZY
    )  # the writer's own store: the reader learns ArmState from the bag
    types = get_types_from_msg(ARM_MSG.split("=" * 80)[0], ARM)
    types.update(
        get_types_from_msg("float64 width\nfloat32 force\nbool grasped\n", "my_robot_msgs/msg/GripperState")
    )
    store.register(types)
    rng = np.random.default_rng(1)
    with Writer(path, version=9) as writer:
        state = writer.add_connection("/arm/state", obs_type, typestore=store)
        cmd = writer.add_connection("/arm/cmd", "std_msgs/msg/Float64MultiArray", typestore=store)
        for k in range(n):
            stamp = 10**9 + k * 40_000_000 + (k // 100) * 2_000_000_000  # demonstrations of 100 steps
            writer.write(state, stamp, obs[k])
            writer.write(cmd, stamp + 2_000_000, m.encode_float64_array(rng.standard_normal(7), "cmd"))


def bench_read(n: int, repeats: int) -> Result:
    from ompn_ros.data import ReaderSpec, read_episodes

    arms, states = _messages(n)
    tmp = Path(tempfile.mkdtemp(prefix="bench_types_"))
    try:
        _bag(tmp / "arm", arms, ARM, n)
        _bag(tmp / "js", states, "sensor_msgs/msg/JointState", n)
        common = {
            "action": {"topic": "/arm/cmd", "type": "std_msgs/msg/Float64MultiArray"},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
        }
        arm_spec = ReaderSpec.from_dict(
            {"observation": {"topic": "/arm/state", "type": ARM, "field": "positions"}, **common}
        )
        js_spec = ReaderSpec.from_dict(
            {
                "observation": {
                    "topic": "/arm/state",
                    "type": "sensor_msgs/msg/JointState",
                    "fields": ["position"],
                },
                **common,
            }
        )
        a, b = read_episodes(tmp / "arm", spec=arm_spec), read_episodes(tmp / "js", spec=js_spec)
        assert all(np.array_equal(x.observations, y.observations) for x, y in zip(a.episodes, b.episodes))
        t_arm = _best(lambda: read_episodes(tmp / "arm", spec=arm_spec), repeats)
        t_js = _best(lambda: read_episodes(tmp / "js", spec=js_spec), repeats)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {
        "custom_read_episodes": (t_arm, "s"),
        "jointstate_read_episodes": (t_js, "s"),
        "custom_over_jointstate_read": (t_arm / t_js, "x"),
    }


def run(quick: bool = False) -> Result:
    """Measure and print; returns name -> (value, unit)."""
    n, repeats = (5000, 3) if quick else (50_000, 5)
    results = bench_decode(n, repeats)
    results.update(bench_read(n // 5, repeats))
    for name, (value, unit) in results.items():
        print(f"{name:40s} {value:10.3f} {unit}")
    return results


def main(argv: list[str] | None = None) -> Any:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    run(parser.parse_args(argv).quick)


if __name__ == "__main__":
    main()
