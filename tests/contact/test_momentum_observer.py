"""The generalized-momentum observer of the tip force (no accelerations) on the true state."""

import numpy as np
import pytest

from tdacm.control.model import EstimatedModel
from tdacm.estimation.contact_force import MomentumObserver, TipForceEstimator
from tdacm.system import paper_system
from tdacm.system.integrate import simulate

F = np.array([0.1, -0.05, 0.3])  # N, a constant dead load on the tip (inertial)
GAIN = 20.0  # 1/s


def _run(h: float):
    """The floating paper system under held inputs (the drone falls, the rod swings) and the
    constant tip force ``F``; the observer on the exact samples every ``h`` s, against the
    first-order lag ``rdot = K_o (tau_e - r)`` of the true ``tau_e = A(q) F`` discretized
    alike (the trapezoid over each period, the observer's quadrature)."""
    s = paper_system()
    s.loads.tip_force = F
    q0 = np.zeros(s.n)
    q0[5], q0[6:] = 1.0, (0.1, -0.1)
    u = np.r_[np.full(4, 2.0), 1.0, 0.5, 0.2, 0.8]
    model = EstimatedModel(s, 0.0, 0)  # the exact model: tau_e is the tip force alone
    a_of = TipForceEstimator(model, "all", input_sigma=0.02)._a
    res = simulate(s, q0, None, 0.5, dt=h / 2, u=u, record_dt=h, method="rk4")
    obs = MomentumObserver(model, GAIN)
    ref, tau_prev, err = np.zeros(s.n), None, 0.0
    for q, qd in zip(res.q, res.qd, strict=True):
        r = obs.step(q, qd, u, h)
        tau = a_of(q) @ F
        if tau_prev is not None:
            ref = (1.0 - GAIN * h) * ref + GAIN * h * 0.5 * (tau + tau_prev)
        tau_prev = tau
        err = max(err, float(np.abs(r - ref).max()))
    return err, ref, tau, r


def test_momentum_observer_is_the_first_order_lag_of_the_tip_force():
    """``r`` follows ``K_o (tau_e - r)`` from ``r(0) = 0``: after ``10 / K_o`` s the lag has
    decayed to ``(1 - K_o h)^k`` (< 1e-6) of the step, and what is left of ``r - ref`` is the
    trapezoid's quadrature error of ``int beta``, second order in ``h``: measured 3.0e-4,
    7.5e-5 N at h = 10, 5 ms (0.1 % and 0.03 % of |tau_e| = 0.3 N)."""
    e1, ref, tau, r = _run(0.01)
    e2, _, _, _ = _run(0.005)
    assert e1 < 1e-3 * 0.3 / 0.1  # 1e-3 N: 0.3 % of the largest component of tau_e
    assert 3.5 < e1 / e2 < 4.5  # second order
    # the step is recovered: r is tau_e up to the lag of a moving A(q) (the rod swings)
    assert np.abs(r - tau).max() < 0.1 * np.abs(tau).max()


def test_momentum_observer_step_response_at_rest():
    """Fed a rest (``qd = 0``, ``q`` fixed) under held inputs ``u``, ``p`` stays 0 and the
    observer's recursion gives ``r_k = (1 - (1 - K_o h)^k) tau_e`` exactly, ``tau_e = K - B u``
    the generalized force the rest needs (here the tip force ``F`` and what the inputs cannot
    balance of gravity)."""
    s = paper_system()
    model = EstimatedModel(s, 0.0, 0)
    q = np.zeros(s.n)
    q[5] = 1.0
    tau = TipForceEstimator(model, "all", input_sigma=0.02)._a(q) @ F
    b = s.input_matrix(q)
    k = model.terms(q, np.zeros(s.n)).K
    u = np.linalg.lstsq(b, k - tau, rcond=None)[0]
    tau_e = k - b @ u
    h = 0.02
    obs = MomentumObserver(model, GAIN)
    for i in range(30):
        r = obs.step(q, np.zeros(s.n), u, h)
        assert r == pytest.approx((1.0 - (1.0 - GAIN * h) ** i) * tau_e, abs=1e-12)
    with pytest.raises(ValueError, match="gain"):
        MomentumObserver(model, 0.0)
    fast = MomentumObserver(model, 200.0)  # K_o h = 4: the recursion would diverge
    with pytest.raises(ValueError, match="period"):  # refused at the first period
        fast.step(q, np.zeros(s.n), u, h)
