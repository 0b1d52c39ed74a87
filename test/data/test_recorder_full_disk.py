"""bag_recorder on a disk that fills up (a small tmpfs): one error line naming the bag and the free
space, the bag closed properly (metadata.yaml, mcap footer / sqlite3 COMMIT), exit status 2, and
what was written opens without skip_tail.  Too little space at start is refused in one line."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from small_disk import small_disk  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _record(bag: Path, storage: str, topic: str, env: dict[str, str], extra: list[str]) -> subprocess.Popen:
    env = {**env, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "ompn_ros.nodes.bag_recorder", topic, "-o", str(bag), "-s", storage,
           "--ros-args", "-p", "commit_period:=0.1", *extra]  # fmt: skip
    return subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)  # fmt: skip


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_full_disk_stops_the_recording_and_closes_the_bag(
    tmp_path: Path, ros_env: dict[str, str], storage: str
) -> None:
    topic = f"/full_{os.getpid()}_{storage}/observation"
    with small_disk(tmp_path / "disk", 8 * 1024, free_kb=4 * 1024) as disk:
        bag = disk / "bag"
        proc = _record(bag, storage, topic, ros_env, ["-p", "min_free_mb:=0.5"])
        ctx = rclpy.context.Context()
        rclpy.init(context=ctx)
        try:
            node = rclpy.create_node("filler", context=ctx)
            pub = node.create_publisher(Float32MultiArray, topic, QoSProfile(depth=50,
                                        reliability=ReliabilityPolicy.RELIABLE))  # fmt: skip
            data = [float(i) for i in range(20_000)]  # 80 kB a message: the disk fills in ~50
            deadline = time.monotonic() + 60
            while proc.poll() is None and time.monotonic() < deadline:
                if pub.get_subscription_count() > 0:
                    pub.publish(Float32MultiArray(data=data))
                time.sleep(0.01)
        finally:
            rclpy.try_shutdown(context=ctx)
            if proc.poll() is None:
                proc.kill()
            out, _ = proc.communicate(timeout=20)
        assert proc.returncode == 2, out
        assert "Traceback" not in out, out
        errors = [line for line in out.splitlines() if "stopped recording" in line]
        assert len(errors) == 1 and str(bag) in errors[0] and "MB free" in errors[0], out
        assert (bag / "metadata.yaml").is_file() and not [p for p in disk.iterdir() if p.name.startswith(".")]
        with AnyReader([bag]) as reader:  # no skip_tail: the bag was closed properly
            count = sum(1 for _ in reader.messages())
        assert count > 0, out


def test_too_little_space_at_start_is_one_line(tmp_path: Path, ros_env: dict[str, str]) -> None:
    with small_disk(tmp_path / "disk", 1024) as disk:
        proc = _record(disk / "bag", "mcap", "/nothing", ros_env, [])  # needs 64 MB
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "Traceback" not in out, out
        assert "min_free_mb" in out and str(disk / "bag") in out and not (disk / "bag").exists(), out


def test_low_space_is_warned_once_and_the_reserve_is_released(tmp_path: Path) -> None:
    from ompn_ros.data.recorder.disk_guard import DiskGuard

    with small_disk(tmp_path / "disk", 1024) as disk:
        guard = DiskGuard(disk / "bag", min_free_bytes=400_000, reserve_bytes=200_000)
        guard.start()
        assert guard.reserve is not None and guard.reserve.stat().st_size == 200_000
        assert guard.low() is None
        (disk / "data").write_bytes(b"\0" * 500_000)  # the recording grows
        line = guard.low()
        assert line is not None and "running low" in line and str(disk / "bag") in line
        assert guard.low() is None  # once
        guard.release()
        assert not [p for p in disk.iterdir() if p.name.startswith(".")]
