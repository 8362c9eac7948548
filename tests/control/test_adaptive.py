"""Controller on its own: tracking with a perturbed model, V non-increasing, gain check."""

import numpy as np
import pytest

from tdacm import paper_system
from tdacm.control import (
    AdaptiveController,
    AdaptiveGains,
    CubicTrajectory,
    EstimatedModel,
    GainConditionError,
    TDACMController,
    check_gains,
)
from tdacm.control.config import ControlLawConfig
from tdacm.system.kernels import rk4_run


@pytest.fixture(scope="module")
def system():
    return paper_system()


def test_gain_condition_violation_raises():
    with pytest.raises(GainConditionError, match="A_p > A_d beta"):
        AdaptiveGains(beta=[2.0, 2.0], A_d=[1.0, 1.0], A_p=[1.0, 5.0], A_a=[1.0, 1.0], eps=0.9)
    g = AdaptiveGains(beta=[2.0, 2.0], A_d=[1.0, 1.0], A_p=[2.0, 2.0], A_a=[1.0, 1.0])
    check_gains(g)
    g.eps = 1.5
    with pytest.raises(GainConditionError, match="eps"):
        check_gains(g)


def test_estimated_model_structure(system):
    q = np.array([0.05, -0.03, 0.2, 0.1, 0.2, 3.0, 0.3, -0.2])
    qd = np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2, 0.5, -0.4])
    model = EstimatedModel(system, 0.1, seed=3)
    t_hat, t = model.terms(q, qd), system.terms(q, qd)
    assert np.allclose(t_hat.M, t_hat.M.T)
    assert np.all(np.linalg.eigvalsh(t_hat.M) > 0)
    ratio = np.diag(t_hat.M) / np.diag(t.M)
    assert np.all(np.abs(ratio - 1) <= 0.1 + 1e-12) and np.any(np.abs(ratio - 1) > 0.01)
    # Mdot_hat - 2 C_hat skew: check with a finite-difference Mdot
    h = 1e-6
    mdot = (model.terms(q + h * qd, qd).M - model.terms(q - h * qd, qd).M) / (2 * h)
    n = mdot - 2 * t_hat.C
    assert np.allclose(n, -n.T, atol=1e-6)
    assert np.allclose(EstimatedModel(system, 0.0).terms(q, qd).M, t.M)


def test_tracking_with_perturbed_model_converges(system):
    """Full TD-ACM (8 DoF, underactuated drone + tendons) tracks a cubic joint trajectory on
    the true plant with a 10 % perturbed model."""
    ctl = TDACMController(system, EstimatedModel(system, 0.1, seed=1))
    q = np.array([0.0, 0.0, 0.15, -0.3, 0.3, 3.5, 0.2, 0.25])
    qd = np.zeros(8)
    goal = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0])
    traj = CubicTrajectory(q, goal, 0.0, 2.5)
    dt = 0.02
    for k in range(300):
        qr, qdr, qddr = traj(k * dt)
        st = ctl.step(q, qd, qr, qdr, qddr, dt)
        assert np.all(st.u[4:] >= 0.0)
        qs, qds, ok = rk4_run(q, qd, st.u, dt / 4, 4, 4, system.model_arrays, system.loads.packed())
        assert ok
        q, qd = qs[-1], qds[-1]
    err = q - goal
    assert np.abs(err[2:]).max() < 5e-3, err  # from 0.5 m / 0.3 rad
    assert np.abs(err[:2]).max() < 5e-3  # roll/pitch back to level at hover
    assert np.abs(qd).max() < 2e-2


def _simulate_fully_actuated(system, law, q, qd, q_d, delta, dt, steps):
    """Plant ``M qdd + (C + D) qd + K = tau + tau_ext + delta`` driven directly by tau_a."""
    vs = []
    for _ in range(steps):
        out = law.law(q, qd, q_d, np.zeros_like(q), np.zeros_like(q))
        t = system.terms(q, qd)
        # Delta of the paper for a model that is exact up to the constant force `delta`
        # (the controller's K_hat includes -tau_ext, so the unknown part is exactly -delta)
        vs.append(law.lyapunov(out, delta_true=-delta))
        law.adapt(out.s, dt)
        qdd = np.linalg.solve(t.M, out.tau + t.tau_ext + delta - (t.C + t.D) @ qd - t.K)
        q, qd = q + dt * qd + 0.5 * dt * dt * qdd, qd + dt * qdd
    return np.array(vs), q


def test_lyapunov_non_increasing_with_constant_uncertainty():
    """Fixed-base rod, exact model except a constant unknown generalized force: V of the
    stability analysis (with the Delta_tilde term) does not increase."""
    system = paper_system(fixed_base_pose=np.eye(4))
    model = EstimatedModel(system, 0.0)
    m = np.diag(system.terms(np.zeros(2), np.zeros(2)).M)
    gains = AdaptiveGains.from_rates(m, beta=3.0, damping_rate=12.0, adaptation_rate=30.0)
    law = AdaptiveController(model, gains)
    delta = np.array([0.01, -0.015])
    v, q = _simulate_fully_actuated(
        system, law, np.array([0.3, -0.2]), np.zeros(2), np.zeros(2), delta, 2.5e-4, 10000
    )
    dv = np.diff(v)
    assert np.all(dv <= 1e-9 * v[0]), dv.max()
    assert v[-1] < 1e-2 * v[0]
    assert np.abs(q).max() < 1e-2
    assert np.allclose(law.delta_hat, -delta, atol=2e-3)


def test_law_kernel_matches_the_matrix_form():
    """``law_kernel`` (the law's per-period numba core) = the paper's law written with
    matrix products, for full (non-diagonal) gains and a random state."""
    from tdacm.control.adaptive import law_kernel

    rng = np.random.default_rng(9)
    n = 8
    x = rng.standard_normal((n, n))
    m = x @ x.T + n * np.eye(n)
    c, d = rng.standard_normal((n, n)), np.diag(rng.uniform(0.1, 1.0, n))
    k = rng.standard_normal(n)
    q, qd, q_d, qd_d, qdd_d, delta = (rng.standard_normal(n) for _ in range(6))
    beta = rng.uniform(1.0, 5.0, n)
    a_d = m * 2.0
    a_p = a_d * beta[None, :] + np.eye(n)
    tau, e, edot, s, qd_r, qdd_r, v = law_kernel(
        m, c, d, k, q, qd, q_d, qd_d, qdd_d, beta, a_d, a_p, delta
    )
    e_ref, edot_ref = q - q_d, qd - qd_d
    qd_r_ref, qdd_r_ref = qd_d - beta * e_ref, qdd_d - beta * edot_ref
    s_ref = edot_ref + beta * e_ref
    tau_ref = m @ qdd_r_ref + (c + d) @ qd_r_ref + k - a_d @ edot_ref - a_p @ e_ref + delta
    v_ref = 0.5 * s_ref @ m @ s_ref + 0.5 * e_ref @ ((beta[:, None] * a_d + a_p) @ e_ref)
    for got, ref in ((e, e_ref), (s, s_ref), (qd_r, qd_r_ref), (qdd_r, qdd_r_ref)):
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(tau, tau_ref, rtol=1e-13, atol=1e-12)
    assert v == pytest.approx(v_ref, rel=1e-13)


@pytest.mark.parametrize("beta", [1.2, 2.0])
def test_velocity_estimate_bias_leaves_offset_b_over_beta(system, beta):
    """A constant error ``b`` of the drone's horizontal velocity estimate: on the sliding
    surface ``s_q = (xdot + b) + beta (x - x_d) = 0`` at rest, so the drone settles ``-b / beta``
    from its reference however the adaptation integrates (``horizontal_position_rate``)."""
    law = ControlLawConfig(horizontal_position_rate=beta)
    ctl = TDACMController(system, EstimatedModel(system, 0.1, seed=2), law=law)
    assert np.allclose(ctl.gains.beta[3:5], beta)
    goal = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0])
    q, qd = goal.copy(), np.zeros(8)
    bias = np.zeros(8)
    bias[3] = 0.005  # m/s on x, the size of the default sensors' velocity error
    dt = 0.02
    for _ in range(1500):  # 30 s: the slowest horizontal mode decays at about 1 /s
        st = ctl.step(q, qd + bias, goal, np.zeros(8), np.zeros(8), dt)
        qs, qds, ok = rk4_run(q, qd, st.u, dt / 4, 4, 4, system.model_arrays, system.loads.packed())
        assert ok
        q, qd = qs[-1], qds[-1]
    assert q[3] == pytest.approx(-bias[3] / beta, rel=0.02)
    assert abs(q[4]) < 1e-4 and abs(qd[3]) < 1e-5
