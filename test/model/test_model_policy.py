"""OMPNPolicy: shapes, the stick-breaking contract, first step, memory updates, masking, fused path."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor, nn

from ompn_ros.model.config import OMPNConfig
from ompn_ros.model.errors import ModelInputError
from ompn_ros.model.policy import OMPNPolicy

torch.set_num_threads(1)


def make(seed: int = 0, **kwargs) -> OMPNPolicy:
    torch.manual_seed(seed)
    base = {"obs_dim": 12, "action_type": "discrete", "action_dim": 5, "n_slots": 3, "slot_size": 16}
    return OMPNPolicy(OMPNConfig(**{**base, **kwargs}))


def batch(obs_dim: int = 12, lengths: tuple[int, ...] = (5, 9, 1, 9), seed: int = 1) -> tuple[Tensor, Tensor]:
    g = torch.Generator().manual_seed(seed)
    steps = max(lengths)
    obs = torch.randn(len(lengths), steps, obs_dim, generator=g)
    mask = torch.arange(steps)[None] < torch.tensor(lengths)[:, None]
    return obs, mask


@pytest.mark.parametrize("impl", ["fused", "reference"])
def test_shapes_and_p_hat_contract(impl: str) -> None:
    policy = make()
    obs, mask = batch()
    out = policy.forward_sequence(obs, mask, impl=impl)
    assert out.action_out.shape == (4, 9, 5)
    assert out.p_hat.shape == (4, 9, 4) and out.pi.shape == (4, 9, 3)
    valid = out.p_hat[mask]
    torch.testing.assert_close(valid.sum(-1), torch.ones(len(valid)), atol=1e-6, rtol=0)
    torch.testing.assert_close(out.pi[mask].sum(-1), torch.ones(len(valid)), atol=1e-6, rtol=0)
    # ordering: p_hat = [pi_end, top, ..., bottom] and pi = p_hat slots normalised, lowest first
    later = mask.clone()
    later[:, 0] = False
    slots = out.p_hat[later][:, 1:]
    torch.testing.assert_close(out.pi[later], slots.flip(-1) / slots.sum(-1, keepdim=True), atol=1e-6, rtol=0)
    assert torch.equal(out.pi_end, out.p_hat[..., 0])
    assert (out.p_hat[~mask] == 0).all() and (out.action_out[~mask] == 0).all()


def test_first_step_expands_from_the_top_and_skips_bottom_up() -> None:
    policy = make(sketch_mode="sum", sketch_vocab=4)
    obs, mask = batch()
    sketch = torch.tensor([[0, 1, -1], [2, -1, -1], [3, 3, 0], [1, 1, 1]])
    out = policy.forward_sequence(obs, mask, sketch)
    assert torch.equal(out.p_hat[:, 0], torch.tensor([[0.0, 1.0, 0.0, 0.0]] * 4))
    assert torch.equal(out.pi[:, 0], torch.tensor([[0.0, 0.0, 1.0]] * 4))
    # the bottom-up cells and the score MLP are not used on the first step
    with torch.no_grad():
        for p in [*policy.com_cells.parameters(), *policy.score.parameters()]:
            p.add_(torch.randn_like(p))
    changed = policy.forward_sequence(obs, mask, sketch)
    torch.testing.assert_close(changed.action_out[:, 0], out.action_out[:, 0], atol=1e-6, rtol=0)
    assert not torch.allclose(changed.p_hat[:, 1], out.p_hat[:, 1], atol=1e-3)


def test_initial_memory_puts_layer_normed_sketch_in_the_top_slot() -> None:
    policy = make(sketch_mode="sum", sketch_vocab=4)
    state = policy.initial_state(2, torch.tensor([[0, 1], [2, -1]]))  # -1 pads
    assert (state.memory[:, :2] == 0).all()
    e = policy.sketch_embedding.weight  # row id + 1; row 0 is the (zero) padding row
    top = torch.stack([e[1] + e[2], e[3]])
    torch.testing.assert_close(state.memory[:, 2], nn.functional.layer_norm(top, (16,)), atol=1e-6, rtol=0)
    assert state.first.all()
    no_sketch = make().initial_state(3)
    assert (no_sketch.memory == 0).all() and (no_sketch.task_emb == 0).all()


class _ConstCom(nn.Module):
    def __init__(self, value: list[float]) -> None:
        super().__init__()
        self.value = torch.tensor(value)

    def forward(self, v: Tensor, h: Tensor, u: Tensor) -> Tensor:
        return self.value.expand(h.shape[0], -1)


class _SlotScore(nn.Module):
    """logit 0 (beta 0.5) for the slot whose C starts with 10, ln 3 (beta 0.75) otherwise."""

    def forward(self, u: Tensor, m: Tensor, c: Tensor) -> Tensor:
        return torch.where(c[:, :1] == 10, 0.0, math.log(3.0))


class _Double(nn.Module):
    def forward(self, p: Tensor, u: Tensor) -> Tensor:
        return 2 * p


@pytest.mark.parametrize(
    ("mode", "expected"),
    [
        ("paper", [[220 / 7, 320 / 7], [102 / 7, 136 / 7]]),  # M(1-cp) + C pi + M_hat(1-rcp)
        ("code", [[220 / 7, 320 / 7], [30.0, 40.0]]),  # rcp C + (1-rcp) M_hat
    ],
)
def test_memory_update_matches_hand_computed_case(mode: str, expected: list[list[float]]) -> None:
    """n=2, m=2, M^{t-1} = [[1,2],[3,4]], C = [[10,20],[30,40]], beta = (0.5, 0.75), DecomCell_2(p) = 2p.

    pi_hat = (0.5, 0.375), pi_end = 0.125, pi = (4/7, 3/7), rcp = (4/7, 1), cp = (1, 3/7), M_hat_1 = 2 C_2.
    """
    policy = make(n_slots=2, slot_size=2, obs_dim=3, memory_update=mode)
    policy.com_cells = nn.ModuleList([_ConstCom([10.0, 20.0]), _ConstCom([30.0, 40.0])])
    policy.score = _SlotScore()
    policy.decom_cells = nn.ModuleList([_Double()])
    state = policy.initial_state(1)
    state.memory = torch.tensor([[[1.0, 2.0], [3.0, 4.0]]])
    state.first = torch.tensor([False])
    out, new = policy.step(torch.zeros(1, 3), state)
    torch.testing.assert_close(out.p_hat, torch.tensor([[0.125, 0.375, 0.5]]))
    torch.testing.assert_close(out.pi, torch.tensor([[4 / 7, 3 / 7]]))
    torch.testing.assert_close(new.memory, torch.tensor([expected]))
    assert not new.first.any()


def test_memory_update_modes_differ_on_real_weights() -> None:
    obs, mask = batch()
    paper = make(memory_update="paper").forward_sequence(obs, mask)
    code = make(memory_update="code").forward_sequence(obs, mask)
    torch.testing.assert_close(paper.p_hat[:, :2], code.p_hat[:, :2])  # same until M^1 is read
    assert (paper.p_hat[mask] - code.p_hat[mask]).abs().max() > 1e-3


@pytest.mark.parametrize("impl", ["fused", "reference"])
def test_padding_never_changes_valid_steps(impl: str) -> None:
    policy = make(action_type="continuous", action_dim=4)
    obs, mask = batch()
    out = policy.forward_sequence(obs, mask, impl=impl)
    noisy = obs.clone()
    noisy[~mask] = float("nan")
    out2 = policy.forward_sequence(noisy, mask, impl=impl)
    for name in ("action_out", "p_hat", "pi"):
        assert torch.equal(getattr(out, name)[mask], getattr(out2, name)[mask]), name
        assert (getattr(out2, name)[~mask] == 0).all()
    # a batch of one episode alone gives the same outputs as inside the padded batch
    alone = policy.forward_sequence(obs[2:3, :1], mask[2:3, :1], impl=impl)
    torch.testing.assert_close(alone.p_hat[0], out.p_hat[2, :1], atol=1e-6, rtol=0)


ABLATIONS = [
    {"sketch_mode": "none", "memory_update": "paper"},
    {"sketch_mode": "sum", "sketch_vocab": 4, "memory_update": "code"},
    {"sketch_mode": "sum", "sketch_vocab": 4, "no_bottom_up": True},
    {"no_top_down": True, "memory_update": "code"},
    {"sketch_mode": "sum", "sketch_vocab": 4, "no_bottom_up_recurrence": True},
    {"n_slots": 1},
    {"action_type": "continuous", "action_dim": 3, "sketch_mode": "sum", "sketch_vocab": 4},
]


@pytest.mark.parametrize("kwargs", ABLATIONS)
def test_fused_matches_reference_values_and_gradients(kwargs: dict) -> None:
    policy = make(**kwargs)
    obs, mask = batch()
    sketch = (
        torch.tensor([[0, 1, -1], [2, -1, -1], [3, 3, 0], [1, 1, 1]])
        if policy.config.sketch_mode == "sum"
        else None
    )
    outs = [policy.forward_sequence(obs, mask, sketch, bptt=4, impl=impl) for impl in ("reference", "fused")]
    for name in ("action_out", "p_hat", "pi"):
        torch.testing.assert_close(getattr(outs[1], name), getattr(outs[0], name), atol=1e-5, rtol=1e-5)
    params = [p for p in policy.parameters() if p.requires_grad]
    grads = []
    for out in outs:
        objective = (out.action_out**2).sum() + torch.log(out.p_hat[..., 0].clamp_min(1e-6)).sum()
        grads.append(torch.autograd.grad(objective, params, allow_unused=True))
    for (name, _), g_ref, g_fast in zip(policy.named_parameters(), *grads):
        if g_ref is None or g_fast is None:
            assert g_ref is None or not g_ref.any(), name
            continue
        scale = g_ref.abs().max().clamp_min(1.0)
        assert ((g_ref - g_fast).abs().max() / scale) < 1e-4, name


def test_bptt_truncation_cuts_gradients() -> None:
    policy = make()
    obs, mask = batch(lengths=(6,))
    obs.requires_grad_(True)
    for bptt, reaches in ((64, True), (2, False)):
        out = policy.forward_sequence(obs, mask, bptt=bptt)
        (grad,) = torch.autograd.grad(out.action_out[0, 5].sum(), obs)
        assert grad[0, 5].abs().sum() > 0
        assert bool(grad[0, 1].abs().sum() > 0) == reaches  # step 1 is before the cut after step 3


def test_bad_inputs_raise_model_input_error() -> None:
    policy = make()
    obs, mask = batch()
    with pytest.raises(ModelInputError, match="obs_dim=12"):
        policy.forward_sequence(obs[..., :5], mask)
    holes = mask.clone()
    holes[1, 2] = False
    with pytest.raises(ModelInputError, match="mask row 1 is not a prefix"):
        policy.forward_sequence(obs, holes)
    with pytest.raises(ModelInputError, match="sketch_mode='none'"):
        policy.forward_sequence(obs, mask, torch.zeros(4, 2, dtype=torch.long))
    sketched = make(sketch_mode="sum", sketch_vocab=4)
    with pytest.raises(ModelInputError, match="needs a sketch"):
        sketched.forward_sequence(obs, mask)
    with pytest.raises(ModelInputError, match=r"ids must lie in 0\.\.3"):
        sketched.forward_sequence(obs, mask, torch.full((4, 2), 4))
    with pytest.raises(ModelInputError, match=r"ids must lie in 0\.\.3"):
        sketched.forward_sequence(obs, mask, torch.full((4, 2), -2))
    with pytest.raises(ModelInputError, match="size obs_dim=12"):
        policy.set_obs_normalization(torch.zeros(3).numpy(), torch.ones(3).numpy())


def test_obs_normalization_is_applied_inside_the_model() -> None:
    policy = make()
    obs, mask = batch()
    mean, scale = torch.randn(12), torch.rand(12) + 0.5
    reference = policy.forward_sequence((obs - mean) / scale, mask)
    policy.set_obs_normalization(mean.numpy(), scale.numpy())
    torch.testing.assert_close(policy.forward_sequence(obs, mask).p_hat, reference.p_hat, atol=1e-5, rtol=0)


def test_empty_episodes_and_float64_inputs() -> None:
    policy = make()
    obs, mask = batch(lengths=(3, 0, 5))
    fused = policy.forward_sequence(obs.double(), mask)
    reference = policy.forward_sequence(obs, mask, impl="reference")
    torch.testing.assert_close(fused.p_hat, reference.p_hat, atol=1e-5, rtol=0)
    assert (fused.p_hat[1] == 0).all()
    assert policy.forward_sequence(obs[:, :0], mask[:, :0]).p_hat.shape == (3, 0, 4)


class _BottomExpands(nn.Module):
    """Huge logit for the slot whose C starts with 10 (the bottom one): pi = one-hot(slot 1)."""

    def forward(self, u: Tensor, m: Tensor, c: Tensor) -> Tensor:
        return torch.where(c[:, :1] == 10, 40.0, -40.0)


def test_paper_update_preserves_slots_above_the_expansion_and_code_update_does_not() -> None:
    """Paper Fig. 2(a): expansion at the lowest slot keeps M_2, M_3; the executed code overwrites them."""
    results = {}
    for mode in ("paper", "code"):
        policy = make(n_slots=3, slot_size=2, obs_dim=3, memory_update=mode)
        policy.com_cells = nn.ModuleList(
            [_ConstCom([10.0, 1.0]), _ConstCom([20.0, 2.0]), _ConstCom([30.0, 3.0])]
        )
        policy.score = _BottomExpands()
        state = policy.initial_state(1)
        state.memory = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]])
        state.first = torch.tensor([False])
        out, new = policy.step(torch.zeros(1, 3), state)
        torch.testing.assert_close(out.pi, torch.tensor([[1.0, 0.0, 0.0]]))
        results[mode] = new.memory[0]
    torch.testing.assert_close(results["paper"], torch.tensor([[10.0, 1.0], [3.0, 4.0], [5.0, 6.0]]))
    torch.testing.assert_close(results["code"], torch.tensor([[10.0, 1.0], [20.0, 2.0], [30.0, 3.0]]))
