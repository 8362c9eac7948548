"""The batched engine against the block loop whose compiled steps it calls, and its
determinism.

With every random element off, each batched world equals :class:`tdacm.loop.ClosedLoop` with
analytic cameras on the same scenario bit for bit over the run (both call the same compiled
steps on the same records). With noise, a world's run depends only on its seed: not on the
batch size, its index in the batch or the number of threads stepping the batch.
"""

import numpy as np
import pytest

from tdacm.sim.assemble import build_loop
from tdacm.sim.batch import build_batch
from tdacm.sim.scenario import ScenarioError, load_scenario

#: the engine's configuration: analytic cameras, the servo on the measured points (the
#: cases below with PREDICTED: on the features predicted from the target filter)
ENGINE = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
    "ibvs": {"features": "measured"},
}
#: the robust servo: features predicted from the target filter (the shipped default)
PREDICTED = {"ibvs": {"features": "predicted"}}
#: flight test C's air without its random part (the turbulence), with a steady wind and a gust
STEADY_AIR = {
    "wind": {
        "turbulence_wind20": 0.0,
        "velocity": [0.3, -0.2, 0.0],
        "gust_amplitude": [0.5, 0.0, 0.0],
        "gust_start": 0.5,
    }
}


def _scenario(name, extra=None, duration=None):
    ov = {**ENGINE, **(extra or {})}
    if duration is not None:
        ov["duration"] = duration
    return load_scenario(name).with_overrides(ov, "engine configuration")


@pytest.mark.parametrize(
    "name, extra, duration",
    [
        ("paper-in-fov", None, 2.0),
        ("paper-in-fov", PREDICTED, 2.0),  # as shipped: the robust servo's target filter
        ("ground-test-a", None, 1.5),
        ("custom-robot-example", None, 1.5),
        ("flight-test-c", STEADY_AIR, 1.5),
        ("paper-out-of-fov", None, 3.0),  # the recovery: a C_G snapshot, the plan, the cubic
        ("ground-test-b", None, 2.0),
    ],
)
def test_each_world_equals_the_block_loop(name, extra, duration):
    """Two worlds of different seeds (their own model errors, rotor-drag estimates) against
    the block loop built with each seed: the plant states and the image error are the same
    numbers at every sample."""
    sc = _scenario(name, extra, duration)
    seeds = [0, 5]
    res = build_batch(sc, seeds).run(log_states=True)
    for w, seed in enumerate(seeds):
        r = build_loop(sc, seed).loop.run(sc.data["duration"])
        q = r.arrays["q"]
        assert res.termination[w] is None and r.termination is None
        assert res.samples[w] == q.shape[0]
        np.testing.assert_array_equal(res.q[:, w], q)
        np.testing.assert_array_equal(res.rmse[:, w], r.arrays["rmse"])
    assert not np.allclose(res.q[-1, 0], res.q[-1, 1])  # the seeds' model errors differ


@pytest.mark.parametrize("features", ["measured", "predicted"])
def test_a_world_does_not_depend_on_the_batch_size_its_index_or_threads(features):
    """With pixel noise, dropped frames and latency, world of seed 11 gives bit-identical
    arrays alone, in a batch of 7 at another index, and with 1 or 2 threads (the servo on
    the measured points, or on the points predicted by the target filter)."""
    sc = _scenario(
        "paper-in-fov",
        {
            "sensors": {"pixel_noise": 1.0, "dropout": 0.05, "latency_steps": 1},
            "ibvs": {"features": features},
        },
        duration=1.0,
    )
    alone = build_batch(sc, [11], threads=1).run(log_states=True)
    seeds = [3, 4, 5, 6, 11, 8, 9]
    runs = [build_batch(sc, seeds, threads=t).run(log_states=True) for t in (1, 2)]
    for r in runs:
        np.testing.assert_array_equal(r.q[:, 4], alone.q[:, 0])
        np.testing.assert_array_equal(r.rmse[:, 4], alone.rmse[:, 0])
    np.testing.assert_array_equal(runs[0].q, runs[1].q)
    assert not np.array_equal(runs[0].q[:, 0], runs[0].q[:, 4])  # other seeds, other noise


#: the proprioceptive sensors and the tip camera without noise or bias (the EKF's equality)
QUIET_SENSORS = {
    "pixel_noise": 0.0, "accel_bias": 0.0, "accel_noise": 0.0, "gyro_bias": 0.0,
    "gyro_noise": 0.0, "encoder_noise": 0.0, "encoder_resolution": 0.0,
    "pose_attitude_noise": 0.0, "pose_position_noise": 0.0,
}  # fmt: skip
#: the EKF's estimates with noiseless, unbiased sensors
QUIET_ESTIMATES = {"estimation": {"source": "estimated"}, "sensors": QUIET_SENSORS}
#: the tip force estimate from the balance with differenced velocities
DIFFERENCED = {"touch": {"force_estimator": "differenced"}}


@pytest.mark.parametrize(
    "name, extra, duration",
    [
        # on the EKF's estimates: each world's filter, its sensors and start-up reading
        ("paper-in-fov", QUIET_ESTIMATES, 1.0),
        ("dual-in-fov", None, 0.6),  # two arms on one drone, the arms' stacked step
    ],
)
def test_each_world_equals_the_block_loop_on_estimates_and_two_arms(name, extra, duration):
    """The scenarios the engine runs beyond one arm on the true state: the same numbers as
    the block loop of each seed at every sample (both call the same compiled steps)."""
    _worlds_equal_the_block_loop(_scenario(name, extra, duration))


def _worlds_equal_the_block_loop(sc, check=None):
    """Worlds of seeds 0 and 5 against the block loop built with each seed: ``check`` on the
    block loop's arrays, then the plant states and the servo's RMSE the same numbers at every
    sample (both call the same compiled steps)."""
    seeds = [0, 5]
    res = build_batch(sc, seeds, threads=1).run(log_states=True)
    for w, seed in enumerate(seeds):
        r = build_loop(sc, seed).loop.run(sc.data["duration"])
        assert res.termination[w] is None and r.termination is None
        if check is not None:
            check(r.arrays)
        np.testing.assert_array_equal(res.q[:, w], r.arrays["q"])
        np.testing.assert_array_equal(res.rmse[:, w], r.arrays["rmse"])


def _near_standoff(extra=None, duration=14.0):
    """touch-target started 0.18 m above its standoff view (as tests/contact/test_touch.py):
    it moves in, touches, settles and holds within ``duration``."""
    sc = load_scenario("touch-target")
    q0 = list(sc.data["initial"]["q"])
    q0[5] = 2.0
    ov = {"cameras": ENGINE["cameras"], "initial": {"q": q0}, "duration": duration}
    return sc.with_overrides({**ov, **(extra or {})}, "engine configuration")


@pytest.mark.parametrize(
    "extra",
    [
        None,  # the true state
        QUIET_ESTIMATES,  # the EKF's
        DIFFERENCED,  # the force from differenced velocities
        {**QUIET_ESTIMATES, **DIFFERENCED},  # from the EKF's, with its covariance
    ],
)
def test_touch_target_worlds_equal_the_block_loop(extra):
    """Servoing into contact: each world's force estimate (the momentum observer, or the
    balance with differenced velocities), the touch
    law's phases, the pinned view and the admittance are the block loop's compiled steps, so
    the plant states, the servo's RMSE (the monitor's: the standoff view, then the task's)
    are the same numbers at every sample, through the touch and into the hold."""

    def held(arrays):  # the touch, the pinned view, the force
        assert arrays["touch_phase"].max() >= 2

    _worlds_equal_the_block_loop(_near_standoff(extra), held)


def _squeeze_near_contact(extra=None, duration=9.0):
    """dual-squeeze started 1 cm above its contact pose with a 1 cm standoff (as
    tests/contact/test_squeeze.py): both arms move in and touch within 2 s."""
    sc = load_scenario("dual-squeeze")
    q0 = list(sc.data["desired"]["q"])
    q0[5] += 0.01
    ov = {"cameras": ENGINE["cameras"], "initial": {"q": q0}, "duration": duration,
          "touch": {"standoff": 0.01, "dwell": 0.1}}  # fmt: skip
    return sc.with_overrides({**ov, **(extra or {})}, "engine configuration")


@pytest.mark.parametrize(
    "extra, held",
    [
        # the true state with the seeds' model errors: landings off the markers, unloaded and
        # flown again (measured in the block loop: both seeds back to the approach at 4.4 s,
        # seed 5 down again at 5.8 s)
        (None, False),
        # the EKF's, no model error: both touches, the pinned views, the hold from 7.7 s
        ({**QUIET_ESTIMATES, "model": {"perturbation": 0.0}}, True),
    ],
)
def test_squeeze_worlds_equal_the_block_loop(extra, held):
    """The two-arm squeeze: every arm's force estimate (one residual, solved together), the
    squeeze's phases, landing check and unloading, pinned views, mapping in feature space and
    force and balance loops are the block loop's compiled steps, so the plant states and the
    servo's RMSE are the same numbers at every sample."""

    def landed(arrays):
        phase = arrays["touch_phase"]
        if held:
            assert phase.max() == 2
        else:  # down on both markers, then unloaded and back to the approach
            assert arrays["touch_landing"].max() >= 1
            assert np.any((phase[:-1] == 1) & (phase[1:] == 0))

    _worlds_equal_the_block_loop(_squeeze_near_contact(extra), landed)


def test_unsupported_scenarios_are_refused_naming_the_key():
    with pytest.raises(ScenarioError, match="cameras.local_renderer"):
        build_batch(load_scenario("paper-in-fov"), [0])
    user = load_scenario("paper-in-fov").with_overrides(
        {"cameras": ENGINE["cameras"], "controller": {"class": f"{__name__}:UserController"}},
        "t",
    )
    with pytest.raises(ScenarioError, match=r"controller\.class: the engine runs the shipped"):
        build_batch(user, [0])


class UserController:
    """A user's controller class (the engine runs the shipped ones only): holds still."""

    def __init__(self, context):
        self.n = context.system.n
        self.n_u = context.system.n_u

    def reset(self, estimate):
        pass

    def step(self, estimate, command, dt):
        from tdacm.loop.data import ActuatorCommand

        return ActuatorCommand(np.zeros(self.n_u), np.zeros(self.n), command.q_d)


def test_recovery_failure_ends_the_world_named():
    """A recovery whose C_G snapshot does not see the target ends as ``recovery failed``,
    as in the block loop (the drone too high for C_G to see the whole target)."""
    sc = _scenario("paper-out-of-fov", duration=0.5)
    q0 = sc.data["initial"]["q"]
    q_far = list(q0)
    q_far[3] += 3.0  # far to the side: neither camera sees the target
    sc = sc.with_overrides(
        {"initial": {"q": q_far}, "expect": {"initial_in_global_fov": False}}, "t"
    )
    res = build_batch(sc, [0]).run()
    r = build_loop(sc, 0).loop.run(0.5)
    assert res.termination == ["recovery failed"]
    assert r.termination == "recovery failed"


@pytest.mark.parametrize("features", ["measured", "predicted"])
def test_a_period_in_halves_is_the_period(features):
    """The vector env's path (the period's sense, an observation of the servo's view, then
    its act) gives the states of the plain periods bit for bit over 0.5 s with noise, dropped
    frames and latency, and the view observed holds the features the period's step servoed
    on."""
    from tdacm.batch import engine as E
    from tdacm.vision.features import advanced_features

    sc = _scenario(
        "paper-in-fov",
        {
            "sensors": {"pixel_noise": 1.0, "dropout": 0.1, "latency_steps": 1},
            "ibvs": {"features": features},
        },
        duration=0.5,
    )
    seeds = [2, 7, 12]
    plain = build_batch(sc, seeds, threads=1)
    halves = build_batch(sc, seeds, threads=1)
    N = len(seeds)
    nan = np.full((N, 6), np.nan)
    views = 0
    for _ in range(int(round(0.5 / sc.config.dt))):
        plain.step()
        d = halves.data
        active = d.active.copy()
        E.sense_worlds(halves.model, d, 0, N)
        out = d.servo_out
        seen = active & out.seen[:, 0, 0] & (out.mode[:, 0, 0] == 0)  # arm 0, IBVS
        points = out.points[:, 0].copy()  # arm 0's
        E.act_worlds(halves.model, d, nan, 0, N)
        np.testing.assert_array_equal(halves.data.q, plain.data.q)
        for a, b in zip(halves.data.servo.filter, plain.data.servo.filter, strict=True):
            np.testing.assert_array_equal(a, b)  # the filter's state
        views += int(seen.sum())
        for w in np.flatnonzero(seen):  # the step servoed on the observed points
            np.testing.assert_array_equal(out.features[w, 0], advanced_features(points[w]))
    assert views > 10
