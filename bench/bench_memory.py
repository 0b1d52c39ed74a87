"""Benchmark: memory while reading bags into the episode cache, and training from the memory-mapped cache.

Data: three Craft bags of about the same size (quick ~50 MB each, full ~230 MB each), generated
with :func:`ompn_ros.app.collect.collect` (expert episodes, one run split into parts).

1. **Reading.**  Child processes report their peak RSS (``VmHWM``) on the first bag for: the bag
   reader alone (``read_episodes``), the in-memory path (``load_arrays(use_cache=False)``: parse +
   concatenate), building the cache (``load_arrays``: bags read one at a time, episodes appended to
   ``.npy`` files) and a cache hit that touches every episode (its pages are file-backed:
   ``hit_rss_anon`` is the process's own memory).  Figures: peak RSS in MB, as a ratio to the bag
   size, and the part above the RSS after imports (``*_over_imports_over_bag``; ``imports_rss`` is
   that baseline: Python, NumPy, rosbags and the package).  ``build_all_*``: building one cache from
   all three bags, whose peak is bounded by the largest bag, not the dataset.  ``reader_sqlite3_*``:
   the reader alone on a Craft bag of the same size in sqlite3 storage; ``reader_multi_*``: on a bag
   whose observation is assembled from several topics (``MULTI_SPEC``: joint states, gripper, wrist
   wrench at 100 Hz, with command and skill-id topics).
2. **Throughput.**  Frames/s of :func:`ompn_ros.train.trainer.train_step` (a small OMPN, batches of
   32 whole episodes cycling through the dataset, 1 thread) on episodes that are views into the
   memory-mapped cache of the first bag vs on an in-memory copy of the same arrays, the two
   interleaved step by step on the same batches.  The page cache is warm (the cache was just built).
3. **Memory limit.**  On the three-bag cache, a child builds the model, runs one warm-up step, then
   sets ``RLIMIT_DATA`` (private writable memory: heap and anonymous maps; read-only file maps are
   not counted) to its current ``VmData`` plus a quarter of the cache size, trains over every
   episode of the mapped cache (every page is read) and then tries to copy the cache into memory,
   which the limit must refuse.  In the full run the cache is larger than the whole limit
   (``limit_cache_over_limit`` > 1).  ``RLIMIT_AS`` cannot show this: a file map counts towards the
   address space, so mapping a cache bigger than the limit fails by design (the child tries and
   prints the error).  A cgroup ``memory.max`` is not used: it needs a cgroup v2 hierarchy the
   benchmark may write to.

    .venv/bin/python bench/bench_memory.py [--quick]
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

MB = 1 << 20
EPISODE_BYTES = 104_000  # a Craft expert episode in an mcap bag, about (to size the bags)
TASKS = ["makebed", "makeaxe", "makeshears"]


def _status(field: str) -> int:
    """A ``/proc/self/status`` figure in bytes (``VmHWM``, ``VmRSS``, ``RssAnon``, ``VmData``, ...)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(field)


def _dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


# ----------------------------------------------------------------------------------------- children
MULTI_JOINTS = [f"joint_{i}" for i in range(7)]
MULTI_SPEC: dict[str, Any] = {  # a lab's arm: joint states + gripper + wrist wrench, 100 Hz
    "assemble": {
        "step_topic": "/arm/joint_states", "tolerance_s": 0.03, "stamp": "receive",
        "fields": [
            {"topic": "/arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "position"},
            {"topic": "/arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "velocity"},
            {"topic": "/arm/joint_states", "type": "sensor_msgs/msg/JointState", "field": "effort"},
            {"topic": "/arm/gripper", "type": "std_msgs/msg/Float32MultiArray", "field": "data", "size": 2},
            {"topic": "/arm/ft", "type": "geometry_msgs/msg/WrenchStamped", "field": "wrench"},
        ],
    },
    "action": {"topic": "/arm/command", "type": "std_msgs/msg/Float32MultiArray", "dim": 7},
    "subtask": "/task/skill", "labels": "id", "sketch": None, "episode": None,
    "split": "gaps", "time_gap": 0.5, "tolerance": 0.03, "task": "lab", "strict": False,
}


def _spec(kind: str) -> Any:
    from ompn_ros.data import ReaderSpec

    return ReaderSpec.from_dict(MULTI_SPEC) if kind == "multi" else ReaderSpec.for_domain("craft")


def _child_read(mode: str, bag: str, cache_dir: str, kind: str = "craft") -> dict[str, Any]:
    from ompn_ros.data import load_arrays, read_episodes

    spec = _spec(kind)
    imports = _status("VmRSS")
    if mode == "reader":
        n = len(read_episodes(bag, spec=spec).episodes)
    elif mode == "memory":
        n = len(load_arrays(bag, spec=spec, use_cache=False))
    else:  # "build" (a miss) or "hit" (which then reads every episode's rows)
        arrays = load_arrays(bag, spec=spec, cache_dir=cache_dir)
        assert arrays.cache_hit == (mode == "hit"), mode
        n = len(arrays)
        if mode == "hit":  # every page of the observations is read (file-backed, reclaimable)
            checksum = sum(float(e.observations.sum()) for e in arrays.episodes())
            assert checksum > 0, "a cache of Craft observations holds ones"
    return {"peak": _status("VmHWM"), "imports": imports, "anon": _status("RssAnon"), "episodes": n}


def _train_setup(entry: str) -> tuple[Any, Any, Any, Any, Any]:
    import torch

    from ompn_ros import layout
    from ompn_ros.data.cache import EpisodeArrays
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.model.policy import OMPNPolicy
    from ompn_ros.train.config import TrainConfig

    torch.set_num_threads(1)
    torch.manual_seed(0)
    arrays = EpisodeArrays.load(Path(entry))
    config = OMPNConfig(obs_dim=layout.CRAFT.obs_dim, action_type="discrete",
                        action_dim=layout.CRAFT.action_dim, n_slots=3, slot_size=32)
    cfg = TrainConfig(lr=1e-3, batch_size=32, progress=False, threads=1)
    policy = OMPNPolicy(config)
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    return arrays, config, cfg, policy, optimizer


def _child_throughput(entry: str, iterations: int) -> dict[str, Any]:
    """Frames/s per variant, the variants interleaved step by step (alternating which goes first),
    so a change in the machine's load hits both alike."""
    from ompn_ros.data.cache import EpisodeArrays
    from ompn_ros.train.trainer import train_step

    arrays, config, cfg, policy, optimizer = _train_setup(entry)
    mapped = arrays.episodes()
    variants = {"mmap": mapped, "memory": EpisodeArrays.from_episodes(mapped).episodes()}
    n = len(mapped)
    train_step(policy, optimizer, variants["memory"][: cfg.batch_size], config, cfg)  # warm-up
    seconds = {k: 0.0 for k in variants}
    frames = {k: 0 for k in variants}
    for i in range(iterations):
        b = (i * cfg.batch_size) % n
        for name in (("mmap", "memory") if i % 2 == 0 else ("memory", "mmap")):
            start = time.perf_counter()
            stats = train_step(policy, optimizer, variants[name][b: b + cfg.batch_size], config, cfg)
            seconds[name] += time.perf_counter() - start
            frames[name] += int(stats["global_valid"])
    return {k: frames[k] / seconds[k] for k in variants}


def _child_limit(entry: str) -> dict[str, Any]:
    from ompn_ros.data.cache import EpisodeArrays
    from ompn_ros.train.trainer import train_step

    arrays, config, cfg, policy, optimizer = _train_setup(entry)
    episodes = arrays.episodes()
    cache = _dir_bytes(Path(entry))
    train_step(policy, optimizer, episodes[: cfg.batch_size], config, cfg)  # allocator pools, threads
    headroom = cache // 4
    limit = _status("VmData") + headroom
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    out: dict[str, Any] = {"cache": cache, "limit": limit, "headroom": headroom}
    frames = 0
    anon_peak = 0
    try:
        for b in range(0, len(episodes), cfg.batch_size):
            stats = train_step(policy, optimizer, episodes[b: b + cfg.batch_size], config, cfg)
            frames += int(stats["global_valid"])
            anon_peak = max(anon_peak, _status("RssAnon"))
        out["trained_frames"] = frames
    except (MemoryError, RuntimeError) as err:  # torch reports a refused allocation as RuntimeError
        out["train_error"] = f"training under the limit failed: {type(err).__name__} {str(err)[:100]}"
    out.update(rss_anon_peak=anon_peak, rss_file=_status("RssFile"), peak_rss=_status("VmHWM"))
    try:
        copy = EpisodeArrays.from_episodes(episodes)
        out["copy"] = f"succeeded ({copy.observations.nbytes // MB} MB): the limit is not binding"
    except MemoryError as err:
        out["copy"] = f"refused: MemoryError ({str(err)[:80]})"
    return out


def _child_limit_as(entry: str) -> dict[str, Any]:
    from ompn_ros.data.cache import EpisodeArrays

    cache = _dir_bytes(Path(entry))
    limit = _status("VmSize") + cache // 2
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    try:
        arrays = EpisodeArrays.load(Path(entry))
        return {"rlimit_as": f"mapped {len(arrays)} episodes under RLIMIT_AS"}
    except (MemoryError, OSError, ValueError) as err:
        return {"rlimit_as": f"{type(err).__name__}: {str(err)[:100]}"}


_CHILDREN: dict[str, Callable[..., dict[str, Any]]] = {
    "read": _child_read, "throughput": _child_throughput, "limit": _child_limit, "limit_as": _child_limit_as,
}


def _run_child(name: str, *args: Any) -> dict[str, Any]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, __file__, "--child", json.dumps([name, *args])], env=env,
                          capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"bench_memory child '{name}' failed:\n{proc.stderr[-2000:]}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


# ------------------------------------------------------------------------------------------- parent
def _make_bags(out: Path, megabytes: int, parts: int, storage: str = "mcap") -> list[Path]:
    """``parts`` Craft bags of about ``megabytes`` each (one ``collect`` run split into parts)."""
    from ompn_ros.app.collect import collect

    per_part = max(10, megabytes * MB // EPISODE_BYTES)
    collect(out, domain="craft", tasks=TASKS, episodes=parts * per_part, seed=0, split_every=per_part,
            progress=False, command=["bench_memory"], storage=storage)
    return sorted(out.glob("part_*"))


def _make_multi_topic_bag(path: Path, megabytes: int) -> Path:
    """A bag of about ``megabytes`` from several topics per 10 ms step (``MULTI_SPEC``): joint states
    (7 joints), gripper, wrist wrench, command and skill id; episodes of 200 steps, 1 s apart."""
    import numpy as np
    from rosbags.rosbag2 import Writer

    from ompn_ros.data import messages as m
    from ompn_ros.data.recorder.bag_writer import storage_plugin

    rng = np.random.default_rng(0)
    v3 = m.msg_class("geometry_msgs/msg/Vector3")
    types = {"/arm/gripper": "std_msgs/msg/Float32MultiArray", "/arm/ft": "geometry_msgs/msg/WrenchStamped",
             "/arm/joint_states": "sensor_msgs/msg/JointState", "/task/skill": "std_msgs/msg/Int32",
             "/arm/command": "std_msgs/msg/Float32MultiArray"}
    steps = megabytes * MB // 610  # bytes of one step's five messages in an mcap file, about
    with Writer(path, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conn = {t: w.add_connection(t, ty, typestore=m.typestore()) for t, ty in types.items()}
        for k in range(steps):
            ep, i = divmod(k, 200)
            t = 10**9 + ep * (200 * 10**7 + 10**9) + i * 10**7
            q = rng.standard_normal((4, 7))
            w.write(conn["/arm/gripper"], t - 3_000_000, m.encode_float32_array(rng.random(2), "grip"))
            wrench = m.msg_class("geometry_msgs/msg/Wrench")(force=v3(*q[3, :3]), torque=v3(*q[3, 3:6]))
            stamped = m.msg_class("geometry_msgs/msg/WrenchStamped")(header=m.header(t - 2_000_000, "ft"),
                                                                     wrench=wrench)
            w.write(conn["/arm/ft"], t - 2_000_000, m.serialize(stamped))
            w.write(conn["/arm/joint_states"], t, m.serialize(m.joint_state(t, MULTI_JOINTS, *q[:3])))
            if i < 199:  # the last joint state of an episode is its final observation
                w.write(conn["/task/skill"], t + 1_000_000, m.encode_int32(i // 50))
                w.write(conn["/arm/command"], t + 2_000_000, m.encode_float32_array(q[0] * 0.1, "cmd"))
    return path


def _reader_kinds(tmp: Path, megabytes: int) -> dict[str, tuple[float, str]]:
    """The reader's peak RSS on a Craft sqlite3 bag and on a bag of several observation topics."""
    results: dict[str, tuple[float, str]] = {}
    bags = {"sqlite3": (_make_bags(tmp / "bags_sqlite3", megabytes, 1, "sqlite3")[0], "craft"),
            "multi": (_make_multi_topic_bag(tmp / "bag_multi", megabytes), "multi")}
    for name, (bag, kind) in bags.items():
        size = _dir_bytes(bag)
        res = _run_child("read", "reader", str(bag), str(tmp / "unused"), kind)
        results[f"reader_{name}_bag_size"] = (size / MB, "MB")
        results[f"reader_{name}_episodes"] = (float(res["episodes"]), "episodes")
        results[f"reader_{name}_peak_over_bag"] = (res["peak"] / size, "x")
        results[f"reader_{name}_over_imports_over_bag"] = ((res["peak"] - res["imports"]) / size, "x")
    return results


def _reading(bags: list[Path], tmp: Path) -> dict[str, tuple[float, str]]:
    """Peak RSS of the read paths on one bag, and of building a cache from all of them."""
    size = _dir_bytes(bags[0])
    largest = max(_dir_bytes(b) for b in bags)
    results: dict[str, tuple[float, str]] = {"bag_size": (size / MB, "MB")}
    results["imports_rss"] = (0.0, "MB")
    for mode in ("reader", "memory", "build", "hit"):
        res = _run_child("read", mode, str(bags[0]), str(tmp / "cache1"))
        results["imports_rss"] = (res["imports"] / MB, "MB")
        results[f"{mode}_peak_rss"] = (res["peak"] / MB, "MB")
        results[f"{mode}_peak_over_bag"] = (res["peak"] / size, "x")
        results[f"{mode}_over_imports_over_bag"] = ((res["peak"] - res["imports"]) / size, "x")
    results["hit_rss_anon"] = (res["anon"] / MB, "MB")
    res = _run_child("read", "build", str(bags[0].parent), str(tmp / "cache_all"))
    results["build_all_bags"] = (float(len(bags)), "bags")
    results["build_all_dataset_size"] = (sum(_dir_bytes(b) for b in bags) / MB, "MB")
    results["build_all_peak_rss"] = (res["peak"] / MB, "MB")
    results["build_all_peak_over_largest_bag"] = (res["peak"] / largest, "x")
    return results


def _limits(entry: Path) -> tuple[dict[str, tuple[float, str]], list[str]]:
    lim = _run_child("limit", str(entry))
    results = {
        "limit_cache_size": (lim["cache"] / MB, "MB"),
        "limit_rlimit_data": (lim["limit"] / MB, "MB"),
        "limit_rlimit_data_headroom": (lim["headroom"] / MB, "MB"),
        "limit_cache_over_limit": (lim["cache"] / lim["limit"], "x"),
        "limit_trained_frames": (float(lim.get("trained_frames", 0)), "frames"),
        "limit_rss_anon_peak": (lim["rss_anon_peak"] / MB, "MB"),
        "limit_peak_rss": (lim["peak_rss"] / MB, "MB"),
    }
    notes = [f"in-memory copy of the cache under RLIMIT_DATA: {lim['copy']}", lim.get("train_error", ""),
             "RLIMIT_AS = VmSize + half the cache, mapping the cache: "
             + _run_child("limit_as", str(entry))["rlimit_as"]]
    return results, notes


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """Measure and print; returns name -> (value, unit)."""
    megabytes, iterations = (50, 24) if quick else (230, 80)
    tmp = Path(tempfile.mkdtemp(prefix="bench_memory_"))
    try:
        bags = _make_bags(tmp / "bags", megabytes, parts=3)
        results = _reading(bags, tmp)
        results.update(_reader_kinds(tmp, megabytes))
        entry = next((tmp / "cache1").glob("episodes_*"))
        results["cache_size"] = (_dir_bytes(entry) / MB, "MB")
        fps = _run_child("throughput", str(entry), iterations)
        results["train_mmap_frames_per_s"] = (fps["mmap"], "frames/s")
        results["train_memory_frames_per_s"] = (fps["memory"], "frames/s")
        results["train_mmap_over_memory"] = (fps["mmap"] / fps["memory"], "x")
        limit_results, notes = _limits(next((tmp / "cache_all").glob("episodes_*")))
        results.update(limit_results)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{'metric':<38}{'value':>12}  unit")
    for name, (value, unit) in results.items():
        print(f"{name:<38}{value:>12.3f}  {unit}")
    for note in notes:
        if note:
            print(note)
    return results


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        name, *args = json.loads(sys.argv[2])
        print(json.dumps(_CHILDREN[name](*args)))
        return 0
    run(quick="--quick" in sys.argv[1:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
