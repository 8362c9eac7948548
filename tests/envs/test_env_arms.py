"""The Gymnasium env on a robot of two arms (``dual-in-fov``): Gymnasium's checker, the
observation's per-arm blocks, the stacked twist action, a view per arm."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tdacm.envs  # noqa: F401  (registers the id)


@pytest.fixture(scope="module")
def env():
    e = gym.make(
        "tdacm/TipServo-v0", scenario="dual-in-fov", max_steps=5, render_mode="rgb_array"
    ).unwrapped
    yield e
    e.close()


def _ibvs_action(env) -> np.ndarray:
    """Each arm's own IBVS twist (its servo's perception of this period), as an action."""
    loop, sensed = env.loop, env._sensed
    twists = [
        servo.perceive_period(loop.plant.state.t, loop.dt, view, sensed.estimate).ibvs_twist
        for servo, view in zip(env._arm_servos, sensed.view.arms, strict=True)
    ]
    return np.clip(np.concatenate(twists) / env.scale, -1, 1).astype(np.float32)


def _arm_rmse(env, obs, k) -> float:
    pts = obs[15 * k + 6 : 15 * k + 14].reshape(4, 2).astype(float) * env.point_scales[k]
    return float(np.sqrt(np.mean(np.sum((pts - env._arm_servos[k].desired_points) ** 2, 1))))


def test_two_arm_env_passes_the_checker(env):
    assert env.action_space.shape == (12,)
    assert env.observation_space.shape == (30 + 2 * env.n,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)


def test_observation_has_one_block_per_arm_and_the_state_once(env):
    obs, info = env.reset(seed=4)
    assert env.observation_space.contains(obs)
    assert obs[14] == 1.0 and obs[29] == 1.0 and info["detected"]
    rmses = [_arm_rmse(env, obs, k) for k in (0, 1)]
    assert rmses[0] != pytest.approx(rmses[1], abs=1e-3)  # two different views
    assert info["rmse"] == pytest.approx(max(rmses), abs=1e-5)  # the worse arm's
    q = env._sensed.estimate.q
    assert np.allclose(obs[30 : 30 + env.n], (q - env.world.q_star) / env.q_scale, atol=1e-5)


def test_each_arms_ibvs_twist_as_the_action_servoes_both_arms(env):
    """The arms' IBVS twists (12 values) as the action lower both arms' image errors over
    1 s (through the joint mapping of both arms and the shared drone)."""
    env.max_steps = 100
    obs, _ = env.reset(seed=0)
    start = [_arm_rmse(env, obs, k) for k in (0, 1)]
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(_ibvs_action(env))
        assert not terminated
        assert reward == pytest.approx(-info["rmse"])
    end = [_arm_rmse(env, obs, k) for k in (0, 1)]
    assert end[0] < 0.6 * start[0] and end[1] < 0.6 * start[1], (start, end)
    env.max_steps = 5


def test_render_shows_each_arms_view_side_by_side(env):
    env.reset(seed=0)
    img = env.render()
    cam = env.loop.sensors.local.camera
    assert img.shape == (cam.height, 2 * cam.width, 3) and img.dtype == np.uint8
    assert img[:, : cam.width].std() > 10 and img[:, cam.width :].std() > 10


def test_the_vector_env_steps_two_arms_as_the_single_env():
    """``gym.make_vec`` on ``dual-in-fov``: the same spaces as the single env (12 actions,
    one block per arm), and world 1 of ``reset(seed=3)`` follows ``TipServoEnv.reset(seed=4)``
    under a fixed twist per arm: observations, plant states and rewards over 10 steps."""
    from tdacm.envs.servo import TipServoEnv

    vec = gym.make_vec(
        "tdacm/TipServo-v0", num_envs=2, vectorization_mode="vector_entry_point",
        scenario="dual-in-fov", max_steps=20,
    )  # fmt: skip
    single = TipServoEnv(scenario="dual-in-fov", max_steps=20)
    try:
        assert vec.single_action_space.shape == single.action_space.shape == (12,)
        assert vec.single_observation_space.shape == single.observation_space.shape
        obs, _ = vec.reset(seed=3)
        o1, _ = single.reset(seed=4)
        np.testing.assert_allclose(obs[1], o1, rtol=0, atol=1e-9)
        a = np.tile(np.linspace(-0.3, 0.3, 12, dtype=np.float32), (2, 1))
        for _ in range(10):
            obs, r, te, tr, _ = vec.step(a)
            o1, r1, te1, tr1, _ = single.step(a[1])
            np.testing.assert_allclose(obs[1], o1, rtol=0, atol=1e-9)
            np.testing.assert_allclose(
                vec.unwrapped.batch.data.q[1], single.loop.plant.state.q, rtol=0, atol=1e-9
            )
            assert r[1] == pytest.approx(r1, abs=1e-9)
            assert (te[1], tr[1]) == (te1, tr1)
    finally:
        vec.close()
        single.close()
