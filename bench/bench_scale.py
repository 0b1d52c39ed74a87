"""Benchmark of the whole-dataset paths: batch segmentation, the per-bag cache, multi-node training
and the training cost per 1 000 episodes.

* ``ompn_segment --bags DIR --jobs 1`` against ``--jobs 2`` on generated bags (one expert episode
  per bag, Craft and Dial, the shipped checkpoints): episodes/s, MB/s of bags, the scaling ratio;
* the training cache from 50 of the Dial bags: one entry read serially (``load_arrays``) against
  per-bag entries over 2 processes (``data.cache_workers: 2``), then again after adding 10 bags;
* ``torchrun``: frames/s of 1 node x 2 processes against 2 "nodes" x 1 process on this machine
  (rendezvous on 127.0.0.1, the same synthetic run);
* ``ompn_train`` on the generated Craft and Dial episodes with 1 and 2 processes: wall time per
  1 000 training episodes (iterations x batch size) and the peak resident memory of a process.

    nice .venv/bin/python bench/bench_scale.py [--bags 100] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data import ReaderSpec, load_arrays, write_episodes
from sim_nodes.registry import default_tasks, expert_episode

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo", PYTHONPATH=f"{ROOT}{os.pathsep}"
               f"{env.get('PYTHONPATH', '')}")
    return env


def make_bags(root: Path, domain: str, count: int, first_seed: int = 50_000, per_bag: int = 1) -> Path:
    """``count`` bags of ``per_bag`` expert episodes each (Craft: the paper's tasks in turn)."""
    tasks = default_tasks(domain)
    for i in range(count):
        seeds = range(first_seed + i * per_bag, first_seed + (i + 1) * per_bag)
        episodes = [expert_episode(domain, seed, task=tasks[seed % len(tasks)]) for seed in seeds]
        write_episodes(root / domain / f"bag{i:04d}", episodes, domain)
    return root / domain


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def segment(bags: Path, domain: str, jobs: int, out: Path) -> dict[str, float]:
    command = [sys.executable, "-m", "ompn_ros.cli.segment", "--bags", str(bags), "--jobs", str(jobs),
               "--checkpoint", str(shipped_checkpoint(domain)), "--domain", domain, "--out", str(out)]
    start = time.perf_counter()
    proc = subprocess.run(command, env=_env(), cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    summary = json.loads((out / "summary.json").read_text())
    episodes = summary["this_run"]["episodes"]
    return {"wall_s": wall, "episodes": episodes, "episodes_per_s": episodes / wall,
            "mb_per_s": _size(bags) / 1e6 / wall, "segments": summary["segments"]}


def cache(bags: Path, extra: Path, tmp: Path) -> dict[str, float]:
    spec = ReaderSpec.for_domain("dial")
    base = sorted(bags.iterdir())[:50]
    start = time.perf_counter()
    load_arrays(base, spec=spec, cache_dir=tmp / "serial")
    serial = time.perf_counter() - start
    start = time.perf_counter()
    load_arrays(base, spec=spec, cache_dir=tmp / "perbag", workers=2)
    parallel = time.perf_counter() - start
    start = time.perf_counter()
    load_arrays(base + sorted(extra.iterdir()), spec=spec, cache_dir=tmp / "perbag", workers=2)
    incremental = time.perf_counter() - start
    return {"bags": len(base), "serial_s": serial, "workers2_s": parallel,
            "added": len(list(extra.iterdir())), "incremental_s": incremental}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _train_args(bags: Path | None, domain: str, iterations: int, batch: int, out: Path) -> list[str]:
    config = str(ROOT / "config" / f"train_{domain}.yaml")
    synthetic = ["--synthetic", "discrete", "--episodes", "256"]
    source = ["--bags", str(bags), "--config", config] if bags else synthetic
    settings = {"iterations": iterations, "eval_every": iterations, "batch_size": batch, "patience": 0,
                "threads": 1, "device": "cpu", "restart_at": 0, "candidates": 1, "candidates_no_final": 1,
                "val_ratio": 0.1}
    sets = [item for key, value in settings.items() for item in ("--set", f"train.{key}={value}")]
    return ["-m", "ompn_ros.cli.train", *source, "--out", str(out), "--quiet", *sets]


_PEAK = ("import resource, subprocess, sys\n"
         "code = subprocess.run(sys.argv[1:]).returncode\n"
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)\n"
         "sys.exit(code)")


def _run(commands: list[list[str]]) -> tuple[float, float]:
    """Run ``commands`` side by side; (wall seconds, the peak resident MB of any of their processes)."""
    start = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", _PEAK, *c], env=_env(), cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for c in commands]
    peak = 0.0
    for proc in procs:
        _, err = proc.communicate()
        if proc.returncode != 0:
            said = [line for line in err.splitlines() if "error:" in line]
            raise RuntimeError(said[0] if said else err[-2000:])
        peak = max(peak, int(err.strip().splitlines()[-1]) / 1024)
    return time.perf_counter() - start, peak


def multinode(tmp: Path, iterations: int) -> dict[str, float]:
    run = [sys.executable, "-m", "torch.distributed.run"]
    one = tmp / "one_node"
    _run([[*run, "--standalone", "--nproc_per_node=2", *_train_args(None, "craft", iterations, 32, one)]])
    port, two = _free_port(), tmp / "two_nodes"
    _run([[*run, "--nnodes=2", f"--node_rank={rank}", "--nproc_per_node=1", "--master_addr=127.0.0.1",
           f"--master_port={port}", *_train_args(None, "craft", iterations, 32, two)] for rank in (0, 1)])
    out = {}
    for name, path in (("1x2", one), ("2x1", two)):
        summary = json.loads((path / "summary.json").read_text())
        out[f"{name}_frames_per_s"] = summary["frames"] / summary["train_seconds"]
    return out


def training_cost(bags: Path, domain: str, iterations: int, batch: int, tmp: Path) -> dict[str, float]:
    """Seconds per 1 000 training episodes from the difference of a run of ``3 x iterations`` and one of
    ``iterations`` (the evaluation and detector fitting at the end cancel out), peak memory of the longer."""
    out = {}
    for procs in (1, 2):
        torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone",
                    f"--nproc_per_node={procs}"]
        run = [sys.executable] if procs == 1 else torchrun
        seconds = []
        for length in (iterations, 3 * iterations):
            target = tmp / f"train_{domain}_{procs}_{length}"
            _, peak = _run([[*run, *_train_args(bags, domain, length, batch, target)]])
            seconds.append(json.loads((target / "summary.json").read_text())["train_seconds"])
        out[f"{procs}proc_s_per_1000_episodes"] = (seconds[1] - seconds[0]) / (2 * iterations * batch) * 1000
        out[f"{procs}proc_peak_mb"] = peak
    return out


def measure(count: int, iterations: int, parts: set[str], per_bag: int = 1) -> dict[str, dict[str, float]]:
    """Generate ``count`` bags of ``per_bag`` episodes per domain in a temporary folder; measure ``parts``."""
    tmp = Path(tempfile.mkdtemp(prefix="bench_scale_"))
    os.environ["OMPN_CACHE_DIR"] = str(tmp / "cache")
    results: dict[str, dict[str, float]] = {}
    try:
        bags = {d: make_bags(tmp / "bags", d, count, per_bag=per_bag) for d in ("craft", "dial")}
        for domain in ("craft", "dial") if "segment" in parts else ():
            for jobs in (1, 2):
                name = f"segment_{domain}_jobs{jobs}"
                results[name] = segment(bags[domain], domain, jobs, tmp / name)
                print(name, results[name], flush=True)
        if "cache" in parts:
            extra = make_bags(tmp / "extra", "dial", 10, first_seed=90_000)
            results["cache_dial"] = cache(bags["dial"], extra, tmp)
            print(results["cache_dial"], flush=True)
        if "multinode" in parts:
            results["multinode"] = multinode(tmp, iterations)
            print(results["multinode"], flush=True)
        for domain, batch in (("craft", 64), ("dial", 32)) if "train" in parts else ():
            try:
                results[f"train_{domain}"] = training_cost(bags[domain], domain, iterations, batch, tmp)
            except RuntimeError as exc:  # one failed measurement does not lose the others
                results[f"train_{domain}"] = {"error": str(exc)}  # type: ignore[dict-item]
            print(domain, results[f"train_{domain}"], flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return results


def run(quick: bool = False) -> dict[str, tuple[float, str]]:
    """``bench/run_all.py`` entry (on request: ``--only scale``): the figures, flat."""
    results = measure(10 if quick else 100, 2 if quick else 6, {"segment", "cache", "multinode", "train"})
    return {f"{group}.{name}": (value, "") for group, figures in results.items()
            for name, value in figures.items() if isinstance(value, int | float)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bags", type=int, default=100, help="generated bags per domain")
    parser.add_argument("--per-bag", type=int, default=1, help="expert episodes per generated bag")
    parser.add_argument("--iterations", type=int, default=6, help="training iterations per measurement")
    parser.add_argument("--only", default="segment,cache,multinode,train", help="which parts to run")
    parser.add_argument("--out", type=Path, default=None, help="JSON results file (none: print only)")
    args = parser.parse_args()
    results = measure(args.bags, args.iterations, set(args.only.split(",")), args.per_bag)
    text = json.dumps(results, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
