"""Run by test_async_vector_after_the_parent_used_an_env (a subprocess, so that a hang is
killed by the test's timeout): the parent makes an env, renders C_G with PyBullet (EGL when
available), closes it, then steps an AsyncVectorEnv of two forked workers that render C_G too."""

import sys

import gymnasium as gym
import numpy as np

import tdacm.envs  # noqa: F401  (registers the id)

PYBULLET = {"cameras": {"global_renderer": "pybullet", "global_backend": "auto"}}


def make(overrides=None):
    env = gym.make("tdacm/TipServo-v0", overrides=overrides)
    if overrides:  # render C_G once: the renderer starts in this process
        loop = env.unwrapped.loop
        loop.sensors.global_.measure(loop.plant.state)
    return env


def main(with_pybullet: bool) -> None:
    ov = PYBULLET if with_pybullet else None
    e = make(ov)
    e.reset(seed=0)
    e.close()
    envs = gym.vector.AsyncVectorEnv([lambda: make(ov)] * 2)
    try:
        obs, _ = envs.reset(seed=0)
        for _ in range(5):
            obs, reward, term, trunc, info = envs.step(np.zeros((2, 6), np.float32))
        assert obs.shape[0] == 2 and np.all(np.isfinite(reward))
    finally:
        envs.close()
    print("done")


if __name__ == "__main__":
    main(sys.argv[1:] == ["pybullet"])
