"""bf16 training only on a CPU with native bfloat16: detection, fallback with one warning, force."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.train import precision
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.errors import TrainConfigError
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import train

AVX2_ONLY = "processor\t: 0\nmodel name\t: Test CPU 1\nflags\t\t: fpu sse2 avx avx2 fma\n\nprocessor\t: 1\n"
ZEN4 = "processor\t: 0\nmodel name\t: Test CPU 2\nflags\t\t: avx2 avx512f avx512_bf16 avx512_vnni\n"


@pytest.fixture(autouse=True)
def _fresh_warning(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precision, "_warned", False)


def test_cpu_flags_and_model_are_read_from_cpuinfo(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text(AVX2_ONLY)
    assert precision.cpu_flags(info) == {"fpu", "sse2", "avx", "avx2", "fma"}
    assert precision.cpu_model(info) == "Test CPU 1"
    assert not precision.native_bf16(precision.cpu_flags(info))
    info.write_text(ZEN4)
    assert precision.native_bf16(precision.cpu_flags(info))
    assert precision.cpu_flags(tmp_path / "missing") == frozenset()


def test_fallback_warns_once_and_force_overrides(caplog: pytest.LogCaptureFixture) -> None:
    avx2 = lambda: frozenset({"avx2"})  # noqa: E731
    with caplog.at_level(logging.WARNING, logger="ompn_ros.train"):
        assert precision.resolve_bf16(True, read_flags=avx2) is False
        assert precision.resolve_bf16(True, read_flags=avx2) is False
    assert len([r for r in caplog.records if "force_bf16" in r.getMessage()]) == 1
    assert precision.resolve_bf16(True, force=True, read_flags=avx2) is True
    assert precision.resolve_bf16(True, read_flags=lambda: frozenset({"amx_bf16"})) is True
    assert precision.resolve_bf16(False, force=True, read_flags=lambda: frozenset({"amx_bf16"})) is False


@pytest.mark.parametrize(("flags", "force", "expect"), [
    ({"avx2"}, False, False), ({"avx2"}, True, True), ({"avx512_bf16"}, False, True),
])
def test_trainer_uses_bf16_only_where_native(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flags: set[str], force: bool, expect: bool
) -> None:
    monkeypatch.setattr(precision, "cpu_flags", lambda: frozenset(flags))
    seen: list[bool] = []
    original = OMPNPolicy.forward_sequence

    def spy(self: OMPNPolicy, *args: object, **kwargs: object) -> object:
        seen.append(bool(kwargs.get("bf16", False)))
        return original(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(OMPNPolicy, "forward_sequence", spy)
    obs_dim, action_type, action_dim, _ = synthetic_spec("discrete")
    model = OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2,
                       slot_size=8)
    cfg = TrainConfig(iterations=2, eval_every=2, batch_size=4, progress=False, threads=1, bf16=True,
                      force_bf16=force, out_dir=str(tmp_path))
    torch.manual_seed(0)
    train(make_dataset("discrete", 8, seed=2), model, cfg)
    assert seen and any(seen) == expect  # evaluation passes run in float32 either way
    assert load_checkpoint(tmp_path / "last")[1]["train_config"]["bf16"] is expect


def test_literal_options_are_validated() -> None:
    for name, bad in (("lr_schedule", "step"), ("selection", "reward"), ("obs_norm", "zscore")):
        with pytest.raises(TrainConfigError, match=name):
            TrainConfig(**{name: bad})  # type: ignore[arg-type]
    with pytest.raises(TrainConfigError, match="force_bf16"):
        TrainConfig(force_bf16="yes")  # type: ignore[arg-type]
