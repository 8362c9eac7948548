"""Numba kernels of the state estimator (the hot path of
:class:`~tdacm.estimation.ekf.ExtendedKalmanFilter`).

The filter's process model is the controller's *perturbed* model (paper, "Simulation Results":
a 10 % multiplicative perturbation of ``M``, ``C``, ``D`` and ``K``; see
:class:`tdacm.control.model.EstimatedModel`), written with the same congruences::

    M_hat = S_M M S_M,  C_hat = S_M C S_M,  D_hat = S_D D S_D,
    K_hat = (1 + d_K) * (K q) - (1 + d_g) * tau_grav,

    qdd = M_hat^-1 (B(q) u - C_hat qd - D_hat qd - K_hat) + a_d,           (paper eq. (9))

and, when the model knows the drone's rotor drag ``k_r_hat`` (``drag``, all zeros: not), the
damping ``R diag(k_r_hat) R^T`` of the drone's velocity on its position rows
(:meth:`tdacm.control.model.EstimatedModel.rotor_damping`).

with ``a_d`` the filter's disturbance acceleration state (model error and unknown loads). The
kernels take ``m`` (the :class:`tdacm.system.kernels.ModelArrays` of the private model) and
the packed gravity-only ``loads``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..lie.euler import euler_rate_matrix, rot_zyx
from ..system.kernels import (
    cholesky_solve,
    coupled_terms,
    input_matrix,
    tendon_lengths_and_matrix,
)


@njit(cache=True)
def model_qdd(q, qd, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag):
    """Accelerations of the perturbed model plus the disturbance acceleration ``ad``;
    ``ok`` False when ``M_hat`` is not positive definite. ``drag`` (3,): the rotor drag the
    model knows (zeros: none; the arithmetic is then that of the model without it)."""
    n = q.shape[0]
    mm, cc, _, tau, _, _, _ = coupled_terms(q, qd, m, loads, bool(1))
    bu = input_matrix(q, m) @ u
    kq = m.stiffness @ q
    sqd = s_m * qd
    dqd = s_d * qd
    rhs = np.empty(n)
    mh = np.empty((n, n))
    for i in range(n):
        acc_c = 0.0
        acc_d = 0.0
        for j in range(n):
            acc_c += cc[i, j] * sqd[j]
            acc_d += m.damping[i, j] * dqd[j]
            mh[i, j] = s_m[i] * mm[i, j] * s_m[j]
        rhs[i] = bu[i] - s_m[i] * acc_c - s_d[i] * acc_d - k_scale[i] * kq[i] + g_scale[i] * tau[i]
    if drag[0] != 0.0 or drag[1] != 0.0 or drag[2] != 0.0:
        r = rot_zyx(q[0], q[1], q[2])
        vb = r.T @ qd[3:6]
        for i in range(3):
            acc = 0.0
            for k in range(3):
                acc += r[i, k] * drag[k] * vb[k]
            rhs[3 + i] -= acc
    x, ok = cholesky_solve(mh, rhs)
    return x + ad, ok


@njit(cache=True)
def propagate_mean(q0, qd0, u, ad, dt, nsub, m, loads, s_m, s_d, k_scale, g_scale, drag):
    """RK4 of the perturbed model over ``dt`` in ``nsub`` steps, ``u`` and ``ad`` held."""
    h = dt / nsub
    q = q0.copy()
    qd = qd0.copy()
    for _ in range(nsub):
        a1, ok1 = model_qdd(q, qd, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag)
        a2, ok2 = model_qdd(
            q + 0.5 * h * qd, qd + 0.5 * h * a1, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag
        )
        a3, ok3 = model_qdd(
            q + 0.5 * h * (qd + 0.5 * h * a1),
            qd + 0.5 * h * a2,
            u,
            ad,
            m,
            loads,
            s_m,
            s_d,
            k_scale,
            g_scale,
            drag,
        )
        a4, ok4 = model_qdd(
            q + h * (qd + 0.5 * h * a2), qd + h * a3, u, ad, m, loads, s_m, s_d, k_scale, g_scale,
            drag,
        )  # fmt: skip
        if not (ok1 and ok2 and ok3 and ok4):
            return q, qd, False
        q = q + h * qd + h * h / 6.0 * (a1 + a2 + a3)
        qd = qd + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q, qd, True


@njit(cache=True)
def linearize(q, qd, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag, skip):
    """``qdd`` and its forward-difference Jacobian ``d qdd / d[q, qd]`` (n x 2n).

    Columns with ``skip[j]`` True are left zero: the drone's inertial position does not enter
    the dynamics (uniform gravity, no position-dependent load in the filter's model)."""
    n = q.shape[0]
    a0, ok = model_qdd(q, qd, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag)
    jac = np.zeros((n, 2 * n))
    if not ok:
        return a0, jac, False
    for j in range(2 * n):
        if j < n and skip[j]:
            continue
        qq = q.copy()
        qqd = qd.copy()
        if j < n:
            eps = 1e-6 * (1.0 + abs(q[j]))
            qq[j] += eps
        else:
            eps = 1e-6 * (1.0 + abs(qd[j - n]))
            qqd[j - n] += eps
        a1, ok1 = model_qdd(qq, qqd, u, ad, m, loads, s_m, s_d, k_scale, g_scale, drag)
        if not ok1:
            return a0, jac, False
        for i in range(n):
            jac[i, j] = (a1[i] - a0[i]) / eps
    return a0, jac, True


@njit(cache=True)
def transition(a, dt):
    """``Phi = expm(A dt)`` to third order and the discretized process noise map of a white
    continuous noise: returns ``Phi``. (``|A dt| < 0.2`` for the paper system at 50 Hz, the
    fourth-order remainder is below 1e-4 relative.)"""
    n = a.shape[0]
    ad = a * dt
    ad2 = ad @ ad
    ad3 = ad2 @ ad
    phi = np.eye(n) + ad + ad2 / 2.0 + ad3 / 6.0
    return phi


@njit(cache=True)
def discrete_noise(a, qc, dt):
    """Van Loan's series for ``Q_d = int_0^dt Phi(s) Q_c Phi(s)^T ds`` to third order."""
    aq = a @ qc
    return qc * dt + (aq + aq.T) * (dt * dt / 2.0) + (a @ qc @ a.T) * (dt**3 / 3.0)


@njit(cache=True)
def tendon_lengths_and_jacobian(qs, m):
    """Tendon path lengths and ``dl/dq_s = -B_s^T`` (n_a x n_s) of the model
    (:func:`tdacm.system.kernels.tendon_lengths_and_matrix`, paper eq. (13))."""
    lengths, b_s = tendon_lengths_and_matrix(qs, m)
    return lengths, -b_s.T.copy()


@njit(cache=True)
def specific_force(q, qdd, gravity):
    """Accelerometer at the drone's centre of mass: ``R_b^T (p_ddot - g)`` (body frame)."""
    r = rot_zyx(q[0], q[1], q[2])
    f = np.empty(3)
    for i in range(3):
        acc = 0.0
        for k in range(3):
            acc += r[k, i] * (qdd[3 + k] - gravity[k])
        f[i] = acc
    return f


@njit(cache=True)
def body_rate(q, qd):
    """Gyroscope: body angular velocity ``T(phi, theta) Phi_dot`` (paper eq. (4))."""
    return euler_rate_matrix(q[0], q[1]) @ qd[:3]


#: :func:`kalman_update` outcomes: fused; ``H P H^T + R`` singular; not finite
UPDATE_OK, UPDATE_SINGULAR, UPDATE_NONFINITE = 0, 1, 2


@njit(cache=True)
def kalman_update(x, p, r, h, rr):
    """Joseph-form EKF update with residual ``r = z - h(x)``, Jacobian ``h``, noise ``rr``:
    ``K = P H^T (H P H^T + R)^-1``, ``x + K r``, ``(I - K H) P (I - K H)^T + K R K^T``
    (symmetrized). Returns ``(x, P, nis, status)`` with the normalized innovation squared and
    :data:`UPDATE_OK`, or :data:`UPDATE_SINGULAR` / :data:`UPDATE_NONFINITE` when the
    innovation covariance cannot be solved with (``x``, ``P`` then unchanged: only a broken
    ``P`` does that, ``R`` being positive definite)."""
    ph = p @ h.T
    s = h @ ph + rr
    s = 0.5 * (s + s.T)
    pht = ph.T.copy()
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(pht)) and np.all(np.isfinite(r))):
        return x, p, np.nan, UPDATE_NONFINITE
    try:
        k = np.linalg.solve(s, pht).T
        nis = r @ np.linalg.solve(s, r)
    except Exception:  # noqa: BLE001 - numba's LinAlgError of a singular s
        return x, p, np.nan, UPDATE_SINGULAR
    x1 = x + k @ r
    ikh = np.eye(p.shape[0]) - k @ h
    p1 = ikh @ p @ ikh.T + k @ rr @ k.T
    return x1, 0.5 * (p1 + p1.T), nis, UPDATE_OK
