"""Golden test: the streaming segmenter reproduces the model's offline teacher-forced sequence."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
policy_mod = pytest.importorskip("ompn_ros.model.policy")
streaming = pytest.importorskip("ompn_ros.model.streaming")
checkpoint = pytest.importorskip("ompn_ros.model.checkpoint")

from ompn_ros.data.episode import Episode  # noqa: E402
from ompn_ros.detect.online import DetectorConfig, detect_sequence, expansion_scores  # noqa: E402
from ompn_ros.model.config import OMPNConfig  # noqa: E402
from ompn_ros.segmenter import StreamingSegmenter  # noqa: E402
from ompn_ros.stream.replay import replay_episode  # noqa: E402

torch.set_num_threads(1)


def random_episode(obs_dim: int, T: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    return Episode(
        observations=rng.normal(size=(T + 1, obs_dim)).astype(np.float32),
        actions=rng.integers(0, 5, size=T),
        subtask=np.repeat(np.arange(4), T // 4 + 1)[:T],
        sketch=np.array([1, 2, 3, 4]),
    )


@pytest.mark.parametrize(
    "cfg",
    [
        OMPNConfig(obs_dim=7, action_type="discrete", action_dim=5, n_slots=3, slot_size=16),
        OMPNConfig(
            obs_dim=9, action_type="continuous", action_dim=4, n_slots=2, slot_size=16, memory_update="code"
        ),
        OMPNConfig(
            obs_dim=5,
            action_type="discrete",
            action_dim=3,
            n_slots=3,
            slot_size=8,
            sketch_mode="sum",
            sketch_vocab=6,
        ),
    ],
    ids=["discrete", "continuous-code-update", "sketch"],
)
def test_segmenter_matches_forward_sequence(cfg: OMPNConfig, tmp_path) -> None:
    torch.manual_seed(0)
    model = policy_mod.OMPNPolicy(cfg)
    checkpoint.save_checkpoint(tmp_path / "ckpt", model)
    stream = streaming.StreamingPolicy.from_checkpoint(tmp_path / "ckpt")
    segmenter = StreamingSegmenter(stream, DetectorConfig(high=0.4))
    for seed, T in ((0, 30), (1, 17)):
        ep = random_episode(cfg.obs_dim, T, seed)
        replay = replay_episode(segmenter, ep, include_done_step=True)
        obs = torch.from_numpy(ep.observations[:T]).unsqueeze(0)
        sketch = torch.from_numpy(ep.sketch).unsqueeze(0) if cfg.sketch_mode == "sum" else None
        with torch.inference_mode():
            ref, fused = (
                model.forward_sequence(obs, torch.ones(1, T, dtype=torch.bool), sketch=sketch, impl=impl)
                for impl in ("reference", "fused")
            )
        ref_p_hat = ref.p_hat[0].numpy()
        np.testing.assert_allclose(replay.p_hat, ref_p_hat, atol=1e-5)
        np.testing.assert_allclose(replay.p_hat, fused.p_hat[0].numpy(), atol=1e-5)  # the training path too
        # pi (lowest first) is p_hat's slots reversed and normalised
        slots = ref_p_hat[:, 1:][:, ::-1]
        np.testing.assert_allclose(replay.pi, slots / slots.sum(1, keepdims=True), atol=1e-5)
        np.testing.assert_allclose(replay.pi_end, ref_p_hat[:, 0], atol=1e-5)
        # the online boundaries are the causal detector run on the offline scores
        offline = detect_sequence(expansion_scores(ref_p_hat), DetectorConfig(high=0.4))
        assert [b.step for b in replay.boundaries] == [b.step for b in offline]
        assert replay.boundaries[-1].step == T - 1
