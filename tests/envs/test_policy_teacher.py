"""The imitation teacher (:func:`tdacm.envs.teacher.teacher_twists`): the twist the servo
would command on the current observation, exactly, without changing the worlds."""

import gymnasium as gym
import numpy as np

import tdacm.envs  # noqa: F401  (registers the id)
from tdacm.envs.teacher import teacher_twists

#: the robustness campaigns' initial spread of paper-in-fov (examples/train_ppo.py)
SPREAD = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)


def _env(n=6, **kw):
    return gym.make_vec("tdacm/TipServo-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        init_noise=SPREAD, max_steps=40, threads=1, **kw)  # fmt: skip


def test_teacher_is_the_twist_the_servo_then_applies():
    """With NaN actions (the servo's own twist), the teacher's twist before each step is the
    twist the step applies, to the bit; with pixel noise and autoresets."""
    env = _env(overrides={"sensors": {"pixel_noise": 1.0}})
    u = env.unwrapped
    env.reset(seed=3)
    nan = np.full((6, 6), np.nan)
    compared = 0
    for _ in range(45):  # past the 40-step horizon: autoresets included
        label = teacher_twists(env)
        stepping = ~u._autoreset.copy()
        env.step(nan)
        ok = stepping & np.isfinite(label).all(axis=1)
        np.testing.assert_array_equal(label[ok], u.batch.data.robot_out.twist[ok])
        compared += ok.sum()
    assert compared > 200
    env.close()


def test_teacher_does_not_change_the_worlds():
    """Asking the teacher between steps leaves a learner's trajectory unchanged (it works on
    a copy of the target filter's state)."""
    runs = []
    for ask in (False, True):
        env = _env(4)
        obs, _ = env.reset(seed=11)
        traj = []
        for k in range(15):
            if ask:
                teacher_twists(env)
            obs, *_ = env.step(np.full((4, 6), 0.1 * np.sin(k)))
            traj.append(obs)
        runs.append(np.array(traj))
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])
