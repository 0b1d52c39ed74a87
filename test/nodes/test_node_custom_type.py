"""ompn_node runs on a lab's own message type live, equal to the offline replay of the same messages
written to a bag; a type that is not installed is one line naming its package.

The lab's package ``my_robot_msgs`` is built from its ``.msg`` files in the test, as ``ompn_interfaces``
is built (test/custom_interfaces.py; once per session, about a minute).  A driver process publishes
``my_robot_msgs/msg/ArmState`` on ``/arm1/state`` and keeps the CDR of every message it published; the
node assembles ``positions`` and ``gripper.width`` into its observation.  The same bytes, written to a
rosbag2 bag with the type's definition, are read back by the bag reader with the same spec and
replayed through a StreamingSegmenter: the node's ``~/pi`` must equal it.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
rclpy = pytest.importorskip("rclpy")

import custom_interfaces as ci  # noqa: E402
import type_corpus as tc  # noqa: E402
from node_process import NodeProcess, Peer, node_command  # noqa: E402
from random_checkpoint import random_checkpoint  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from ompn_ros.data import ReaderSpec, read_episodes  # noqa: E402
from ompn_ros.data.messages import parse_float32_array  # noqa: E402
from ompn_ros.detect.online import DetectorConfig  # noqa: E402
from ompn_ros.model.load import stepper_from_checkpoint  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402

torch.set_num_threads(1)
STEPS = 120
TOPIC = "/arm1/state"
SPEC_TEXT = (
    "{step_topic: /arm1/state, stamp: receive, fields: ["
    "{topic: /arm1/state, type: my_robot_msgs/msg/ArmState, field: positions},"
    "{topic: /arm1/state, type: my_robot_msgs/msg/ArmState, field: gripper.width}]}"
)
OBS_DIM = 4
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

DRIVER = textwrap.dedent(f"""
    import struct, sys, time
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from my_robot_msgs.msg import ArmState

    rclpy.init()
    node = rclpy.create_node("arm_driver", namespace="arm1")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(ArmState, "state", qos)
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    with open(sys.argv[1], "wb") as out:
        for k in range({STEPS}):
            msg = ArmState()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.header.frame_id = "base_link"
            msg.joint_names = ["shoulder", "elbow", "wrist"]
            msg.positions = [0.01 * k, -0.02 * k, 0.5 + 0.001 * k * k]
            msg.velocities = [0.1, 0.2, 0.3]
            msg.gripper.width = 0.08 - 0.0005 * k
            msg.gripper.force = 1.5
            msg.gripper.grasped = k > 60
            raw = serialize_message(msg)
            out.write(struct.pack("<qI", time.time_ns(), len(raw)) + raw)
            pub.publish(msg)
            time.sleep(0.01)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.fixture(scope="session")
def lab_package(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``my_robot_msgs`` built and installed into a prefix (once per session)."""
    if shutil.which("cmake") is None:
        pytest.skip("needs cmake and a C/C++ compiler")
    from ompn_ros.ros import containment

    env = dict(os.environ)
    containment.contain(env)
    return ci.build(tmp_path_factory.mktemp("my_robot_msgs"), env)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_checkpoint(
        tmp_path_factory,
        "customtype",
        seed=9,
        obs_dim=OBS_DIM,
        action_type="discrete",
        action_dim=3,
        n_slots=3,
        slot_size=16,
    )


def _published(path: Path) -> list[tuple[int, bytes]]:
    data, out, pos = path.read_bytes(), [], 0
    while pos < len(data):
        stamp, size = struct.unpack_from("<qI", data, pos)
        out.append((stamp, data[pos + 12 : pos + 12 + size]))
        pos += 12 + size
    return out


def _replay(ckpt: Path, published: list[tuple[int, bytes]], bag: Path) -> np.ndarray:
    """The published bytes as a rosbag2 bag (definition embedded), read with the node's spec, replayed."""
    from rosbags.rosbag2 import Writer

    store = tc.lab_typestore()
    with Writer(bag, version=9) as writer:
        conn = writer.add_connection(TOPIC, tc.ARM_STATE, typestore=store)
        for stamp, raw in published:
            writer.write(conn, stamp, raw)
    tc.forget_lab_types()  # the reader learns the type from the bag
    spec = ReaderSpec.from_dict(
        {
            "assemble": {
                "step_topic": TOPIC,
                "stamp": "receive",
                "tolerance_s": 1.0,
                "fields": [
                    {"topic": TOPIC, "type": tc.ARM_STATE, "field": "positions"},
                    {"topic": TOPIC, "type": tc.ARM_STATE, "field": "gripper.width"},
                ],
            },
            "action": {"topic": TOPIC, "type": tc.ARM_STATE, "field": "velocities"},
            "subtask": None,
            "sketch": None,
            "episode": None,
            "split": "gaps",
            "time_gap": 5.0,
        }
    )
    (episode,) = read_episodes(bag, spec=spec).episodes
    seg = StreamingSegmenter(stepper_from_checkpoint(ckpt), DetectorConfig())
    rows = []
    for x in episode.observations[: len(published)]:
        so = seg.step(x).step_output
        rows.append(np.concatenate([so.pi, [so.expected_position, so.pi_end]]).astype(np.float32))
    return np.stack(rows)


def test_custom_type_live_equals_replay(
    lab_package: Path, ckpt: Path, ros_env: dict[str, str], tmp_path: Path
) -> None:
    env = ci.environment(lab_package, ros_env)
    ns = f"/custom_{os.getpid()}"
    spec_file = tmp_path / "arm.yaml"
    spec_file.write_text(f"observation: {SPEC_TEXT}\n")
    node_proc = NodeProcess(env, f"checkpoint:={ckpt}", f"observation_spec:={spec_file}", "qos_depth:=1000",
                            "diagnostics_period:=0.1", "max_stamp_lead:=0.0", ns=ns)  # fmt: skip
    driver: NodeProcess | None = None
    pis: list[np.ndarray] = []
    peer = Peer(node_proc, name="observer")
    try:
        peer.node.create_subscription(
            Float32MultiArray,
            node_proc.topic("ompn_node/pi"),
            lambda raw: pis.append(np.asarray(parse_float32_array(raw))),
            RELIABLE,
            raw=True,
        )
        peer.wait_active(node_proc, 90)
        driver = NodeProcess(env, program=[sys.executable, "-c", DRIVER, str(tmp_path / "published.bin")])
        assert peer.pump(lambda: driver is not None and not driver.running(), 120), (
            "the driver did not finish"
        )
        peer.pump(lambda: len(pis) >= STEPS, 10)
    finally:
        peer.close()
        driver_out = driver.stop() if driver is not None else ""
        node_out = node_proc.stop()
    assert driver is not None and driver.returncode == 0, driver_out
    assert node_proc.returncode == 0, node_out
    assert "Traceback" not in node_out and "FATAL" not in node_out
    published = _published(tmp_path / "published.bin")
    assert len(published) == STEPS == len(pis), (len(published), len(pis))
    np.testing.assert_allclose(
        np.stack(pis), _replay(ckpt, published, tmp_path / "bag"), rtol=1e-5, atol=1e-6
    )


def test_a_type_not_installed_is_one_line_naming_its_package(
    ckpt: Path, ros_env: dict[str, str], tmp_path: Path
) -> None:
    spec_file = tmp_path / "arm.yaml"
    spec_file.write_text(
        "observation: {step_topic: /arm/state, fields: [{topic: /arm/state, type: "
        "acme_arm_msgs/msg/ArmState, field: positions}]}\n"
    )
    done = subprocess.run(
        node_command(f"checkpoint:={ckpt}", f"observation_spec:={spec_file}"),
        env=ros_env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    problems = [x for x in (done.stdout + done.stderr).splitlines() if "[INFO]" not in x]
    assert len(problems) == 1, problems
    assert "acme_arm_msgs/msg/ArmState is not installed" in problems[0], problems
    assert "install its package 'acme_arm_msgs'" in problems[0], problems
