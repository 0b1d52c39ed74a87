"""Benchmark: the reader's peak memory on a bag whose bulk is a topic the reader spec does not use.

A ``ros2 bag record -a`` bag holds cameras beside the few topics a demonstration needs.  The bag:
a 640x480 RGB ``sensor_msgs/Image`` on ``/camera/image_raw`` at 10 Hz (``--camera-mb`` of images)
beside the compatibility corpus' lab robot (``Float32MultiArray`` state and command at 25 Hz, 64
floats each, ``--wanted-mb`` of them), written with ``rosbags``.  A child process per case reads it
with ``read_episodes`` and reports its peak RSS (``VmHWM``) and the RSS after imports (the process
baseline):

* ``metadata``: the bag directory with its metadata.yaml (topics chosen before reading);
* ``bare_mcap`` / ``bare_sqlite3``: the storage file alone (a killed recorder, a file sent by mail):
  the topics are chosen from the storage file's own connections;
* ``no_camera``: the same wanted topics without the camera (the reader's own cost per wanted byte,
  the modules it loads while reading included).

Target: peak ≤ baseline + 1.5 × the wanted topics' bytes (``*_over_wanted`` ≤ 1.5, the part above
the baseline over the wanted bytes).

    .venv/bin/python bench/bench_unwanted.py [--quick]
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

MB = 1 << 20
STATE, CMD, CAMERA = "/lab/state", "/lab/cmd", "/camera/image_raw"
DIM = 64
SPEC: dict[str, Any] = {
    "observation": {"topic": STATE, "type": "std_msgs/msg/Float32MultiArray", "dim": DIM},
    "action": {"topic": CMD, "type": "std_msgs/msg/Float32MultiArray", "dim": DIM},
    "subtask": None, "sketch": None, "episode": None, "split": "gaps", "time_gap": 0.5,
}


def _status(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(field)


def _child(bag: str) -> dict[str, Any]:
    from ompn_ros.data import ReaderSpec, read_episodes

    spec = ReaderSpec.from_dict(SPEC)
    imports = _status("VmRSS")
    n = len(read_episodes(bag, spec=spec).episodes)
    return {"peak": _status("VmHWM"), "imports": imports, "episodes": n}


def _run_child(bag: Path) -> dict[str, Any]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, __file__, "--child", str(bag)], env=env, capture_output=True,
                          text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"bench_unwanted child failed:\n{proc.stderr[-2000:]}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def _make_bag(path: Path, storage: str, camera_mb: int, wanted_mb: int) -> int:
    """Write the bag; returns the bytes of the wanted topics' messages."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer

    from ompn_ros import layout
    from ompn_ros.data import messages as m

    rng = np.random.default_rng(0)
    image = m.msg_class("sensor_msgs/msg/Image")
    pixels = rng.integers(0, 255, 640 * 480 * 3, dtype=np.uint8)
    n_images = camera_mb * MB // pixels.size  # 0: no camera topic at all
    state = m.serialize(m.float32_array(rng.standard_normal(DIM).astype(np.float32), "s"))
    per_step = 2 * len(state)
    steps = wanted_mb * MB // per_step
    camera_every = max(1, steps // max(n_images, 1))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    wanted = 0
    with Writer(path, version=9, storage_plugin=plugin) as w:  # type: ignore[arg-type]
        conns = {t: w.add_connection(t, layout.FLOAT32_ARRAY, typestore=m.typestore()) for t in (STATE, CMD)}
        cam = w.add_connection(CAMERA, "sensor_msgs/msg/Image", typestore=m.typestore())
        for k in range(steps):
            t = 10**9 + k * 40_000_000 + (k // 200) * 2 * 10**9  # episodes of 200 steps, 2 s apart
            for topic, offset in ((STATE, 0), (CMD, 2_000_000)):
                if topic == CMD and k % 200 == 199:
                    continue  # the last state of an episode is its final observation
                raw = m.serialize(m.float32_array(rng.standard_normal(DIM).astype(np.float32), "v"))
                w.write(conns[topic], t + offset, raw)
                wanted += len(raw)
            if k % camera_every == 0 and k // camera_every < n_images:
                msg = image(header=m.header(t, "cam"), height=480, width=640, encoding="rgb8",
                            is_bigendian=0, step=640 * 3, data=pixels)
                w.write(cam, t + 1_000_000, m.serialize(msg))
    return wanted


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """Measure and print; returns name -> (value, unit)."""
    camera_mb, wanted_mb = (100, 10) if quick else (300, 30)
    tmp = Path(tempfile.mkdtemp(prefix="bench_unwanted_"))
    results: dict[str, tuple[float, str]] = {}
    try:
        plain = tmp / "no_camera"
        wanted = _make_bag(plain, "mcap", 0, wanted_mb)
        res = _run_child(plain)
        results["no_camera_mcap_peak_rss"] = (res["peak"] / MB, "MB")
        results["no_camera_mcap_over_wanted"] = ((res["peak"] - res["imports"]) / wanted, "x")
        for storage in ("mcap", "sqlite3"):
            bag = tmp / storage
            wanted = _make_bag(bag, storage, camera_mb, wanted_mb)
            (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
            bare = tmp / f"bare_{storage}"
            bare.mkdir()
            shutil.copy(file, bare / file.name)
            cases = {f"metadata_{storage}": bag, f"bare_{storage}": bare / file.name}
            results[f"{storage}_bag_size"] = (file.stat().st_size / MB, "MB")
            results[f"{storage}_wanted_bytes"] = (wanted / MB, "MB")
            for name, path in cases.items():
                res = _run_child(path)
                results[f"{name}_peak_rss"] = (res["peak"] / MB, "MB")
                results[f"{name}_baseline_rss"] = (res["imports"] / MB, "MB")
                results[f"{name}_over_wanted"] = ((res["peak"] - res["imports"]) / wanted, "x")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{'metric':<38}{'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<38}{value:>12.3f}  {unit}")
    return results


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        print(json.dumps(_child(sys.argv[2])))
        return 0
    run(quick="--quick" in sys.argv[1:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
