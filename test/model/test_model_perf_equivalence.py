"""The speed paths stay equivalent: sparse-gather streaming encoder, Dial-sized stepper, bf16 training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ompn_ros.model import _fast_stream
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ModelInputError
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.model.streaming import StreamingPolicy

torch.set_num_threads(1)


def _stream_vs_sequence(policy: OMPNPolicy, obs: np.ndarray, backend: str = "jit") -> float:
    """Max |difference| of p_hat and action outputs between streaming and forward_sequence."""
    batch, steps, _ = obs.shape
    mask = torch.ones(batch, steps, dtype=torch.bool)
    with torch.no_grad():
        seq = policy.forward_sequence(torch.from_numpy(obs), mask)
    stream = StreamingPolicy(policy, backend=backend)  # type: ignore[arg-type]
    worst = 0.0
    for b in range(batch):
        stream.reset()
        for t in range(steps):
            out = stream.step(obs[b, t])
            worst = max(worst, float(np.abs(out.p_hat - seq.p_hat[b, t].numpy()).max()))
            if policy.config.action_type == "continuous":
                worst = max(worst, float(np.abs(out.action - seq.action_out[b, t].numpy()).max()))
    return worst


@pytest.mark.parametrize("backend", ["jit", "numpy"])
def test_sparse_craft_observations_match_sequence(backend: str) -> None:
    """Binary Craft-sized observations (~5% non-zero, mean 0) take the gather encoder."""
    torch.manual_seed(1)
    policy = OMPNPolicy(OMPNConfig(obs_dim=1075, action_type="discrete", action_dim=5))
    obs = (np.random.default_rng(1).random((2, 12, 1075)) < 0.05).astype(np.float32)
    obs[1, 3:5] = (np.random.default_rng(2).random((2, 1075)) < 0.5)  # dense rows take the dense path
    assert _stream_vs_sequence(policy, obs, backend) < 1e-5


def test_sparse_and_dense_encoders_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    torch.manual_seed(2)
    policy = OMPNPolicy(OMPNConfig(obs_dim=300, action_type="discrete", action_dim=4, slot_size=32))
    stepper = _fast_stream.NumpyStepper(policy)
    s = (np.random.default_rng(2).random(300) < 0.1).astype(np.float32) * 3.0
    stepper._encode(s)
    sparse_x, sparse_proj = stepper.x.copy(), stepper.proj.copy()
    monkeypatch.setattr(_fast_stream, "SPARSE_FRACTION", -1.0)  # force the dense matrix-vector product
    stepper._encode(s)
    np.testing.assert_allclose(sparse_x, stepper.x, atol=1e-5, rtol=0)
    np.testing.assert_allclose(sparse_proj, stepper.proj, atol=1e-5, rtol=0)
    with torch.no_grad():
        ref = policy.encode_obs(torch.from_numpy(s)[None])[0].numpy()
    np.testing.assert_allclose(sparse_x, ref, atol=1e-5, rtol=0)


def test_all_zero_observation_is_encoded_as_bias() -> None:
    torch.manual_seed(3)
    policy = OMPNPolicy(OMPNConfig(obs_dim=200, action_type="discrete", action_dim=4, slot_size=32))
    stepper = _fast_stream.NumpyStepper(policy)
    stepper._encode(np.zeros(200, np.float32))
    np.testing.assert_allclose(stepper.x, policy.encoder.bias.detach().numpy(), atol=1e-6, rtol=0)


@pytest.mark.parametrize("backend", ["jit", "numpy"])
def test_dial_config_matches_sequence(backend: str) -> None:
    """The shipped Dial model (obs 39 -> m 64, n 2, Gaussian head) with max-abs normalisation."""
    torch.manual_seed(4)
    cfg = OMPNConfig(obs_dim=39, action_type="continuous", action_dim=9, n_slots=2, slot_size=64)
    policy = OMPNPolicy(cfg)
    rng = np.random.default_rng(4)
    policy.set_obs_normalization(rng.normal(size=39), rng.uniform(0.5, 2.0, size=39))
    obs = rng.normal(size=(2, 15, 39)).astype(np.float32)
    assert _stream_vs_sequence(policy, obs, backend) < 1e-5


def _batch(rng: np.random.Generator, lengths: list[int], obs_dim: int) -> dict[str, torch.Tensor]:
    steps = max(lengths)
    lens = torch.tensor(lengths)
    mask = torch.arange(steps)[None] < lens[:, None]
    done = torch.arange(steps)[None] == (lens - 1)[:, None]
    actions = torch.as_tensor(rng.integers(0, 5, size=(len(lengths), steps)))
    actions[done] = 5
    obs = torch.as_tensor((rng.random((len(lengths), steps, obs_dim)) < 0.1).astype(np.float32))
    return {"obs": obs, "mask": mask, "done": done, "actions": actions}


def test_bf16_training_forward_is_float32_and_close() -> None:
    torch.manual_seed(5)
    cfg = OMPNConfig(obs_dim=60, action_type="discrete", action_dim=5, slot_size=32)
    policy = OMPNPolicy(cfg)
    b = _batch(np.random.default_rng(5), [7, 3, 11, 1], 60)
    ref = policy.forward_sequence(b["obs"], b["mask"])
    out = policy.forward_sequence(b["obs"], b["mask"], bf16=True)
    for name in ("action_out", "p_hat", "pi"):
        got, want = getattr(out, name), getattr(ref, name)
        assert got.dtype == torch.float32, name
        assert float((got - want).detach().abs().max()) < 0.05, name  # bfloat16: ~3 significant digits
        assert not torch.equal(got, want) or name == "pi", name  # the bf16 path really ran
    assert torch.allclose(out.p_hat.sum(-1)[b["mask"]], torch.ones(int(b["mask"].sum())), atol=1e-5)
    loss, _ = bc_loss(out, b["actions"], b["mask"], b["done"], cfg)
    loss.backward()
    for name, param in policy.named_parameters():
        assert param.grad is not None and param.grad.dtype == torch.float32, name
        assert torch.isfinite(param.grad).all(), name


def test_bf16_gradients_follow_float32_gradients() -> None:
    torch.manual_seed(6)
    cfg = OMPNConfig(obs_dim=60, action_type="discrete", action_dim=5, slot_size=32)
    policy = OMPNPolicy(cfg)
    b = _batch(np.random.default_rng(6), [9, 5, 12], 60)
    grads = []
    for bf16 in (False, True):
        policy.zero_grad()
        out = policy.forward_sequence(b["obs"], b["mask"], bf16=bf16)
        bc_loss(out, b["actions"], b["mask"], b["done"], cfg)[0].backward()
        grads.append(torch.cat([p.grad.flatten() for p in policy.parameters() if p.grad is not None]))
    cosine = torch.nn.functional.cosine_similarity(grads[0], grads[1], dim=0)
    assert float(cosine) > 0.95  # measured 0.98 at this random init


def test_bf16_needs_the_fused_path() -> None:
    policy = OMPNPolicy(OMPNConfig(obs_dim=8, action_type="discrete", action_dim=3, slot_size=8))
    with pytest.raises(ModelInputError, match="bf16"):
        policy.forward_sequence(
            torch.zeros(1, 2, 8), torch.ones(1, 2, dtype=torch.bool), impl="reference", bf16=True
        )


@pytest.mark.parametrize("kind", ["discrete", "continuous"])
def test_trainer_bf16_option_trains(kind: str) -> None:
    """``TrainConfig(bf16=True)`` reaches the fused bf16 path and updates the weights."""
    from ompn_ros.train.config import TrainConfig
    from ompn_ros.train.synthetic import make_dataset, synthetic_spec
    from ompn_ros.train.trainer import train

    obs_dim, action_type, action_dim, _ = synthetic_spec(kind)  # type: ignore[arg-type]
    config = OMPNConfig(
        obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2, slot_size=16
    )
    tc = TrainConfig(batch_size=4, iterations=2, eval_every=2, val_ratio=0.25, progress=False, bf16=True)
    torch.manual_seed(tc.seed)
    initial = OMPNPolicy(config).state_dict()
    result = train(make_dataset(kind, 8, seed=3), config, tc)  # type: ignore[arg-type]
    assert np.isfinite(result.last_metrics["train_loss"])
    after = result.policy.state_dict()
    assert any(not torch.equal(initial[k], after[k]) for k in initial if after[k].dtype.is_floating_point)
    assert all(v.dtype != torch.bfloat16 for v in after.values())  # master weights stay float32


def test_trainer_bf16_option_is_validated() -> None:
    from ompn_ros.train.config import TrainConfig
    from ompn_ros.train.errors import TrainConfigError

    with pytest.raises(TrainConfigError, match="bf16"):
        TrainConfig(bf16="yes")  # type: ignore[arg-type]
    assert TrainConfig.from_dict(TrainConfig(bf16=True).to_dict()).bf16 is True
