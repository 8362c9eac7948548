"""The Gymnasium environment passes Gymnasium's checker and behaves."""

import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tdacm.envs  # noqa: F401  (registers the id)
from tdacm.envs.servo import FEATURE_SCALE, OBS_CLIP
from tdacm.loop.data import Termination
from tdacm.sim import load_scenario
from tdacm.sim.assemble import build_loop, reseed


@pytest.fixture(scope="module")
def env():
    e = gym.make("tdacm/TipServo-v0", max_steps=5, render_mode="rgb_array").unwrapped
    yield e
    e.close()


def test_env_checker_without_warnings(env):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)


def test_render_is_an_rgb_image(env):
    env.reset(seed=0)
    img = env.render()
    cam = env.loop.sensors.local.camera
    assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.uint8
    assert img.std() > 10  # the scene, not a blank frame


def test_observation_is_scaled_and_of_fixed_size(env):
    o1, info1 = env.reset(seed=3)
    o2, _ = env.reset(seed=3)
    assert np.array_equal(o1, o2)
    assert o1.shape == (15 + 2 * env.n,) and env.observation_space.contains(o1)
    assert info1["detected"] and o1[14] == 1.0
    pts = o1[6:14].reshape(4, 2) * env.point_scale  # +-1 is the image border
    assert np.all(np.abs(o1[6:14]) < 1)
    assert np.isclose(
        info1["rmse"], np.sqrt(np.mean(np.sum((pts - env.desired_points) ** 2, 1))), atol=1e-5
    )
    err = env.loop.servo.observe(env._sensed.view, env._sensed.estimate.q)[3]
    assert np.allclose(o1[:6], np.clip(err / FEATURE_SCALE, -OBS_CLIP, OBS_CLIP), atol=1e-6)
    # the state part: offset from the desired configuration (z: 5 m -> 3 m is +2 m)
    assert o1[15 + 5] == pytest.approx(2.0, abs=0.1)


def test_reset_reuses_the_loop_and_a_seed_gives_its_own_streams(env):
    loop = env.loop
    env.reset(seed=1)
    s1 = env._seed
    d1 = env.assembly.model.d_m.copy()
    t0 = time.perf_counter()
    env.reset(seed=2)
    assert time.perf_counter() - t0 < 0.2  # a rebuild takes about 1 s
    assert env.loop is loop and env._seed != s1
    assert not np.array_equal(env.assembly.model.d_m, d1)  # another model perturbation
    env.reset(seed=1)
    assert env._seed == s1 and np.array_equal(env.assembly.model.d_m, d1)


def test_reseeded_loop_runs_as_a_loop_built_with_that_seed():
    """Pixel noise and a model perturbation drawn from the seed: reseeding in place gives the
    run a loop built with the seed gives, sample for sample."""
    sc = load_scenario("paper-in-fov").with_overrides(
        {
            "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
            "sensors": {"pixel_noise": 1.0},
            "disturbances": {"downwash": [0.0, 0.0, -0.5], "downwash_noise": 0.2},
        }
    )
    fresh = build_loop(sc, 7).loop.run(0.3).arrays
    a = build_loop(sc, 3)
    a.loop.run(0.1)  # used with another seed first
    a.loop.plant.reset(a.world.q0, a.world.qd0)
    again = reseed(a, 7).loop.run(0.3).arrays
    for k in ("q", "u", "points_local"):
        assert np.array_equal(fresh[k], again[k], equal_nan=True), k


def test_servoing_action_reduces_error(env):
    """The IBVS twist used as the action (an expert policy) lowers the image error over 1 s.
    The env applies the scenario's command shaping (soft start 0.4 s, rate filter 0.15 s), as
    `tdacm run` does, so the first 0.4 s barely move the camera (the scenario itself goes from
    0.392 to 0.389 in 0.4 s and to 0.288 in 1 s)."""
    env.max_steps = 100
    obs, info = env.reset(seed=0)
    start = info["rmse"]
    for _ in range(50):
        pts = obs[6:14].reshape(4, 2).astype(float) * env.point_scale
        twist = env.loop.servo.ibvs.twist(pts, env.desired_depths)
        action = np.clip(np.asarray(twist) / env.scale, -1, 1).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == pytest.approx(-info["rmse"]) or info["success"]
    assert info["rmse"] < 0.8 * start
    env.max_steps = 5


def test_bad_action_is_refused(env):
    env.reset(seed=1)
    with pytest.raises(ValueError, match="action must be"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="action_type"):
        gym.make("tdacm/TipServo-v0", action_type="torques")


def test_random_actuator_actions_end_with_named_terminations():
    """A newcomer's first try: random thrusts and tensions for 200 steps. Episodes end (the
    drone tumbles, the target leaves C_L or maps behind C_V) with a named termination and the
    failure reward; no exception."""
    e = gym.make("tdacm/TipServo-v0", action_type="actuators")
    e.action_space.seed(0)
    e.reset(seed=1)
    ends = []
    try:
        for _ in range(200):
            obs, reward, term, trunc, info = e.step(e.action_space.sample())
            assert e.observation_space.contains(obs)
            if term or trunc:
                ends.append(info["termination"])
                if term:
                    assert isinstance(info["termination"], Termination) and info["reason"]
                e.reset()
    finally:
        e.close()
    assert ends and all(t is not None and t != Termination.SUCCESS for t in ends)


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_env_steps(mode):
    """The env works under gymnasium.vector, in one process and in worker processes (the
    loop's blocks hold no shared state and pickle through the env's constructor)."""
    envs = gym.make_vec("tdacm/TipServo-v0", num_envs=2, vectorization_mode=mode)
    try:
        obs, _ = envs.reset(seed=0)
        assert obs.shape == (2, envs.single_observation_space.shape[0])
        obs, reward, term, trunc, info = envs.step(np.zeros((2, 6), np.float32))
        assert obs.shape[0] == 2 and np.all(np.isfinite(reward))
    finally:
        envs.close()


@pytest.mark.parametrize("renderer", ["default", "pybullet"])
def test_async_vector_after_the_parent_used_an_env(renderer):
    """make, reset, close an env; then AsyncVectorEnv([make] * 2).reset(seed=0) and steps. With
    PyBullet's EGL renderer started in the parent before the fork, a forked worker that used
    EGL would hang in Mesa; the workers render with TinyRenderer. A subprocess with a timeout: a hang
    fails the test."""
    script = Path(__file__).with_name("_async_after_parent.py")
    args = [sys.executable, str(script)] + (["pybullet"] if renderer == "pybullet" else [])
    p = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        out, err = p.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)  # the script and its hung workers
        p.communicate()
        pytest.fail("AsyncVectorEnv hung after the parent used an env")
    assert p.returncode == 0 and "done" in out, err[-2000:]


def test_env_has_the_scenario_disturbances():
    """flight-test-c's aerodynamics and turbulence, and the vibrating base wrench and downwash
    of an ablation, act in the env's plant."""
    e = gym.make(
        "tdacm/TipServo-v0",
        scenario="flight-test-c",
        overrides={
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
