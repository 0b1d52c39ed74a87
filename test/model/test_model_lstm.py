"""LSTM behaviour-cloning baseline: shapes, loss, checkpoint round trip, streaming, trainer, config."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import load_checkpoint, save_checkpoint
from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ConfigError, ModelInputError, StreamingInputError
from ompn_ros.model.load import build_stepper, stepper_from_checkpoint
from ompn_ros.model.loss import bc_loss
from ompn_ros.model.lstm import LSTMPolicy, LSTMStreamingPolicy
from ompn_ros.model.policy import OMPNPolicy
from ompn_ros.model.streaming import StreamingPolicy
from ompn_ros.train.config import TrainConfig
from ompn_ros.train.synthetic import make_dataset, synthetic_spec
from ompn_ros.train.trainer import train

torch.set_num_threads(1)


def lstm_config(action_type: str = "discrete", sketch: bool = True, **kw: object) -> OMPNConfig:
    action_dim = 5 if action_type == "discrete" else 4
    extra = {"sketch_mode": "sum", "sketch_vocab": 9} if sketch else {}
    return OMPNConfig(
        obs_dim=7, action_type=action_type, action_dim=action_dim, n_slots=2, slot_size=16,  # type: ignore[arg-type]
        arch="lstm", **extra, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def batch_inputs(b: int = 3, t: int = 9) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    obs = torch.randn(b, t, 7, generator=gen)
    mask = torch.ones(b, t, dtype=torch.bool)
    mask[1, 5:] = False
    sketch = torch.tensor([[1, 2, 3, -1], [4, 5, 6, 7], [8, 8, 0, 0]])[:b]
    return obs, mask, sketch


def test_config_arch_field_validates_and_round_trips() -> None:
    cfg = lstm_config()
    back = OMPNConfig.from_json(cfg.to_json())
    assert back == cfg and back.arch == "lstm"
    old = cfg.to_dict()
    del old["arch"]  # configs written before the field existed read as OMPN
    assert OMPNConfig.from_dict(old).arch == "ompn"
    with pytest.raises(ConfigError, match="arch"):
        OMPNConfig(obs_dim=7, action_type="discrete", action_dim=5, arch="gru")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="no_top_down"):
        lstm_config(no_top_down=True)
    assert isinstance(build_policy(lstm_config()), LSTMPolicy)
    assert isinstance(build_policy(OMPNConfig(obs_dim=7, action_type="discrete", action_dim=5)), OMPNPolicy)


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_shapes_p_hat_and_padding(action_type: str) -> None:
    policy = LSTMPolicy(lstm_config(action_type))
    obs, mask, sketch = batch_inputs()
    out = policy.forward_sequence(obs, mask, sketch, bptt=4)
    a = policy.config.action_dim
    assert out.action_out.shape == (3, 9, a) and out.p_hat.shape == (3, 9, 3) and out.pi.shape == (3, 9, 2)
    valid = out.p_hat[mask]
    assert torch.allclose(valid.sum(-1), torch.ones(valid.shape[0]))
    assert torch.allclose(valid[:, 1], 1 - valid[:, 0]) and torch.all(valid[:, 2] == 0)
    assert torch.all(out.pi[mask][:, -1] == 1)  # no hierarchy: everything on the top slot
    assert torch.all(out.action_out[~mask] == 0)
    # padded steps never change valid ones (causality), and bptt only cuts gradients
    obs2 = obs.clone()
    obs2[1, 5:] = 100.0
    out2 = policy.forward_sequence(obs2, mask, sketch, bptt=64)
    assert torch.allclose(out.action_out, out2.action_out, atol=1e-6)


def test_discrete_loss_is_six_way_cross_entropy() -> None:
    policy = LSTMPolicy(lstm_config())
    obs, mask, sketch = batch_inputs()
    actions = torch.randint(0, 5, (3, 9))
    done = torch.zeros(3, 9, dtype=torch.bool)
    done[0, 8], done[1, 4], done[2, 8] = True, True, True
    actions[done] = 5
    out = policy.forward_sequence(obs, mask, sketch)
    loss, _ = bc_loss(out, actions, mask, done, policy.config)
    # the same logits through the 6-way head directly
    x = policy.encode_obs(obs)
    e = policy.embed_sketch(sketch, 3)
    lstm_out, _ = policy.lstm(x, policy.initial_state(e))
    logits6 = policy.head(torch.cat([lstm_out, e.unsqueeze(1).expand(3, 9, -1), x], dim=-1))
    ce = torch.nn.functional.cross_entropy(logits6[mask], actions[mask])
    assert math.isclose(loss.item(), ce.item(), rel_tol=1e-5)
    loss.backward()
    assert policy.encoder.weight.grad is not None and policy.sketch_embedding is not None
    assert policy.sketch_embedding.weight.grad is not None


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_streaming_matches_sequence_forward(action_type: str) -> None:
    policy = LSTMPolicy(lstm_config(action_type))
    policy.set_obs_normalization(np.full(7, 0.1, np.float32), np.full(7, 2.0, np.float32))
    obs, mask, sketch = batch_inputs()
    with torch.no_grad():
        out = policy.forward_sequence(obs, mask, sketch, bptt=3)
    stepper = build_stepper(policy)
    assert isinstance(stepper, LSTMStreamingPolicy)
    for row in (0, 1):
        stepper.reset(sketch[row].numpy())
        for t in range(int(mask[row].sum())):
            so = stepper.step(obs[row, t].numpy())
            np.testing.assert_allclose(so.p_hat, out.p_hat[row, t].numpy(), atol=1e-5)
            assert abs(so.pi_end - float(out.pi_end[row, t])) < 1e-5
            if action_type == "discrete":
                assert so.action == int(out.action_out[row, t].argmax())
            else:
                np.testing.assert_allclose(so.action, out.action_out[row, t].numpy(), atol=1e-5)


def test_streaming_input_errors() -> None:
    stepper = LSTMStreamingPolicy(LSTMPolicy(lstm_config()))
    with pytest.raises(StreamingInputError, match="reset"):
        stepper.step(np.zeros(7, np.float32))
    stepper.reset(np.array([1, 2]))
    with pytest.raises(StreamingInputError, match="obs_dim=7"):
        stepper.step(np.zeros(6, np.float32))
    with pytest.raises(ModelInputError, match="sketch ids"):
        stepper.reset(np.array([42]))


def test_checkpoint_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    policy = LSTMPolicy(lstm_config("continuous"))
    policy.set_obs_normalization(np.arange(7, dtype=np.float32), np.full(7, 3.0, np.float32))
    save_checkpoint(tmp_path / "ck", policy, extra={"note": "lstm"})
    loaded, extra = load_checkpoint(tmp_path / "ck")
    assert isinstance(loaded, LSTMPolicy) and extra == {"note": "lstm"}
    for key, value in policy.state_dict().items():
        assert torch.equal(value, loaded.state_dict()[key]), key
    obs, mask, sketch = batch_inputs()
    with torch.no_grad():
        a = policy.forward_sequence(obs, mask, sketch).action_out
        b = loaded.forward_sequence(obs, mask, sketch).action_out
    assert torch.equal(a, b)
    assert isinstance(stepper_from_checkpoint(tmp_path / "ck"), LSTMStreamingPolicy)
    with pytest.raises(StreamingInputError, match="stepper_from_checkpoint"):
        StreamingPolicy.from_checkpoint(tmp_path / "ck")


def test_trainer_trains_the_lstm(tmp_path) -> None:  # type: ignore[no-untyped-def]
    obs_dim, action_type, action_dim, vocab = synthetic_spec("discrete")
    episodes = make_dataset("discrete", 24, seed=0)
    cfg = OMPNConfig(
        obs_dim=obs_dim, action_type=action_type, action_dim=action_dim, n_slots=2, slot_size=16,  # type: ignore[arg-type]
        sketch_mode="sum", sketch_vocab=vocab, arch="lstm",
    )  # fmt: skip
    tcfg = TrainConfig(
        lr=1e-2, batch_size=8, iterations=30, eval_every=15, out_dir=str(tmp_path / "run"), progress=False
    )
    result = train(episodes, cfg, tcfg)
    assert isinstance(result.policy, LSTMPolicy)
    first, last = result.history[0]["train_loss"], result.history[-1]["train_loss"]
    assert last < first
    loaded, _ = load_checkpoint(tmp_path / "run" / "last")
    assert isinstance(loaded, LSTMPolicy) and loaded.config.arch == "lstm"


def test_the_lstm_stepper_names_its_one_backend() -> None:
    """The LSTM steps with torch: ``backend='torch'``; the old name 'numpy' is one line naming it."""
    policy = LSTMPolicy(lstm_config())
    assert LSTMStreamingPolicy(policy, backend="torch").backend == "torch"
    assert build_stepper(policy, backend="jit").backend == "torch"  # whatever the OMPN kernel asked
    with pytest.raises(StreamingInputError) as err:
        LSTMStreamingPolicy(policy, backend="numpy")
    assert "backend='torch'" in str(err.value) and "\n" not in str(err.value)
