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
    """The IBVS twist used as the action (an expert policy) lowers the image error over 0.4 s
    (the first steps are a transient of the low-level loop)."""
    obs, info = env.reset(seed=0)
    start = info["rmse"]
    for _ in range(20):
        twist = env.servo.controller.twist(
            obs[6:14].reshape(4, 2).astype(float), env.desired_depths
        )
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
