"""StreamingPolicy agrees with forward_sequence (both backends) and reports bad input clearly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import StreamingInputError
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.model.streaming import StreamingPolicy

torch.set_num_threads(1)

CASES = {
    "discrete": {"obs_dim": 20, "action_type": "discrete", "action_dim": 5},
    "discrete_sketch_code": {
        "obs_dim": 20,
        "action_type": "discrete",
        "action_dim": 5,
        "sketch_mode": "sum",
        "sketch_vocab": 6,
        "memory_update": "code",
    },
    "continuous": {"obs_dim": 11, "action_type": "continuous", "action_dim": 9, "n_slots": 2},
    "continuous_sketch": {
        "obs_dim": 11,
        "action_type": "continuous",
        "action_dim": 9,
        "sketch_mode": "sum",
        "sketch_vocab": 6,
    },
    "no_bottom_up_recurr": {
        "obs_dim": 20,
        "action_type": "discrete",
        "action_dim": 5,
        "no_bottom_up_recurrence": True,
    },
    "no_bottom_up": {"obs_dim": 20, "action_type": "discrete", "action_dim": 5, "no_bottom_up": True},
    "no_top_down": {"obs_dim": 11, "action_type": "continuous", "action_dim": 3, "no_top_down": True},
    "single_slot_paper": {"obs_dim": 20, "action_type": "discrete", "action_dim": 5, "n_slots": 1},
    "code_update_continuous": {
        "obs_dim": 11,
        "action_type": "continuous",
        "action_dim": 2,
        "memory_update": "code",
    },
}


def build(kwargs: dict, seed: int = 0, slot_size: int = 16) -> OMPNPolicy:
    torch.manual_seed(seed)
    policy = OMPNPolicy(OMPNConfig(**{"slot_size": slot_size, **kwargs}))
    rng = np.random.default_rng(seed)
    d = policy.config.obs_dim
    policy.set_obs_normalization(rng.normal(size=d), rng.uniform(0.5, 2.0, size=d))
    return policy


def check_agreement(policy: OMPNPolicy, lengths: list[int], backend: str, seed: int = 0) -> None:
    cfg = policy.config
    rng = np.random.default_rng(seed)
    steps = max(lengths)
    obs = rng.normal(size=(len(lengths), steps, cfg.obs_dim)).astype(np.float32)
    mask = torch.arange(steps)[None] < torch.tensor(lengths)[:, None]
    sketch = None
    if cfg.sketch_mode == "sum":
        sketch = torch.as_tensor(rng.integers(-1, cfg.sketch_vocab, size=(len(lengths), 4)))
    with torch.no_grad():
        seq = policy.forward_sequence(torch.from_numpy(obs), mask, sketch)
    stream = StreamingPolicy(policy, backend=backend)
    for b, length in enumerate(lengths):
        stream.reset(None if sketch is None else sketch[b].numpy())
        for t in range(length):
            out = stream.step(obs[b, t])
            np.testing.assert_allclose(out.p_hat, seq.p_hat[b, t].numpy(), atol=1e-5, rtol=0)
            np.testing.assert_allclose(out.pi, seq.pi[b, t].numpy(), atol=1e-5, rtol=0)
            assert out.pi_end == pytest.approx(float(seq.p_hat[b, t, 0]), abs=1e-5)
            assert out.done_prob == out.pi_end
            positions = np.arange(1, cfg.n_slots + 1)
            assert out.expected_position == pytest.approx(float(positions @ out.pi), abs=1e-6)
            if cfg.action_type == "discrete":
                logits = seq.action_out[b, t].numpy()
                assert isinstance(out.action, int)
                assert logits[out.action] >= logits.max() - 1e-5
            else:
                np.testing.assert_allclose(out.action, seq.action_out[b, t].numpy(), atol=1e-5, rtol=0)


@pytest.mark.parametrize("backend", ["jit", "numpy", "torch"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_stream_matches_sequence(case: str, backend: str) -> None:
    check_agreement(build(CASES[case]), [6, 1, 9, 3], backend)


@pytest.mark.parametrize("backend", ["jit", "numpy", "torch"])
def test_stream_matches_sequence_at_craft_size(backend: str) -> None:
    policy = build({"obs_dim": 1075, "action_type": "discrete", "action_dim": 5}, slot_size=128)
    check_agreement(policy, [5, 2], backend)


def test_first_output_and_reset() -> None:
    stream = StreamingPolicy(build(CASES["discrete"]))
    obs = np.ones(20, dtype=np.float32)
    first = stream.step(obs)
    np.testing.assert_array_equal(first.p_hat, [0, 1, 0, 0])
    assert first.expected_position == 3.0 and first.pi_end == 0.0
    second = stream.step(obs)
    assert second.p_hat[1] != 1.0
    stream.reset()
    again = stream.step(obs)
    np.testing.assert_array_equal(again.p_hat, first.p_hat)
    assert again.action == first.action
    assert all(m.dtype == np.float32 for m in stream._memory)  # no silent float64 promotion


def test_from_checkpoint(tmp_path: Path) -> None:
    policy = build(CASES["continuous_sketch"])
    save_checkpoint(tmp_path / "ckpt", policy)
    a, b = StreamingPolicy(policy), StreamingPolicy.from_checkpoint(tmp_path / "ckpt")
    assert b.config == policy.config
    sketch = np.array([1, 2, 3])
    a.reset(sketch)
    b.reset(sketch)
    for obs in np.random.default_rng(0).normal(size=(5, 11)):
        np.testing.assert_array_equal(a.step(obs).p_hat, b.step(obs).p_hat)


def test_bad_input() -> None:
    stream = StreamingPolicy(build(CASES["discrete"]))
    with pytest.raises(StreamingInputError, match="obs_dim=20"):
        stream.step(np.zeros(19))
    with pytest.raises(StreamingInputError, match="NaN"):
        stream.step(np.full(20, np.nan))
    sketched = StreamingPolicy(build(CASES["continuous_sketch"]))
    with pytest.raises(StreamingInputError, match=r"call reset\(sketch\)"):
        sketched.step(np.zeros(11))
    with pytest.raises(StreamingInputError, match="1-D integer array"):
        sketched.reset(np.zeros((2, 2)))
    with pytest.raises(StreamingInputError, match="backend"):
        StreamingPolicy(build(CASES["discrete"]), backend="jax")  # type: ignore[arg-type]


def round_to_half(policy: OMPNPolicy) -> OMPNPolicy:
    """Weights that are float16 values (as a checkpoint saved with weights_dtype='float16')."""
    with torch.no_grad():
        for p in policy.parameters():
            p.copy_(p.half().float())
    return policy


@pytest.mark.parametrize("case", sorted(CASES))
def test_jit_reads_float16_weights_with_float32_arithmetic(case: str) -> None:
    policy = round_to_half(build(CASES[case], seed=3))
    stream = StreamingPolicy(policy, backend="jit")
    assert stream._w is not None and stream._w.weights_dtype == "float16"
    check_agreement(policy, [6, 1, 9, 3], "jit", seed=3)


def test_jit_float16_weights_at_craft_size_with_sparse_observations() -> None:
    craft = {"obs_dim": 1075, "action_type": "discrete", "action_dim": 5}
    policy = round_to_half(build(craft, slot_size=128))
    policy.set_obs_normalization(np.zeros(1075), np.ones(1075))  # Craft: raw one-hot features
    half, full = StreamingPolicy(policy, backend="jit"), StreamingPolicy(policy, backend="torch")
    assert half._w is not None and half._w.weights_dtype == "float16"
    rng = np.random.default_rng(4)
    for _ in range(12):
        obs = np.zeros(1075, np.float32)
        obs[rng.choice(1075, size=60, replace=False)] = 1.0
        a, b = half.step(obs), full.step(obs)
        np.testing.assert_allclose(a.p_hat, b.p_hat, atol=1e-5, rtol=0)
        assert a.action == b.action


def test_weights_that_are_not_float16_values_stay_float32() -> None:
    from ompn_ros.model._jit_stream import half_bits_if_exact

    stream = StreamingPolicy(build(CASES["discrete"]), backend="jit")
    assert stream._w is not None and stream._w.weights_dtype == "float32"
    exact = np.array([0.5, -2.0, 3 * 2.0**-24, -0.0], np.float32)  # 3 * 2^-24: a float16 subnormal
    halves = half_bits_if_exact([exact])
    assert halves is not None and halves[0].dtype == np.uint16
    np.testing.assert_array_equal(halves[0].view(np.float16).astype(np.float32), exact)
    assert half_bits_if_exact([exact, np.array([0.1], np.float32)]) is None
    assert half_bits_if_exact([np.array([7e4], np.float32)]) is None  # beyond float16's range
