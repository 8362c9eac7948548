"""The vector env on the batched engine: Gymnasium's vector API, each world the single env,
autoreset per Gymnasium (``NEXT_STEP``), a world's run independent of the number of worlds.

Seeds: world ``i`` of ``reset(seed=s)`` draws its loop seed and initial offset from its own
generator seeded ``s + i``, exactly as ``TipServoEnv.reset(seed=s + i)`` does, so the single
env and the world share the model error and the offset: the comparison runs the default
configuration (init offset and model perturbation on) without overriding them. The scenario's
sensors are noise-free; with noise, the engine's streams (counter-based) differ from the block
loop's, so equality with the single env is tested noise-free and the noisy runs are compared
between vector envs of different sizes.
"""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

import tdacm.envs  # noqa: F401  (registers the id)
from tdacm.envs import TipServoEnv, TipServoVectorEnv
from tdacm.loop.data import Termination

ID = "tdacm/TipServo-v0"


def _vec(num_envs, **kw):
    return gym.make_vec(ID, num_envs=num_envs, vectorization_mode="vector_entry_point", **kw)


@pytest.fixture(scope="module")
def single():
    e = TipServoEnv()
    yield e
    e.close()


def test_make_vec_gives_the_vector_env_with_the_single_spaces(single):
    env = _vec(3)
    try:
        assert isinstance(env, VectorEnv) and isinstance(env, TipServoVectorEnv)
        assert env.num_envs == 3
        assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
        assert env.single_observation_space == single.observation_space
        assert env.single_action_space == single.action_space
        assert env.observation_space == batch_space(single.observation_space, 3)
        assert env.action_space == batch_space(single.action_space, 3)
        obs, info = env.reset(seed=0)
        assert obs.dtype == np.float32 and env.observation_space.contains(obs)
        assert info["_rmse"].all() and info["detected"].all()
        obs, reward, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert reward.shape == term.shape == trunc.shape == (3,)
        for key in ("rmse", "detected", "success", "termination", "reason"):
            assert info[key].shape == (3,) and info[f"_{key}"].all()
    finally:
        env.close()


#: the EKF's estimates with noiseless, unbiased sensors (the engine's and the single env's
#: random streams differ; without noise both run the same numbers)
ESTIMATED = {
    "estimation": {"source": "estimated"},
    "sensors": {
        "accel_bias": 0.0, "accel_noise": 0.0, "gyro_bias": 0.0, "gyro_noise": 0.0,
        "encoder_noise": 0.0, "encoder_resolution": 0.0, "pose_attitude_noise": 0.0,
        "pose_position_noise": 0.0,
    },
}  # fmt: skip


@pytest.mark.parametrize(
    "overrides",
    [
        None,
        {"ibvs": {"features": "measured"}},
        {"sensors": {"intrinsics_error": 0.03}},
        ESTIMATED,  # the observation holds the EKF's estimate of the state
    ],
)
def test_each_world_follows_the_single_env(overrides):
    """Worlds 0 and 2 of ``reset(seed=7)`` against ``TipServoEnv.reset(seed=7 + i)`` under a
    fixed twist: the observation (1e-9; float32 equal), the plant state (1e-9), the reward and
    the flags at each of 20 steps: on the robust servo's predicted features (the default), on
    the measured points, and with a camera intrinsics error (each world's own camera model and
    reference snapshot, drawn from its seed)."""
    env = _vec(3, overrides=overrides)
    single = TipServoEnv(overrides=overrides)
    try:
        obs, info = env.reset(seed=7)
        a = np.tile(np.array([0.1, -0.2, 0.3, 0.2, -0.1, 0.4], np.float32), (3, 1))
        traj = [(obs, None, None, None)]
        states = [env.unwrapped.batch.data.q.copy()]
        for _ in range(20):
            o, r, te, tr, _ = env.step(a)
            traj.append((o, r, te, tr))
            states.append(env.unwrapped.batch.data.q.copy())
        seeds = info["loop_seed"]
        for w in (0, 2):
            o1, i1 = single.reset(seed=7 + w)
            assert i1["loop_seed"] == seeds[w]
            np.testing.assert_allclose(traj[0][0][w], o1, rtol=0, atol=1e-9)
            for k in range(1, 21):
                o1, r1, te1, tr1, _ = single.step(a[w])
                o, r, te, tr = traj[k]
                np.testing.assert_allclose(o[w], o1, rtol=0, atol=1e-9)
                np.testing.assert_allclose(
                    states[k][w], single.loop.plant.state.q, rtol=0, atol=1e-9
                )
                assert r[w] == pytest.approx(r1, abs=1e-9)
                assert (te[w], tr[w]) == (te1, tr1) == (False, False)
        assert not np.allclose(traj[-1][0][0], traj[-1][0][2])  # other seeds, other runs
    finally:
        env.close()
        single.close()


def test_autoreset_next_step_after_truncation():
    """After ``max_steps`` the worlds truncate; the next step returns each world's reset
    observation (reward 0, flags false) from the next draws of its generator: a new loop seed,
    a new initial offset (roll, pitch and the velocities as the scenario's start)."""
    env = _vec(2, max_steps=3)
    u = env.unwrapped
    try:
        _, info0 = env.reset(seed=3)
        zero = np.zeros((2, 6), np.float32)
        for k in range(3):
            _, r, te, tr, info = env.step(zero)
            assert not te.any() and tr.all() == (k == 2)
            assert np.all(r < 0)
        assert list(info["termination"]) == [None, None]
        obs, r, te, tr, info = env.step(np.ones((2, 6), np.float32))  # ignored: a reset
        assert np.all(r == 0) and not te.any() and not tr.any()
        assert info["_loop_seed"].all() and not info["_success"].any()
        n = u.n
        for w in range(2):
            rng = np.random.default_rng(3 + w)  # the world's generator: Gymnasium's seeding
            assert int(rng.integers(2**31)) == info0["loop_seed"][w]
            rng.normal(0.0, u.init_noise, size=n)
            assert int(rng.integers(2**31)) == info["loop_seed"][w] != info0["loop_seed"][w]
            q = u.q0 + rng.normal(0.0, u.init_noise, size=n)
            q[:2] = u.q0[:2]
            expect = np.clip((q - u.q_star) / u.q_scale, -5, 5)
            np.testing.assert_allclose(obs[w, 15 : 15 + n], expect, atol=1e-6)
            assert np.all(obs[w, 15 + n :] == 0)  # at rest
        _, r, te, tr, _ = env.step(zero)  # the new episode runs
        assert np.all(r < 0) and not (te | tr).any()
    finally:
        env.close()


def test_a_success_ends_then_the_world_restarts():
    """With a success threshold every start meets, each step ends the episode (``success``,
    the bonus) and the next one restarts it (reward 0, not done): Gymnasium's NEXT_STEP."""
    env = _vec(2, success_rmse=10.0, success_bonus=5.0)
    try:
        env.reset(seed=0)
        zero = np.zeros((2, 6), np.float32)
        for _ in range(2):
            _, r, te, tr, info = env.step(zero)
            assert te.all() and not tr.any() and info["success"].all()
            assert all(t == Termination.SUCCESS for t in info["termination"])
            np.testing.assert_allclose(r, 5.0 - info["rmse"])
            obs, r, te, tr, info = env.step(zero)
            assert np.all(r == 0) and not (te | tr).any() and np.all(obs[:, 14] == 1)
    finally:
        env.close()


def test_a_failure_pays_the_steps_left_as_lost():
    """Twists that turn the camera away: the target leaves the view and the world ends as a
    failure (the env's ``target lost`` after ``max_lost`` = 3 frames, before the servo's
    recovery starts after ``recovery.lose`` = 5), with ``-lost_penalty`` for each step left.
    On the measured points: the robust servo's prediction outlives the view (its own
    ``lost_timeout`` decides the loss)."""
    env = _vec(1, max_steps=100, lost_penalty=2.0, max_lost=3,
               overrides={"ibvs": {"features": "measured"}})  # fmt: skip
    try:
        env.reset(seed=1)
        a = np.array([[1.0, 1.0, 1.0, 1.0, 1.0, 0.0]], np.float32)
        k, te = 0, [False]
        while not te[0] and k < 99:
            _, r, te, tr, info = env.step(a)
            k += 1
        assert te[0] and not info["success"][0]
        assert info["termination"][0] == Termination.TARGET_LOST
        assert r[0] <= -2.0 * (100 - k)
    finally:
        env.close()


def test_a_world_does_not_depend_on_the_number_of_worlds():
    """With pixel noise and dropped frames, random actions and autoresets, world 3 of
    ``reset(seed=10)`` with 5 worlds on 2 threads gives bit-identical observations, rewards and
    flags as the only world of ``reset(seed=13)`` on 1 thread."""
    kw = {
        "max_steps": 6,
        "overrides": {"sensors": {"pixel_noise": 1.0, "dropout": 0.1}},
    }
    e5, e1 = _vec(5, threads=2, **kw), _vec(1, threads=1, **kw)
    try:
        o5, _ = e5.reset(seed=10)
        o1, _ = e1.reset(seed=13)
        np.testing.assert_array_equal(o5[3], o1[0])
        rng = np.random.default_rng(0)
        dones = 0
        for _ in range(16):
            a = rng.uniform(-1, 1, (5, 6)).astype(np.float32)
            o5, r5, te5, tr5, _ = e5.step(a)
            o1, r1, te1, tr1, _ = e1.step(a[3:4])
            np.testing.assert_array_equal(o5[3], o1[0])
            assert r5[3] == r1[0] and te5[3] == te1[0] and tr5[3] == tr1[0]
            dones += bool(te1[0] or tr1[0])
        assert dones >= 2  # autoresets happened
        assert not np.array_equal(o5[2], o5[3])
    finally:
        e5.close()
        e1.close()


def test_a_randomized_world_does_not_depend_on_the_number_of_worlds():
    """Domain randomization on (every range at its limit): each reset world draws its robot
    and sensor parameters from its own generator; world 3 of ``reset(seed=10)`` with 5 worlds
    on 2 threads equals the only world of ``reset(seed=13)`` bit for bit, through autoresets
    (new draws), and the worlds' parameters differ within their ranges."""
    from tdacm.envs.options import RANDOMIZATION_LIMITS

    kw = {"max_steps": 5, "randomize": dict(RANDOMIZATION_LIMITS)}
    e5, e1 = _vec(5, threads=2, **kw), _vec(1, threads=1, **kw)
    try:
        o5, _ = e5.reset(seed=10)
        o1, _ = e1.reset(seed=13)
        np.testing.assert_array_equal(o5[3], o1[0])
        m5, m1 = e5.unwrapped.batch.model, e1.unwrapped.batch.model
        k = m5.robot.stiffness[:, -1, -1] / m5.robot.stiffness[0, -1, -1]
        assert len(set(k)) == 5 and np.all(np.abs(k - 1) <= 0.2)
        cam5, cam1 = m5.sensor, m1.sensor  # the tip cameras' records (world, arm)
        assert set(cam5.latency[:, 0]) <= {0, 1, 2}
        assert np.all((cam5.pixel_noise[:, 0] >= 0) & (cam5.pixel_noise[:, 0] <= 2.0))
        rng = np.random.default_rng(1)
        dones = 0
        for _ in range(12):
            a = rng.uniform(-1, 1, (5, 6)).astype(np.float32)
            o5, r5, te5, tr5, _ = e5.step(a)
            o1, r1, te1, tr1, _ = e1.step(a[3:4])
            np.testing.assert_array_equal(o5[3], o1[0])
            assert r5[3] == r1[0] and te5[3] == te1[0] and tr5[3] == tr1[0]
            np.testing.assert_array_equal(m5.robot.stiffness[3], m1.robot.stiffness[0])
            np.testing.assert_array_equal(cam5.pixel_noise[3], cam1.pixel_noise[0])
            np.testing.assert_array_equal(cam5.latency[3], cam1.latency[0])
            dones += bool(te1[0] or tr1[0])
        assert dones >= 2  # autoresets drew again
    finally:
        e5.close()
        e1.close()


def test_resetting_some_worlds_leaves_the_others_running():
    """``reset(options={"reset_mask": ...})`` restarts only the masked worlds; world 1 runs on
    exactly as in an env where nothing was reset."""
    a = np.tile(np.array([0.2, 0.0, -0.2, 0.1, 0.1, 0.0], np.float32), (2, 1))
    ref, env = _vec(2), _vec(2)
    try:
        ref.reset(seed=4)
        env.reset(seed=4)
        for _ in range(3):
            ref.step(a)
            env.step(a)
        obs, info = env.reset(options={"reset_mask": np.array([True, False])})
        assert info["_loop_seed"].tolist() == [True, False]
        for _ in range(3):
            o_ref, r_ref, *_ = ref.step(a)
            o, r, *_ = env.step(a)
            np.testing.assert_array_equal(o[1], o_ref[1])
            assert r[1] == r_ref[1]
            assert not np.array_equal(o[0], o_ref[0])
    finally:
        ref.close()
        env.close()


def _follow_the_teacher(env, single, steps, pinned):
    """``steps`` steps of both envs acting world 1's teacher twists (the servo's own, zero
    where it sees nothing): world 1's observation, state, reward and flags equal the single
    env's (1e-9) at each step. Returns how many steps ``pinned()`` held in the single env."""
    from tdacm.envs.teacher import teacher_twists

    scale = env.unwrapped.scale
    count = 0
    for _ in range(steps):
        a = np.nan_to_num(teacher_twists(env) / scale)
        a = np.clip(a, -1.0, 1.0).astype(np.float32)
        obs, r, te, tr, _ = env.step(a)
        o1, r1, te1, tr1, _ = single.step(a[1])
        np.testing.assert_allclose(obs[1], o1, rtol=0, atol=1e-9)
        np.testing.assert_allclose(
            env.unwrapped.batch.data.q[1], single.loop.plant.state.q, rtol=0, atol=1e-9
        )
        assert r[1] == pytest.approx(r1, abs=1e-9) and (te[1], tr[1]) == (te1, tr1)
        count += bool(pinned())
    return count


def test_servoing_into_contact_follows_the_single_env():
    """``touch-target`` started 0.18 m above its standoff view, both envs acting the servo's
    own twist (the teacher's, zero where it sees nothing): world 1's observation, state,
    reward and flags equal the single env's (1e-9) at each of 640 steps, through the touch,
    after which the observation is the touch law's view pinned in C_L (measured on seeds 3, 5
    and 12 in the single env: touched after 548-589 steps)."""
    from tdacm.sim import load_scenario

    q0 = list(load_scenario("touch-target").data["initial"]["q"])
    q0[5] = 2.0
    kw = {"scenario": "touch-target", "init_noise": 0.0, "hold_success": True,
          "max_steps": 1000, "max_lost": 1000, "overrides": {"initial": {"q": q0}}}  # fmt: skip
    env = _vec(2, max_episode_steps=1000, **kw)  # the single env's horizon (no time limit)
    single = TipServoEnv(**kw)
    try:
        obs, _ = env.reset(seed=20)
        o1, _ = single.reset(seed=21)
        np.testing.assert_allclose(obs[1], o1, rtol=0, atol=1e-9)
        servo = single.loop.servo
        pinned = _follow_the_teacher(
            env, single, 640, lambda: servo.touched and servo.phase in ("contact", "hold")
        )
        assert pinned >= 20  # the pinned view was observed
    finally:
        env.close()
        single.close()


def test_the_squeeze_follows_the_single_env():
    """``dual-squeeze`` started 1 cm above its contact pose with a 1 cm standoff and no model
    error, both envs acting the servo's own twists (the teacher's), success judged at the
    end (``hold_success``): world 1's observation (both arms' blocks), state, reward and
    flags equal the single env's (1e-9) at each of 360 steps, through both touches (measured:
    both probes down at step 273), after which each arm's block is the squeeze's view pinned
    in its C_L."""
    from tdacm.sim import load_scenario

    q0 = list(load_scenario("dual-squeeze").data["desired"]["q"])
    q0[5] += 0.01
    # no model error: with the seeds' 10 % the probes may stop short of the ball (the estimate's
    # bias below detect_force), in both envs alike
    ov = {"initial": {"q": q0}, "touch": {"standoff": 0.01, "dwell": 0.1},
          "model": {"perturbation": 0.0}}  # fmt: skip
    kw = {"scenario": "dual-squeeze", "init_noise": 0.0, "hold_success": True,
          "max_steps": 1000, "max_lost": 1000, "overrides": ov}  # fmt: skip
    env = _vec(2, max_episode_steps=1000, **kw)
    single = TipServoEnv(**kw)
    try:
        obs, _ = env.reset(seed=30)
        o1, _ = single.reset(seed=31)
        assert obs.shape[1] == o1.shape[0] == env.unwrapped.single_observation_space.shape[0]
        np.testing.assert_allclose(obs[1], o1, rtol=0, atol=1e-9)
        state = single.loop.servo.squeeze_state
        pinned = _follow_the_teacher(env, single, 360, lambda: bool(state.pinned.all()))
        assert pinned >= 20  # both arms' pinned views were observed
    finally:
        env.close()
        single.close()


def test_refusals_name_the_option():
    with pytest.raises(ValueError, match="action_type"):
        TipServoVectorEnv(2, action_type="actuators")
    with pytest.raises(ValueError, match="render_mode"):
        TipServoVectorEnv(2, render_mode="rgb_array")
    env = _vec(2)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="actions"):
            env.step(np.zeros((3, 6)))
        with pytest.raises(ValueError, match="actions"):
            env.step(np.array([[np.nan, 0, 0, 0, 0, 0], [0] * 6]))
    finally:
        env.close()


def test_hold_success_is_judged_at_the_last_step_and_agrees_with_the_single_env(single):
    """``hold_success``: reaching the threshold does not end the episode; the last step
    succeeds when the RMSE stayed at or below it (threshold every pose meets: success at step
    3 of 3, with the bonus); a threshold between the start and a later RMSE, left after it
    was reached, fails. World 0 against the single env of the same seed."""
    kw = dict(success_rmse=10.0, success_bonus=5.0, hold_success=True, max_steps=3)
    env = _vec(2, **kw)
    one = TipServoEnv(**kw)
    try:
        env.reset(seed=4)
        one.reset(seed=4)
        zero = np.zeros((2, 6), np.float32)
        for k in range(3):
            _, r, te, tr, info = env.step(zero)
            _, r1, te1, tr1, info1 = one.step(zero[0])
            assert te[0] == te1 and info["success"][0] == info1["success"]
            np.testing.assert_allclose(r[0], r1)
            if k < 2:
                assert not (te | tr).any() and not info["success"].any()
        assert te.all() and info["success"].all()
        np.testing.assert_allclose(r, 5.0 - info["rmse"])
    finally:
        env.close()
        one.close()
