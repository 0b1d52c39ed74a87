"""Training precision: use bfloat16 matmuls only where the CPU computes them natively.

``TrainConfig.bf16`` runs the fused training forward's cell matmuls in bfloat16 autocast.  On a CPU
with native bfloat16 instructions (x86 ``avx512_bf16`` or ``amx_bf16``) that is faster than float32;
without them PyTorch emulates bfloat16 and the same option is many times *slower* (an AVX2-only AMD
EPYC measured 242 against 4 884 frames/s, see ``BENCHMARKS.md``).  :func:`resolve_bf16` therefore
keeps bf16 only on a native CPU and otherwise warns once and trains in float32, unless
``TrainConfig.force_bf16`` asks for bf16 regardless (to measure it, or on CPUs whose flags are not
listed in ``/proc/cpuinfo``).

This is a speed option of ours, not part of the paper (Lu et al., ICLR 2021 train in float32).
"""

from __future__ import annotations

import logging
import platform
from collections.abc import Callable
from pathlib import Path

LOG = logging.getLogger("ompn_ros.train")
CPUINFO = Path("/proc/cpuinfo")
NATIVE_BF16_FLAGS = ("avx512_bf16", "amx_bf16")
"""CPU flags (Linux ``/proc/cpuinfo`` names) of native bfloat16 matrix arithmetic on x86."""
_warned = False


def cpu_flags(cpuinfo: Path = CPUINFO) -> frozenset[str]:
    """The CPU feature flags of the first processor in ``cpuinfo`` (empty when unreadable).

    O(size of the file); the ``flags`` line (x86) or ``Features`` line (ARM) is used.
    """
    try:
        text = cpuinfo.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return frozenset()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return frozenset(value.split())
    return frozenset()


def cpu_model(cpuinfo: Path = CPUINFO) -> str:
    """The CPU model name (``model name`` in ``cpuinfo``; else :func:`platform.processor`)."""
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def native_bf16(flags: frozenset[str]) -> bool:
    """True when ``flags`` include an instruction set with native bfloat16 matrix arithmetic."""
    return any(flag in flags for flag in NATIVE_BF16_FLAGS)


def resolve_bf16(
    requested: bool, force: bool = False, read_flags: Callable[[], frozenset[str]] | None = None
) -> bool:
    """Whether to train in bf16: ``requested`` and (``force`` or a native-bf16 CPU).

    ``read_flags`` defaults to :func:`cpu_flags`.  Falling back to float32 logs one warning per
    process naming the missing CPU flags.
    """
    global _warned
    if not requested:
        return False
    if force or native_bf16((read_flags or cpu_flags)()):
        return True
    if not _warned:
        _warned = True
        LOG.warning(
            "train.bf16 requested, but this CPU (%s) has none of the flags %s: bfloat16 would be "
            "emulated and far slower, so training runs in float32 (set train.force_bf16 to override)",
            cpu_model(),
            ", ".join(NATIVE_BF16_FLAGS),
        )
    return False


__all__ = ["NATIVE_BF16_FLAGS", "cpu_flags", "cpu_model", "native_bf16", "resolve_bf16"]
