"""The Gymnasium environment passes Gymnasium's checker and behaves."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tdacm.envs  # noqa: F401  (registers the id)


@pytest.fixture(scope="module")
def env():
    e = gym.make("tdacm/TipServo-v0", max_steps=5).unwrapped
    yield e
    e.close()


def test_env_checker(env):
    check_env(env, skip_render_check=True)


def test_reset_is_seeded_and_observation_is_consistent(env):
    o1, info1 = env.reset(seed=3)
    o2, _ = env.reset(seed=3)
    assert np.array_equal(o1, o2)
    assert env.observation_space.contains(o1)
    assert info1["detected"] and o1[14] == 1.0
    assert np.isclose(
        -info1["rmse"],
        -np.sqrt(np.mean(np.sum((o1[6:14].reshape(4, 2) - env.desired_points) ** 2, 1))),
        atol=1e-5,
    )


def test_servoing_action_reduces_error(env):
    """The IBVS twist used as the action (an expert policy) lowers the image error over 1 s.
    The env applies the scenario's command shaping (soft start 0.4 s, rate filter 0.15 s), as
    `tdacm run` does, so the first 0.4 s barely move the camera (the scenario itself goes from
    0.392 to 0.389 in 0.4 s and to 0.288 in 1 s)."""
    obs, info = env.reset(seed=0)
    start = info["rmse"]
    for _ in range(50):
        twist = env.loop.servo.ibvs.twist(obs[6:14].reshape(4, 2).astype(float), env.desired_depths)
        action = np.clip(np.asarray(twist) / env.scale, -1, 1).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == pytest.approx(-info["rmse"]) or info["success"]
    assert info["rmse"] < 0.8 * start


def test_bad_action_is_refused(env):
    env.reset(seed=1)
    with pytest.raises(ValueError, match="action must be"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="action_type"):
        gym.make("tdacm/TipServo-v0", action_type="torques")


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_env_steps(mode):
    """The env works under gymnasium.vector, in one process and in worker processes (the
    loop's blocks hold no shared state and pickle through the env's constructor)."""
    envs = gym.make_vec(
        "tdacm/TipServo-v0",
        num_envs=2,
        vectorization_mode=mode,
        overrides={"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}},
    )
    try:
        obs, _ = envs.reset(seed=0)
        assert obs.shape == (2, envs.single_observation_space.shape[0])
        obs, reward, term, trunc, info = envs.step(np.zeros((2, 6), np.float32))
        assert obs.shape[0] == 2 and np.all(np.isfinite(reward))
    finally:
        envs.close()


def test_env_has_the_scenario_disturbances():
    """flight-test-c's aerodynamics and turbulence, and the vibrating base wrench and downwash
    of an ablation, act in the env's plant."""
    e = gym.make(
        "tdacm/TipServo-v0",
        scenario="flight-test-c",
        overrides={
            "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
            "disturbances": {
                "base_wrench_amplitude": [0.01, 0.01, 0.005, 0.2, 0.2, 0.3],
                "base_wrench_frequency": 8.0,
                "downwash": [0.0, 0.0, -0.1],
                "downwash_noise": 0.02,
            },
        },
    ).unwrapped
    try:
        assert e.loop.plant.aero is not None and e.loop.plant.wind is not None
        assert e.loop.plant.disturbances.active
        e.reset(seed=0)
        loads = e.loop.plant.disturbances.loads_at(1 / 32, e.loop.plant.rng, True)
        assert np.allclose(loads["base_wrench"], [0.01, 0.01, 0.005, 0.2, 0.2, 0.3])
        assert "rod_force" in loads
        e.step(np.zeros(6, np.float32))
    finally:
        e.close()
