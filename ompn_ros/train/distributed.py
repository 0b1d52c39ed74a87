"""Data-parallel training under ``torchrun`` with the gloo backend (CPU).

``torchrun --nproc_per_node=2 -m ompn_ros.cli.train ...`` starts one process per rank with
``RANK``/``WORLD_SIZE``/``MASTER_ADDR``/``MASTER_PORT`` in the environment.  Every rank builds the
same global batch (the shuffle is seeded), keeps its shard ``batch[rank::world]``, and gradients are
summed across ranks after each backward pass.  The local loss is scaled by
``world · local_valid_steps / global_valid_steps`` first, so the averaged gradient equals the
gradient of the per-token mean over the *global* batch (docs/craft.md §3.8's loss), whatever the shard
sizes.  ``DistributedDataParallel`` is not used because training calls
``OMPNPolicy.forward_sequence`` rather than ``forward``; an explicit all-reduce is simpler and exact.
Only rank 0 evaluates, logs and writes checkpoints.  The same holds across machines
(``torchrun --nnodes``): ``RANK`` is the global rank, and rank 0 alone reads the bags into the
cache, whose entry the other ranks open memory-mapped (``app/training.py``), so they read the
episodes of their shards only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

from ompn_ros.train.errors import DistributedError


@dataclass(frozen=True)
class DistContext:
    """This process's place in the (possibly single-process) training job."""

    rank: int = 0
    world_size: int = 1

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def init_distributed() -> DistContext:
    """Join the torchrun process group when ``WORLD_SIZE > 1`` (gloo), else a single-process context."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistContext()
    rank_text = os.environ.get("RANK")
    if rank_text is None:
        raise DistributedError("WORLD_SIZE > 1 but RANK is not set; start the job with torchrun")
    if not dist.is_initialized():
        dist.init_process_group(backend="gloo")
    if dist.get_world_size() != world:
        raise DistributedError(f"process group has {dist.get_world_size()} ranks but WORLD_SIZE={world}")
    return DistContext(rank=int(rank_text), world_size=world)


def shutdown(ctx: DistContext) -> None:
    """Leave the process group (after a final barrier)."""
    if ctx.enabled and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


def broadcast_module(module: nn.Module, ctx: DistContext) -> None:
    """Copy rank 0's parameters and buffers to every rank."""
    if not ctx.enabled:
        return
    with torch.no_grad():
        for tensor in list(module.parameters()) + list(module.buffers()):
            dist.broadcast(tensor.data, src=0)


def broadcast_text(text: str, ctx: DistContext) -> str:
    """Rank 0's ``text`` on every rank (its UTF-8 bytes in a tensor; nothing is pickled)."""
    if not ctx.enabled:
        return text
    data = torch.tensor(list(text.encode()) if ctx.is_main else [], dtype=torch.uint8)
    size = torch.tensor([data.numel()], dtype=torch.int64)
    dist.broadcast(size, src=0)
    if not ctx.is_main:
        data = torch.empty(int(size.item()), dtype=torch.uint8)
    dist.broadcast(data, src=0)
    return bytes(data.tolist()).decode()


def all_reduce_sum(value: float, ctx: DistContext) -> float:
    """Sum a scalar over ranks."""
    if not ctx.enabled:
        return value
    t = torch.tensor([value], dtype=torch.float64)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return float(t.item())


def all_reduce_gradients(module: nn.Module, ctx: DistContext) -> None:
    """Average gradients over ranks in one flat buffer (parameters without a gradient count as 0)."""
    if not ctx.enabled:
        return
    params = [p for p in module.parameters() if p.requires_grad]
    for p in params:
        if p.grad is None:
            p.grad = torch.zeros_like(p)
    grads = [p.grad for p in params if p.grad is not None]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat, op=dist.ReduceOp.SUM)
    flat /= ctx.world_size
    offset = 0
    for g in grads:
        n = g.numel()
        g.copy_(flat[offset : offset + n].view_as(g))
        offset += n
