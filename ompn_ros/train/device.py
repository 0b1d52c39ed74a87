"""Where training runs: ``train.device: auto | cpu | cuda``.

``cpu`` is the path every figure of this package was measured on (the fused forward of
``model/fused.py``, bfloat16 autocast where the CPU has it).  ``cuda`` runs the same batched forward,
loss and update on the GPU: the policy's parameters and buffers, the optimizer state and every
tensor of a batch (:func:`batch_to`) live there; checkpoints and the resumable state are written
from CPU copies, so they load on any machine.  ``auto`` is ``cuda`` when torch sees a GPU, else
``cpu``.  The default is ``cpu``: the CUDA path is covered by tests that need a GPU and have not yet
run on one, so a GPU is used only when asked for.  The node steps on the CPU either way (batch 1,
compiled kernel); ``ompn_segment --device`` takes the same names with ``auto`` meaning ``cpu`` (a
batch-1 replay is faster there).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Literal, TypeVar, get_args

from ompn_ros.train.errors import DeviceError

if TYPE_CHECKING:  # torch loads when a function runs: DEVICES is offered by --help, which must stay light
    import torch

Device = Literal["auto", "cpu", "cuda"]
DEVICES: tuple[Device, ...] = get_args(Device)
T = TypeVar("T")


def resolve_device(name: str, setting: str = "train.device") -> torch.device:
    """The torch device of ``name``; :class:`DeviceError` for ``cuda`` without a GPU or an unknown name."""
    import torch

    if name not in DEVICES:
        raise DeviceError(f"{setting} must be one of {DEVICES}, got {name!r}")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise DeviceError(f"{setting}=cuda, but torch sees no GPU (a CPU-only torch build or no driver): "
                          f"use {setting}=cpu or auto")
    return torch.device(name)


def batch_to(batch: T, device: torch.device) -> T:
    """A copy of the dataclass ``batch`` with every tensor field on ``device`` (others kept as they are)."""
    import torch

    assert dataclasses.is_dataclass(batch) and not isinstance(batch, type)
    moved = {f.name: getattr(batch, f.name).to(device) for f in dataclasses.fields(batch)
             if isinstance(getattr(batch, f.name), torch.Tensor)}
    return dataclasses.replace(batch, **moved)


def device_of(module: torch.nn.Module) -> torch.device:
    """The device of ``module``'s first parameter (CPU for a module without any)."""
    import torch

    return next((p.device for p in module.parameters()), torch.device("cpu"))


def stray_tensors(module: torch.nn.Module, device: torch.device) -> list[str]:
    """Names of ``module``'s tensors not on ``device``: parameters, buffers and plain tensor attributes
    of every submodule (``Module.to`` moves only the first two)."""
    import torch

    stray = [name for name, t in [*module.named_parameters(), *module.named_buffers()] if t.device != device]
    for prefix, sub in module.named_modules():
        for name, value in vars(sub).items():
            if isinstance(value, torch.Tensor) and value.device != device:
                stray.append(f"{prefix}.{name}" if prefix else name)
    return stray


__all__ = ["DEVICES", "Device", "batch_to", "device_of", "resolve_device", "stray_tensors"]
