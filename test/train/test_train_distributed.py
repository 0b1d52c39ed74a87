"""DDP (gloo) under torchrun: 2 ranks train on shards, loss goes down, weights identical across ranks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.slow  # two training ranks; one rank per process in test_train_multinode
def test_torchrun_two_ranks_identical_weights_and_loss_decreases(tmp_path: Path) -> None:
    out = tmp_path / "ddp"
    env = dict(os.environ)
    env["OMP_NUM_THREADS"] = "1"
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node=2",
        "-m",
        "ompn_ros.cli.train",
        "--synthetic",
        "discrete",
        "--episodes",
        "48",
        "--out",
        str(out),
        "--quiet",
        "--set",
        "model.n_slots=2",
        "--set",
        "model.slot_size=32",
        "--set",
        "train.iterations=24",
        "--set",
        "train.eval_every=12",
        "--set",
        "train.batch_size=16",
        "--set",
        "train.lr=0.003",
        "--set",
        "train.val_ratio=0.25",
        "--set",
        "train.threads=1",
    ]
    proc = subprocess.run(
        cmd, env=env, capture_output=True, text=True, timeout=300, cwd=Path(__file__).parents[2]
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    hashes = [(out / f"weights_rank{r}.sha256").read_text().strip() for r in (0, 1)]
    assert len(hashes[0]) == 64 and hashes[0] == hashes[1]
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in log] == [12, 24]
    assert log[-1]["train_loss"] < 1.0  # starts at ~ln(4) = 1.39 for 3 actions + done
    assert log[-1]["loss"] < log[0]["loss"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world_size"] == 2 and summary["iterations"] == 24
    assert (out / "best" / "model.safetensors").exists()
