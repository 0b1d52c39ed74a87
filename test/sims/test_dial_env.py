"""Dial env: observation layout, press detection, sketch sampling, timeout, determinism."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from sim_nodes.dial import ENV_ID, OBS_DIM, DialConfigError, DialEnv, sample_sketch
from sim_nodes.dial.env import validate_sketch
from sim_nodes.dial.scene import (
    FRAME_SKIP,
    GRAVITY,
    JOINT_NAMES,
    KEY_XY,
    TIMESTEP,
    TORQUE_SCALE,
    approach_point,
    press_point,
    shared_model,
)
from sim_nodes.dial.targets import shared_targets


def hold_action(env: DialEnv) -> np.ndarray:
    """Normalised torque that cancels gravity/Coriolis at the current state."""
    return env.data.qfrc_bias[env.dm.dof_adr] / TORQUE_SCALE


def put_arm(env: DialEnv, q: np.ndarray) -> None:
    env.data.qpos[env.dm.qpos_adr] = q
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)


def test_scene_constants_and_layout() -> None:
    dm = shared_model()
    m = dm.model
    assert (m.nq, m.nv, m.nu) == (9, 9, 9)
    assert m.opt.timestep == pytest.approx(TIMESTEP) and FRAME_SKIP == 20
    np.testing.assert_allclose(m.opt.gravity, GRAVITY)
    np.testing.assert_allclose(m.actuator_gear[:, 0], TORQUE_SCALE)
    assert [m.joint(j).name for j in m.actuator_trnid[:, 0]] == list(JOINT_NAMES)
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    # phone layout at the original coordinates: 1 2 3 along +x at y=+0.21, 0 below 8
    assert KEY_XY[1] == (0.36, 0.21) and KEY_XY[3] == (0.64, 0.21) and KEY_XY[0] == (0.50, -0.21)
    for d in range(10):
        np.testing.assert_allclose(data.site_xpos[dm.press_sites[d]], press_point(d), atol=1e-9)
        np.testing.assert_allclose(data.site_xpos[dm.approach_sites[d]], approach_point(d), atol=1e-9)
        np.testing.assert_allclose(data.xpos[m.body(f"key{d}").id], [*KEY_XY[d], 0.09], atol=1e-9)


def test_observation_layout() -> None:
    env = DialEnv()
    obs, info = env.reset(seed=1)
    assert obs.shape == (OBS_DIM,) == (39,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    np.testing.assert_allclose(obs[:9], env.joint_position, atol=1e-6)
    ref = env.reference_position
    for k in range(10):
        np.testing.assert_allclose(obs[9 + 3 * k : 12 + 3 * k], ref - press_point(k), atol=1e-6)
    assert info["subtasks_done"] == 0 and info["subtask_index"] == 0


def test_observation_with_label_permutation() -> None:
    env = DialEnv(permute_labels=True)
    obs, info = env.reset(seed=4)
    perm = info["permutation"]
    assert sorted(perm.tolist()) == list(range(10)) and not np.array_equal(perm, np.arange(10))
    ref = env.reference_position
    for k in range(10):
        np.testing.assert_allclose(obs[9 + 3 * k : 12 + 3 * k], ref - press_point(int(perm[k])), atol=1e-6)
    assert env.target_digit == perm[env.sketch[0]]
    assert np.array_equal(DialEnv().reset(seed=4)[1]["permutation"], np.arange(10))  # off by default


def test_press_detection_and_tolerance() -> None:
    targets = shared_targets()
    env = DialEnv()
    env.reset(seed=0, options={"sketch": [5, 2, 8, 0]})
    put_arm(env, targets.approach[5])  # 4 cm above the press point: no press at 0.01
    _, reward, terminated, _, info = env.step(hold_action(env))
    assert info["subtasks_done"] == 0 and reward == 0.0 and not terminated
    put_arm(env, targets.press[5])
    _, reward, terminated, _, info = env.step(hold_action(env))
    assert info["subtasks_done"] == 1 and info["subtask_index"] == 1 and info["target_label"] == 2
    assert reward == 0.0 and not terminated

    loose = DialEnv(press_tolerance=0.1)  # the original gym threshold accepts the approach pose
    loose.reset(seed=0, options={"sketch": [5, 2, 8, 0]})
    put_arm(loose, targets.approach[5])
    assert loose.step(hold_action(loose))[4]["subtasks_done"] == 1


def test_reward_only_on_full_sketch() -> None:
    targets = shared_targets()
    env = DialEnv(sketch_length=2)
    env.reset(seed=0, options={"sketch": [3, 9]})
    put_arm(env, targets.press[3])
    assert env.step(hold_action(env))[1:3] == (0.0, False)
    put_arm(env, targets.press[9])
    _, reward, terminated, truncated, info = env.step(hold_action(env))
    assert (reward, terminated, truncated) == (1.0, True, False)
    assert info["is_success"] and info["subtasks_done"] == 2


def test_subtask_timeout_truncates() -> None:
    env = DialEnv(max_steps_per_subtask=3)
    env.reset(seed=2)
    flags = [env.step(hold_action(env))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_sketch_sampling_has_no_immediate_repeat() -> None:
    rng = np.random.default_rng(0)
    sketches = np.array([sample_sketch(rng) for _ in range(3000)])
    assert sketches.shape == (3000, 4)
    assert not np.any(sketches[:, 1:] == sketches[:, :-1])
    assert set(np.unique(sketches).tolist()) == set(range(10))
    counts = np.bincount(sketches[:, 1:].ravel(), minlength=10)
    assert counts.min() > 0.7 * counts.mean()  # roughly uniform
    assert any(len(set(s)) < 4 for s in sketches.tolist())  # non-adjacent repeats are allowed


def test_sketch_validation_names_the_problem() -> None:
    assert validate_sketch([0, 5, 0, 3]).tolist() == [0, 5, 0, 3]
    with pytest.raises(DialConfigError, match="repeat"):
        validate_sketch([1, 1, 2, 3])
    with pytest.raises(DialConfigError, match=r"0\.\.9"):
        validate_sketch([1, 10, 2, 3])
    with pytest.raises(DialConfigError, match="4 ids"):
        validate_sketch([1, 2, 3], 4)
    with pytest.raises(DialConfigError, match="press_tolerance"):
        DialEnv(press_tolerance=0.0)
    env = DialEnv()
    env.reset(seed=0)
    with pytest.raises(DialConfigError, match="9 elements"):
        env.step(np.zeros(8))


def test_determinism_under_seed() -> None:
    def rollout(seed: int) -> np.ndarray:
        env = DialEnv()
        obs = [env.reset(seed=seed)[0]]
        rng = np.random.default_rng(7)
        for _ in range(10):
            obs.append(env.step(rng.uniform(-0.3, 0.3, 9))[0])
        return np.array(obs)

    a, b, c = rollout(11), rollout(11), rollout(12)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_gym_make() -> None:
    env = gym.make(ENV_ID)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (39,)
    obs, _, _, _, info = env.step(env.action_space.sample())
    assert obs.shape == (39,) and "subtasks_done" in info
    env.close()
