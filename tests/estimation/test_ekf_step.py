"""The filter's and the sensors' compiled steps (tdacm.estimation.ekf_step, sensor_steps): the
records run one world or a stacked batch with one compilation, refused calls change nothing,
the window of ticks, the random numbers' order, the update's failures."""

import numpy as np
import pytest
from scipy.stats import chi2

from tdacm import paper_system
from tdacm._records import put, stack, take
from tdacm.bench.estimation import nees, run
from tdacm.control import EstimatedModel
from tdacm.estimation import (
    ExtendedKalmanFilter,
    Imu,
    ImuConfig,
    PoseMeasurement,
    PoseSensorConfig,
    SensorSuite,
    SensorSuiteConfig,
)
from tdacm.estimation import ekf_step as ES
from tdacm.estimation import kernels as EK
from tdacm.estimation.proprioception import DronePoseSensor
from tdacm.estimation.sensor_steps import queue_capacity
from tdacm.system import kernels as K

Q0 = np.array([0.02, -0.01, 0.1, 0.3, -0.2, 3.0, 0.2, -0.3])
LATE = SensorSuiteConfig.from_section(
    {"pose_latency": 0.06, "pose_dropout": 0.2, "imu_dropout": 0.1, "encoder_latency": 0.02}
)


def _hover(s):
    return np.concatenate([np.full(4, s.total_mass * 9.81 / 4), np.full(4, 0.5)])


def _measurements(s, seed, cfg=LATE, steps=30):
    """Plant under a constant hover input and its sensors' deliveries every 0.02 s."""
    suite = SensorSuite(s, cfg, seed)
    u = _hover(s)
    qs_, qds_, _ = K.rk4_run(Q0, np.zeros(8), u, 0.005, 4 * steps, 4, s.model_arrays,
                             s.loads.packed())  # fmt: skip
    out = []
    for k in range(steps):
        qdd = None if k == 0 else K.forward_dynamics(qs_[k], qds_[k], u, s.model_arrays,
                                                     s.loads.packed())[0]  # fmt: skip
        out.append(suite.sample(0.02 * k, qs_[k], qds_[k], qdd))
    return u, out


def _run(est, u, meas):
    est.reset(Q0 + 0.01, t0=0.0)
    return np.array([est.step(0.02 * k, None if k == 0 else u, m).q for k, m in enumerate(meas)])


def test_kalman_update_numbers_and_failures():
    p = np.diag([4.0, 1.0])
    h = np.array([[1.0, 0.0]])
    rr = np.array([[1.0]])
    x1, p1, nis, status = EK.kalman_update(np.zeros(2), p, np.array([2.0]), h, rr)
    assert status == EK.UPDATE_OK
    # scalar case: K = 4 / 5, x = K r, P_00 = 4 - 16 / 5, nis = r^2 / 5
    np.testing.assert_allclose(x1, [1.6, 0.0], rtol=1e-15)
    np.testing.assert_allclose(p1, np.diag([0.8, 1.0]), rtol=1e-14)
    assert nis == pytest.approx(0.8, rel=1e-15)
    *_, status = EK.kalman_update(np.zeros(2), np.zeros((2, 2)), np.array([1.0]), h, 0 * rr)
    assert status == EK.UPDATE_SINGULAR
    *_, status = EK.kalman_update(np.zeros(2), p * np.nan, np.array([1.0]), h, rr)
    assert status == EK.UPDATE_NONFINITE


def test_a_refused_step_changes_nothing():
    s = paper_system()
    est = ExtendedKalmanFilter(EstimatedModel(s, 0.1, 0))
    u, meas = _measurements(s, 0, steps=6)
    _run(est, u, meas)
    before = [a.copy() for a in est.state]
    with pytest.raises(ValueError, match="time went backwards"):
        est.step(0.05, u, meas[2])
    with pytest.raises(ValueError, match="u_applied is needed"):
        est.step(0.2, None, [])
    for a, b in zip(before, est.state, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_window_sized_for_the_period_is_the_grown_one():
    """With 60 ms of pose latency, dropouts and 20 ms on the encoders, a window sized at once
    for the period (what the engine holds per world) and the one the block grows as it runs
    give the same estimates, bit for bit, and keep ``max_delay`` of history."""
    s = paper_system()
    model = EstimatedModel(s, 0.1, 1)
    u, meas = _measurements(s, 1)
    grown = ExtendedKalmanFilter(model, LATE)
    sized = ExtendedKalmanFilter(model, LATE, period=0.02)
    assert sized.state.window == ES.window_ticks(0.2, 0.02) == 13
    a, b = _run(grown, u, meas), _run(sized, u, meas)
    np.testing.assert_array_equal(a, b)
    assert grown.state.window >= 13 and sized.state.window == 13
    hist = sized.history()
    assert hist[-1].t - hist[1].t <= 0.2 + 1e-9 < hist[-1].t - hist[0].t
    assert sized.dropped_late == 0


def test_one_compilation_steps_one_world_or_a_stacked_batch():
    """Two worlds' records stacked (a leading world axis): world 1 stepped through
    ``take(stacked, 1)`` gives what its own filter gives, with the compiled step of the single
    record (no second specialization)."""
    s = paper_system()
    ests = [ExtendedKalmanFilter(EstimatedModel(s, 0.1, seed), LATE, period=0.02)
            for seed in (0, 1)]  # fmt: skip
    u, meas = _measurements(s, 1)
    ref = _run(ests[1], u, meas)
    n_sig = len(ES.ekf_step.signatures)
    params = stack([e.params for e in ests])
    for e in ests:
        e.reset(Q0 + 0.01, t0=0.0)
    states = stack([e.state for e in ests])
    m = ests[1].system.model_arrays
    got = []
    for k, mk in enumerate(meas):
        rows = ests[1].pack(mk)
        status = ES.ekf_step(take(params, 1), take(states, 1), m, 0.02 * k, u, k > 0, rows)
        assert status == ES.OK
        st = take(states, 1)
        got.append(st.x[ES.ekf_latest(st), :8].copy())
    np.testing.assert_array_equal(np.array(got), ref)
    assert len(ES.ekf_step.signatures) == n_sig
    put(states, 0, ests[1].state)  # and a world's row can be replaced by a record
    np.testing.assert_array_equal(take(states, 0).x, ests[1].state.x)


def test_nees_with_latency_and_dropouts():
    """The re-run path (late poses, lost samples) keeps the filter consistent: normalized
    estimation error squared of ``[q, qd]`` (16 dof) pooled over six seeded runs, as
    ``test_ekf.test_nees_within_chi_square_bounds`` for the sensors on time (measured: mean
    13.1 against 13.3 on time, 0.905 of the samples in the one-sample region, 0.9 % above)."""
    ne = np.concatenate([nees(run(seed=s, duration=2.0, sensors=LATE))[5:] for s in range(6)])
    lo, hi = chi2.ppf([0.025, 0.975], 16)
    assert lo < ne.mean() < hi, ne.mean()
    assert ne.mean() > 0.75 * 16, ne.mean()
    assert np.mean((ne > lo) & (ne < hi)) >= 0.9
    assert np.mean(ne > hi) < 0.025


def test_imu_draws_the_walk_before_the_noise():
    """The IMU's random numbers, in the order the compiled poll uses them: the turn-on
    biases at construction, then per capture the bias walks (after the first capture) and the
    noises."""
    cfg = ImuConfig(gyro_noise=0.0, accel_noise=0.0, gyro_bias_walk=0.01, accel_bias_walk=0.1)
    g = np.array([0.0, 0.0, -9.81])
    imu = Imu(cfg, g, np.random.default_rng(5))
    ref = np.random.default_rng(5)
    b_g = cfg.gyro_bias * ref.standard_normal(3)
    b_a = cfg.accel_bias * ref.standard_normal(3)
    q = np.zeros(8)
    m1 = imu.sample(0.0, q, np.zeros(8), np.zeros(8))
    np.testing.assert_array_equal(m1.gyro, b_g)
    ref.standard_normal(6)  # the first capture's noises (zero here)
    walk = ref.standard_normal(6)
    m2 = imu.sample(0.02, q, np.zeros(8), np.zeros(8))
    np.testing.assert_array_equal(m2.gyro, b_g + 0.01 * np.sqrt(0.02) * walk[:3])
    # the specific force sums g, the bias and its walk in another order: 1e-14 of 9.81
    np.testing.assert_allclose(m2.accel, [0, 0, 9.81] + b_a + 0.1 * np.sqrt(0.02) * walk[3:],
                               rtol=0, atol=1e-14)  # fmt: skip
    np.testing.assert_array_equal(imu.gyro_bias, m2.gyro)


def test_a_sensor_queue_holds_every_capture_in_flight():
    """50 Hz captures delivered 0.1 s late, polled at 100 Hz: every capture arrives once, 0.1 s
    after its capture time, in order (6 in flight at most, the queue holds
    ``queue_capacity``)."""
    cfg = PoseSensorConfig(rate_hz=50.0, latency=0.1, position_noise=0.0, attitude_noise=0.0)
    assert queue_capacity(cfg) == 8
    s = DronePoseSensor(cfg, np.random.default_rng(0))
    got = []
    for k in range(101):
        m = s.sample(0.01 * k, Q0, np.zeros(8))
        if m is not None:
            assert isinstance(m, PoseMeasurement)
            got.append((0.01 * k, m.t))
    t_poll, t_cap = np.array(got).T
    np.testing.assert_allclose(t_cap, 0.02 * np.arange(46), atol=1e-12)
    np.testing.assert_allclose(t_poll - t_cap, 0.1, atol=1e-9)
