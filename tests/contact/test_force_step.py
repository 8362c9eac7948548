"""The tip force estimate's compiled step (tdacm.estimation.contact_force.force_step), the one
the block loop's force block runs: against the observer's recursion written out in numpy and
the estimator's least squares (TipForceEstimator), on one arm and two, momentum and
differenced, with the tare."""

import numpy as np
import pytest

from tdacm.estimation.contact_force import (
    ForceOut,
    ForceState,
    MomentumObserver,
    TipForceEstimator,
    force_params,
    force_reset,
    force_step,
    force_tare,
    normal_forces_of,
)
from tdacm.sim import load_scenario
from tdacm.sim.assemble import build_loop
from tdacm.system.contact import probe_offset

SIGMA = 0.02  # each input's standard deviation (N)
GAIN = 25.0  # the observer's K_o (1/s)
DT = 0.02


def _trajectory(system, q0, steps, seed):
    """A smooth random path of the state and inputs around ``q0`` (no dynamics: the estimate
    is a function of the sequence it is given)."""
    rng = np.random.default_rng(seed)
    n, nu = system.n, system.n_u
    w = rng.uniform(0.5, 3.0, n)
    a = rng.normal(0.0, 0.01, n)
    u0 = np.r_[np.full(4, 7.5 / 4 * 2.0), np.full(nu - 4, 2.0)] if system.floating else None
    out = []
    for k in range(steps):
        t = k * DT
        q = q0 + a * np.sin(w * t)
        qd = a * w * np.cos(w * t)
        u = u0 + rng.normal(0.0, 0.05, nu)
        out.append((q, qd, u))
    return out


def _setup(name):
    a = build_loop(load_scenario(name))
    robot = a.world.robot
    return a.model, robot, probe_offset(robot.tip_mount, robot.probe_length), a.world.q_star


def _observer_reference(model, path):
    """The momentum observer's recursion (MomentumObserver's docstring) in numpy."""
    s = model.system
    r, prev, out = np.zeros(s.n), None, []
    for q, qd, u in path:
        t = model.terms(q, qd)
        beta = s.input_matrix(q) @ u + t.C.T @ qd - t.D @ qd - t.K
        p = t.M @ qd
        if prev is not None:
            beta_prev, p_prev, q_prev, u_prev = prev
            beta_prev = beta_prev + s.input_matrix(q_prev) @ (u - u_prev)
            k = GAIN * DT
            r = (1.0 - k) * r + GAIN * (p - p_prev - 0.5 * DT * (beta + beta_prev))
        prev = (beta, p, q, u)
        out.append(r.copy())
    return out


def test_observer_kernel_is_its_recursion():
    """MomentumObserver (the compiled update) equals its recursion written in numpy."""
    model, _, _, q0 = _setup("touch-target")
    path = _trajectory(model.system, q0, 40, seed=3)
    ref = _observer_reference(model, path)
    obs = MomentumObserver(model, GAIN)
    for (q, qd, u), r in zip(path, ref, strict=True):
        np.testing.assert_allclose(obs.step(q, qd, u, DT), r, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name, arms", [("touch-target", 1), ("dual-squeeze", 2)])
def test_momentum_estimate_equals_the_estimators_solve(name, arms):
    """Each period of the compiled step: the observer's residual less the tare, solved for
    every arm's force along minus its camera's axis with the inputs' covariance through the
    observer's lag, as TipForceEstimator.normal_force_of (one arm) and normal_forces_of (two)
    compute it; invalid before the observer has started; the tare takes the last residual."""
    model, robot, off, q0 = _setup(name)
    s = model.system
    mounts = [arm.tip_mount for arm in robot.arms] or [robot.tip_mount]
    p = force_params(model, mounts, off, SIGMA, "momentum", GAIN)
    st, out = ForceState.initial(s.n, s.n_u), ForceOut.empty(arms)
    est = [TipForceEstimator(model, "all", input_sigma=SIGMA, offset=off, rod=k)
           for k in range(arms)]  # fmt: skip
    path = _trajectory(s, q0, 30, seed=11)
    ref = _observer_reference(model, path)
    m, k = s.model_arrays, GAIN * DT
    for i, ((q, qd, u), r) in enumerate(zip(path, ref, strict=True)):
        if i == 10:  # tare on the last residual: the estimate then reads from it
            tared = st.last.copy()
            np.testing.assert_allclose(tared, ref[9], rtol=1e-10, atol=1e-12)
            force_tare(st)
            np.testing.assert_array_equal(st.bias, tared)
            for e in est:
                e.bias = ref[9].copy()
        force_step(p, st, m, q, qd, u, True, np.zeros((0, 0)), DT, out)
        if i == 0:
            assert not out.valid[0]  # the observer starts
            continue
        assert out.valid[0]
        normals = [-(s.tip_pose(q, a) @ mt)[:3, 2] for a, mt in enumerate(mounts)]
        cov = est[0].input_cov(q) * (k / (2.0 - k))
        if arms == 1:
            f, sigma = est[0].normal_force_of(q, r, normals[0], cov)
            f, sigma = np.array([f]), np.array([sigma])
        else:
            f, sigma = normal_forces_of(est, q, r, normals, cov)
        np.testing.assert_allclose(out.normals, np.array(normals), atol=1e-12)
        np.testing.assert_allclose(out.force, f, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(out.sigma, sigma, rtol=1e-8, atol=1e-12)
    # no applied input: the observer restarts, the estimate is invalid, the tare is kept
    q, qd, u = path[-1]
    force_step(p, st, m, q, qd, u, False, np.zeros((0, 0)), DT, out)
    assert not out.valid[0] and not st.started[0]
    np.testing.assert_array_equal(st.bias, tared)
    force_reset(st)
    assert not st.bias.any()


def test_differenced_estimate_equals_the_estimators_normal_force():
    """The differenced estimate (qdd from consecutive velocities) with the state covariance:
    TipForceEstimator.normal_force with that qdd and covariance."""
    model, robot, off, q0 = _setup("touch-target")
    s = model.system
    p = force_params(model, robot.tip_mount, off, SIGMA, "differenced", 0.0)
    st, out = ForceState.initial(s.n, s.n_u), ForceOut.empty(1)
    est = TipForceEstimator(model, "all", input_sigma=SIGMA, offset=off)
    rng = np.random.default_rng(5)
    g = rng.normal(0.0, 1e-3, (2 * s.n, 2 * s.n))
    cov_state = g @ g.T
    path = _trajectory(s, q0, 12, seed=7)
    for i, (q, qd, u) in enumerate(path):
        force_step(p, st, s.model_arrays, q, qd, u, True, cov_state, DT, out)
        if i == 0:
            assert not out.valid[0]  # no previous velocity
            continue
        qdd = (qd - path[i - 1][1]) / DT
        normal = -(s.tip_pose(q) @ robot.tip_mount)[:3, 2]
        f, sigma = est.normal_force(q, qd, u, normal, qdd, cov_state)
        assert out.valid[0]
        assert out.force[0] == pytest.approx(f, rel=1e-8, abs=1e-10)
        # the state's part by finite differences of the residual, the same steps both sides
        assert out.sigma[0] == pytest.approx(sigma, rel=1e-6)


def test_force_params_refuse_bad_settings():
    model, robot, off, _ = _setup("touch-target")
    with pytest.raises(ValueError, match="kind"):
        force_params(model, robot.tip_mount, off, SIGMA, "kalman", GAIN)
    with pytest.raises(ValueError, match="gain"):
        force_params(model, robot.tip_mount, off, SIGMA, "momentum", -1.0)
    with pytest.raises(ValueError, match="offset"):
        force_params(model, robot.tip_mount, [0.0, np.nan, 0.3], SIGMA, "momentum", GAIN)
    with pytest.raises(ValueError, match="mount"):
        force_params(model, np.zeros((3, 4, 4)), off, SIGMA, "momentum", GAIN)
