"""``torchrun --nnodes=2``: two "nodes" (two torchrun invocations on this machine, rendezvous on
127.0.0.1) train exactly as one node with two processes, and as one process within float tolerance."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from batch_bags import SPEC, write_lab_bag

from ompn_ros.app import training
from ompn_ros.app.errors import TrainSetupError
from ompn_ros.app.read_report import write_read_report
from ompn_ros.data import ReaderSpec
from ompn_ros.data.cache import load_arrays
from ompn_ros.train.distributed import DistContext

ROOT = Path(__file__).resolve().parents[2]
TRAIN = ["-m", "ompn_ros.cli.train", "--quiet", "--set", "model.n_slots=2", "--set", "model.slot_size=16",
         "--set", "train.iterations=6", "--set", "train.eval_every=3", "--set", "train.batch_size=8",
         "--set", "train.lr=0.003", "--set", "train.val_ratio=0.25", "--set", "train.threads=1",
         "--set", "train.device=cpu", "--set", "data.domain=custom"]


def _env(cache: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo", MASTER_ADDR="127.0.0.1",
               OMPN_CACHE_DIR=str(cache), PYTHONPATH=f"{ROOT}{os.pathsep}{env.get('PYTHONPATH', '')}")
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _log(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


@pytest.mark.slow  # three training runs (about a minute): make test-slow; make test keeps the 2-process one
def test_two_nodes_train_as_one_node_with_two_processes(tmp_path: Path) -> None:
    """Another lab's bags, read once into the shared cache by rank 0; every rank trains its shards."""
    for i in range(6):
        write_lab_bag(tmp_path / "bags" / f"day{i}", 30 + i)
    (tmp_path / "reader.yaml").write_text(yaml.safe_dump(SPEC))
    data = ["--bags", str(tmp_path / "bags"), "--set", f"data.reader_spec={tmp_path / 'reader.yaml'}"]
    env, port = _env(tmp_path / "cache"), _free_port()
    run = [sys.executable, "-m", "torch.distributed.run"]
    nodes = [subprocess.Popen(
        [*run, "--nnodes=2", f"--node_rank={rank}", "--nproc_per_node=1", "--master_addr=127.0.0.1",
         f"--master_port={port}", *TRAIN, *data, "--out", str(tmp_path / "two_nodes")],
        env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for rank in (0, 1)]
    results = [node.communicate(timeout=300) for node in nodes]
    for node, (_, err) in zip(nodes, results, strict=True):
        assert node.returncode == 0, err[-3000:]
    one_node = subprocess.run([*run, "--standalone", "--nproc_per_node=2", *TRAIN, *data, "--out",
                               str(tmp_path / "one_node")],
                              env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert one_node.returncode == 0, one_node.stderr[-3000:]
    single = subprocess.run([sys.executable, *TRAIN, *data, "--out", str(tmp_path / "single")],
                            env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert single.returncode == 0, single.stderr[-3000:]
    hashes = {name: [(tmp_path / name / f"weights_rank{r}.sha256").read_text() for r in (0, 1)]
              for name in ("two_nodes", "one_node")}
    assert hashes["two_nodes"][0] == hashes["two_nodes"][1] == hashes["one_node"][0]  # bit for bit
    assert json.loads((tmp_path / "two_nodes" / "summary.json").read_text())["world_size"] == 2
    for two, one in zip(_log(tmp_path / "two_nodes"), _log(tmp_path / "single"), strict=True):
        assert two["iteration"] == one["iteration"]
        assert two["train_loss"] == pytest.approx(one["train_loss"], rel=1e-4)
        assert two["loss"] == pytest.approx(one["loss"], rel=1e-4)


def test_only_rank_0_writes_the_read_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Under torchrun rank 0 refuses a non-empty output directory: another rank writing the read report
    first made a fresh run fail now and then ("output directory ... is not empty")."""
    monkeypatch.setenv("RANK", "1")
    write_read_report(tmp_path / "run", {"summary": "read 1 bag(s)"})
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
    monkeypatch.setenv("RANK", "0")
    training.prepare_out_dir(tmp_path / "run", resume=False, overwrite=False)
    write_read_report(tmp_path / "run", {"summary": "read 1 bag(s)"})
    assert (tmp_path / "run" / "read_report.txt").read_text() == "read 1 bag(s)\n"


def test_the_other_ranks_open_the_cache_entry_rank_0_built(tmp_path: Path) -> None:
    write_lab_bag(tmp_path / "bag", 7)
    arrays = load_arrays(tmp_path / "bag", spec=ReaderSpec.from_dict(SPEC), cache_dir=tmp_path / "cache")
    loads: list[int] = []
    shared: list[str] = []

    def load():  # type: ignore[no-untyped-def]
        loads.append(1)
        return arrays

    def share(text: str, ctx: DistContext) -> str:  # what rank 0 broadcast
        shared.append(text)
        return str(arrays.cache_path)

    got = training.shared_arrays(load, DistContext(rank=1, world_size=2), share)
    assert loads == [] and got.cache_path == arrays.cache_path and len(got) == len(arrays) == 2
    assert training.shared_arrays(load, DistContext(rank=0, world_size=2), share) is arrays
    assert loads == [1] and shared == ["", str(arrays.cache_path)]
    with pytest.raises(TrainSetupError, match=r"rank 1 cannot open the cache entry .*OMPN_CACHE"):
        training.shared_arrays(load, DistContext(rank=1, world_size=2), lambda text, ctx: str(tmp_path / "x"))
