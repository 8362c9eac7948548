"""Integrators for stiff strain bases, in numba: a linearly implicit Rosenbrock-W method
(:func:`rosw_run`) and the implicit Radau IIA method (:func:`radau_run`).

Torsion, elongation and shear modes of a thin rod vibrate at 10^3-10^6 rad/s, far above the
motion of interest (a few rad/s), so explicit RK4 must take steps of microseconds.  These modes
are stiff because their inertia is tiny (``rho J``, ``rho A`` against ``G J``, ``E A``), so
``M(q)^-1`` amplifies *every* force in their direction, not only the elastic one.  Measured on
the 18-DoF rod (torsion + 2 bendings of order 3): a W-matrix built from ``K`` and ``D`` alone
is unstable beyond 1 ms, and a full Jacobian reused for two steps diverges too.  So each step
takes a fresh tangent of the forces in ``q`` by forward differences,

    J_q = d/dq [B u + tau_ext - C qdot - M(q) a0]          (a0 = qdd at the step start)

(n evaluations of the model terms, no factorization), and uses

    W = [[0, I], [M0^-1 (J_q - K), -M0^-1 D]]              (M0 = M(q) at the step start)

whose only neglected part is the (slow, non-stiff) velocity dependence of the Coriolis forces.
With ``(I/(h g) - W) U = R``, ``U = [U_q; U_v]``, ``R = [R_q; R_v]`` a step needs one LU of the
n x n matrix ``S = M0 + h g D + (h g)^2 (K - J_q)`` and one solve per stage:
``S U_v = h g (M0 R_v - h g (K - J_q) R_q)``, ``U_q = h g (R_q + U_v)``.

The scheme is ROS34PW2 (Rang and Angermann, BIT 45 (2005) 761-787): 4 stages, order 3 for any
W (a W-method), L-stable and stiffly accurate, with an embedded order-2 solution for error
control, in the transformed form of Hairer and Wanner (Solving ODEs II, section IV.7).  A step
costs ``n + 4`` evaluations of the dynamics.  L-stability damps modes with ``h w >> 1``: on
stiff bases the scheme dissipates the energy of the unresolved modes (``docs/model.md``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import kernels as K


def _tableau():
    """Transformed ROS34PW2 coefficients: ``(gamma, a, c, m, e)`` for
    ``(I/(h gamma) - W) U_i = f(y + sum_j a_ij U_j) + sum_j c_ij U_j / h``,
    ``y_1 = y + sum m_i U_i``, error ``sum e_i U_i``."""
    g = 4.3586652150845900e-01
    a = np.zeros((4, 4))
    a[1, 0] = 8.7173304301691801e-01
    a[2, 0] = 8.4457060015369423e-01
    a[2, 1] = -1.1299064236397981e-01
    a[3, 2] = 1.0
    gam = np.zeros((4, 4))
    gam[1, 0] = -8.7173304301691801e-01
    gam[2, 0] = -9.0338057013044082e-01
    gam[2, 1] = 5.4180672388095326e-02
    gam[3, 0] = 2.4212380706095346e-01
    gam[3, 1] = -1.2232505839045147e00
    gam[3, 2] = 5.4526025533510214e-01
    b = np.array([2.4212380706095346e-01, -1.2232505839045147e00, 1.5452602553351023e00, g])
    bh = np.array(
        [3.7810903145819369e-01, -9.6042292212423178e-02, 5.0e-01, 2.1793326075422950e-01]
    )
    full = gam + g * np.eye(4)
    inv = np.linalg.inv(full)
    at = a @ inv
    ct = -(inv - np.diag(np.diag(inv)))
    return g, np.ascontiguousarray(at), np.ascontiguousarray(ct), b @ inv, (b - bh) @ inv


GAMMA, A_T, C_T, M_T, E_T = _tableau()
#: Order of the propagated solution and of the embedded one.
ORDER, EMBEDDED_ORDER = 3, 2


@njit(cache=True)
def dynamics_and_mass(q, qd, u, m, loads):
    """``qdd`` (as :func:`kernels.forward_dynamics`), the mass matrix ``M(q)`` and ``ok``."""
    mm, _, cqd, tau, _, _, _ = K.coupled_terms(q, qd, m, loads, False)
    rhs = K._matvec(K.input_matrix(q, m), u) + tau - cqd
    rhs -= K._matvec(m.damping, qd) + K._matvec(m.stiffness, q)
    qdd, ok = K.cholesky_solve(mm, rhs)
    return qdd, mm, ok


@njit(cache=True)
def _lu(a):
    """LU factorization with partial pivoting of a copy of ``a``: ``(lu, piv, ok)``."""
    n = a.shape[0]
    lu = a.copy()
    piv = np.arange(n)
    for k in range(n):
        p = k
        big = abs(lu[k, k])
        for i in range(k + 1, n):
            if abs(lu[i, k]) > big:
                big = abs(lu[i, k])
                p = i
        if big == 0.0 or not np.isfinite(big):
            return lu, piv, False
        if p != k:
            for c in range(n):
                lu[k, c], lu[p, c] = lu[p, c], lu[k, c]
            piv[k], piv[p] = piv[p], piv[k]
        for i in range(k + 1, n):
            lu[i, k] /= lu[k, k]
            f = lu[i, k]
            if f != 0.0:
                for c in range(k + 1, n):
                    lu[i, c] -= f * lu[k, c]
    return lu, piv, True


@njit(cache=True)
def _lu_solve(lu, piv, b):
    n = b.shape[0]
    y = np.empty(n)
    for i in range(n):
        s = b[piv[i]]
        for p in range(i):
            s -= lu[i, p] * y[p]
        y[i] = s
    for i in range(n - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, n):
            s -= lu[i, p] * y[p]
        y[i] = s / lu[i, i]
    return y


@njit(cache=True)
def _forces(q, qd, u, a0, m, loads):
    """``B u + tau_ext - C qdot - M(q) a0`` (everything but ``K q`` and ``D qdot``)."""
    mm, _, cqd, tau, _, _, _ = K.coupled_terms(q, qd, m, loads, False)
    return K._matvec(K.input_matrix(q, m), u) + tau - cqd - K._matvec(mm, a0)


@njit(cache=True)
def tangent_matrix(q, qd, u, a0, m, loads):
    """Forward-difference ``J_q = d/dq [B u + tau_ext - C qdot - M(q) a0]`` (n x n)."""
    n = q.shape[0]
    g0 = _forces(q, qd, u, a0, m, loads)
    jq = np.empty((n, n))
    for i in range(n):
        e = 1e-7 * max(1.0, abs(q[i]))
        qp = q.copy()
        qp[i] += e
        gi = _forces(qp, qd, u, a0, m, loads)
        for r in range(n):
            jq[r, i] = (gi[r] - g0[r]) / e
    return jq


@njit(cache=True)
def rosw_step(q, qd, u, h, m, loads, a_t, c_t, m_t, e_t, gamma):
    """One ROS34PW2 step of size ``h``: returns ``(q1, qd1, err_q, err_v, ok)`` (``err_*`` the
    embedded error estimates; ``ok`` False when ``M`` is not positive definite, ``S`` is
    singular or a state is not finite)."""
    n = q.shape[0]
    ns = m_t.shape[0]
    uq = np.zeros((ns, n))
    uv = np.zeros((ns, n))
    c = h * gamma
    bad = np.full(n, np.inf)
    a0, m0, ok = dynamics_and_mass(q, qd, u, m, loads)
    if not ok:
        return q, qd, bad, bad, False
    kt = m.stiffness - tangent_matrix(q, qd, u, a0, m, loads)
    lu, piv, ok = _lu(m0 + c * m.damping + (c * c) * kt)
    if not ok:
        return q, qd, bad, bad, False
    for i in range(ns):
        yq = q.copy()
        yv = qd.copy()
        for j in range(i):
            aij = a_t[i, j]
            if aij != 0.0:
                for r in range(n):
                    yq[r] += aij * uq[j, r]
                    yv[r] += aij * uv[j, r]
        if i == 0:
            qdd = a0.copy()
        else:
            qdd, ok = K.forward_dynamics(yq, yv, u, m, loads)
            if not ok:
                return q, qd, bad, bad, False
        rq = yv.copy()
        rv = qdd
        for j in range(i):
            cij = c_t[i, j] / h
            for r in range(n):
                rq[r] += cij * uq[j, r]
                rv[r] += cij * uv[j, r]
        v = _lu_solve(lu, piv, c * (K._matvec(m0, rv) - c * K._matvec(kt, rq)))
        for r in range(n):
            uv[i, r] = v[r]
            uq[i, r] = c * (rq[r] + v[r])
    q1 = q.copy()
    qd1 = qd.copy()
    eq = np.zeros(n)
    ev = np.zeros(n)
    for i in range(ns):
        for r in range(n):
            q1[r] += m_t[i] * uq[i, r]
            qd1[r] += m_t[i] * uv[i, r]
            eq[r] += e_t[i] * uq[i, r]
            ev[r] += e_t[i] * uv[i, r]
    fin = 0.0
    for r in range(n):
        fin += q1[r] * q1[r] + qd1[r] * qd1[r]
    if not np.isfinite(fin):
        return q, qd, bad, bad, False
    return q1, qd1, eq, ev, True


@njit(cache=True)
def _err_norm(q, qd, q1, qd1, eq, ev, rtol, atol_q, atol_v):
    acc = 0.0
    n = q.shape[0]
    for r in range(n):
        sq = atol_q + rtol * max(abs(q[r]), abs(q1[r]))
        sv = atol_v + rtol * max(abs(qd[r]), abs(qd1[r]))
        acc += (eq[r] / sq) ** 2 + (ev[r] / sv) ** 2
    return np.sqrt(acc / (2 * n))


@njit(cache=True)
def rosw_run(q0, qd0, u, duration, record_dt, h0, h_max, rtol, atol_q, atol_v, m, loads):
    """Integrate ``duration`` seconds at constant input ``u`` with ROS34PW2.

    ``rtol > 0``: adaptive steps (at most ``h_max``; first try ``h0``) with the embedded error
    estimate, weighted RMS norm ``|e_i| / (atol_i + rtol |y_i|)`` over positions (``atol_q``)
    and velocities (``atol_v``) below 1; steps end exactly on the record times.  ``rtol <= 0``:
    fixed steps ``h0`` (``record_dt`` must be a multiple).  Returns
    ``(t, qs, qds, ok, n_accepted, n_rejected, h_last)``, states every ``record_dt``.
    """
    n = q0.shape[0]
    nrec = int(np.floor(duration / record_dt + 1e-9)) + 1
    ts = np.empty(nrec)
    qs = np.empty((nrec, n))
    qds = np.empty((nrec, n))
    q = q0.copy()
    qd = qd0.copy()
    ts[0] = 0.0
    qs[0] = q
    qds[0] = qd
    t = 0.0
    h = min(h0, h_max)
    adaptive = rtol > 0.0
    n_acc = 0
    n_rej = 0
    a_t, c_t, m_t, e_t = A_T, C_T, M_T, E_T
    for rec in range(1, nrec):
        t_rec = rec * record_dt
        while t < t_rec - 1e-12 * record_dt:
            hs = min(h, t_rec - t)
            last = hs >= t_rec - t - 1e-12 * record_dt
            q1, qd1, eq, ev, ok = rosw_step(q, qd, u, hs, m, loads, a_t, c_t, m_t, e_t, GAMMA)
            if not adaptive:
                if not ok:
                    return ts[:rec], qs[:rec], qds[:rec], False, n_acc, n_rej, h
                q, qd = q1, qd1
                t = t_rec if last else t + hs
                n_acc += 1
                continue
            err = _err_norm(q, qd, q1, qd1, eq, ev, rtol, atol_q, atol_v) if ok else np.inf
            if err <= 1.0:
                q, qd = q1, qd1
                t = t_rec if last else t + hs
                n_acc += 1
                fac = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** (-1.0 / 3.0)))
                # a step shortened to land on a record time does not shrink the next one
                h = min(h_max, max(h, hs * fac) if last and hs < h else hs * fac)
            else:
                n_rej += 1
                h = hs * (0.2 if not np.isfinite(err) else max(0.2, 0.9 * err ** (-1.0 / 3.0)))
                if h < 1e-12:
                    return ts[:rec], qs[:rec], qds[:rec], False, n_acc, n_rej, h
        ts[rec] = t_rec
        qs[rec] = q
        qds[rec] = qd
    return ts, qs, qds, True, n_acc, n_rej, h


# ---------------------------------------------------------------------------------- Radau IIA
def _radau_tableau():
    r6 = np.sqrt(6.0)
    c = np.array([(4.0 - r6) / 10.0, (4.0 + r6) / 10.0, 1.0])
    a = np.array(
        [
            [(88.0 - 7.0 * r6) / 360.0, (296.0 - 169.0 * r6) / 1800.0, (-2.0 + 3.0 * r6) / 225.0],
            [(296.0 + 169.0 * r6) / 1800.0, (88.0 + 7.0 * r6) / 360.0, (-2.0 - 3.0 * r6) / 225.0],
            [(16.0 - r6) / 36.0, (16.0 + r6) / 36.0, 1.0 / 9.0],
        ]
    )
    return c, a


RADAU_C, RADAU_A = _radau_tableau()


@njit(cache=True)
def _f(y, u, m, loads, n):
    out = np.empty(2 * n)
    qdd, ok = K.forward_dynamics(y[:n], y[n:], u, m, loads)
    out[:n] = y[n:]
    out[n:] = qdd
    return out, ok


@njit(cache=True)
def state_jacobian(y, u, m, loads, n, full_v):
    """Jacobian of ``y' = f(y) = [qd; qdd(q, qd)]`` (2n x 2n).

    The ``[I]`` block is exact; ``d qdd / dq`` by forward differences, skipping the drone
    position (``qdd`` does not depend on it: uniform gravity, no ground); ``d qdd / dqd`` by
    forward differences when ``full_v``, else ``-M^-1 D`` (the damping part; the Coriolis part is
    left to the Newton iteration).  Costs ``n - 2`` (``2 n - 2`` with ``full_v``) evaluations.
    """
    nn = 2 * n
    jac = np.zeros((nn, nn))
    f0, mm, ok = dynamics_and_mass(y[:n], y[n:], u, m, loads)
    if not ok:
        return jac, False
    for i in range(n):
        jac[i, n + i] = 1.0
    for i in range(nn):
        if m.floating and 3 <= i < 6:
            continue
        if i >= n and not full_v:
            break
        e = 1e-7 * max(1.0, abs(y[i]))
        yp = y.copy()
        yp[i] += e
        fp, ok = K.forward_dynamics(yp[:n], yp[n:], u, m, loads)
        if not ok:
            return jac, False
        for r in range(n):
            jac[n + r, i] = (fp[r] - f0[r]) / e
    if not full_v:
        col = np.empty(n)
        for c in range(n):
            for r in range(n):
                col[r] = -m.damping[r, c]
            x, ok = K.cholesky_solve(mm, col)
            for r in range(n):
                jac[n + r, n + c] = x[r]
    return jac, True


@njit(cache=True)
def _radau_matrix(jac, h, a):
    """``I - h (A kron J)`` (3N x 3N) of the simplified Newton iteration."""
    nn = jac.shape[0]
    g = np.zeros((3 * nn, 3 * nn))
    for i in range(3):
        for j in range(3):
            hij = h * a[i, j]
            for r in range(nn):
                for c in range(nn):
                    g[i * nn + r, j * nn + c] = -hij * jac[r, c]
    for r in range(3 * nn):
        g[r, r] += 1.0
    return g


@njit(cache=True)
def radau_run(
    q0, qd0, u, h, nsteps, every, m, loads, tol_q, tol_v, max_iter, slow_iter, full_v, stall_ok
):
    """Integrate ``nsteps`` fixed steps ``h`` of the 3-stage Radau IIA method (order 5, L-stable,
    stiffly accurate) at constant input ``u``; keep every ``every``-th state.

    The stage equations are solved by simplified Newton iterations with a forward-difference
    Jacobian that is *reused* across steps (recomputed only when an iteration converges slowly
    or fails: more than ``slow_iter`` iterations); the stage values start from the previous step's collocation polynomial.  An
    iteration has converged when the weighted RMS norm of its update, weights
    ``tol_q (1 + |q_i|)`` and ``tol_v (1 + |qd_i|)``, is below 1 (the velocities of the stiff
    modes carry the round-off of ``M^-1``, whose condition number reaches 1e8-1e10 with torsion:
    their updates stagnate near 1e-4, hence a looser ``tol_v``); an iteration that stalls
    (contraction above 0.9) with a norm below ``stall_ok`` has reached that floor and is
    accepted too.  ``full_v``: see :func:`state_jacobian`.  A step whose iteration fails even
    with a fresh Jacobian is split in two (recursively, down to ``h / 64``).

    Returns ``(qs, qds, ok, stats)`` with ``stats = [f evaluations, Jacobians, LU
    factorizations, Newton iterations, split steps]``.
    """
    n = q0.shape[0]
    nn = 2 * n
    c = RADAU_C
    a = RADAU_A
    nrec = nsteps // every + 1
    qs = np.empty((nrec, n))
    qds = np.empty((nrec, n))
    qs[0] = q0
    qds[0] = qd0
    y = np.empty(nn)
    y[:n] = q0
    y[n:] = qd0
    stats = np.zeros(5, dtype=np.int64)
    f0, ok = _f(y, u, m, loads, n)
    stats[0] += 1
    if not ok:
        return qs[:1], qds[:1], False, stats
    jac, ok = state_jacobian(y, u, m, loads, n, full_v)
    stats[0] += (nn if full_v else n) - (2 if m.floating else -1)
    stats[1] += 1
    hj = h
    lu, piv, ok = _lu(_radau_matrix(jac, hj, a))
    stats[2] += 1
    z = np.zeros((3, nn))  # stage increments of the last step (for the extrapolation)
    have_prev = False
    fresh = True
    rec = 1
    k = 0
    sub = 1  # current number of substeps per step (after failures)
    while k < nsteps:
        hs = h / sub
        done_sub = 0
        while done_sub < sub:
            if hs != hj:
                lu, piv, ok = _lu(_radau_matrix(jac, hs, a))
                stats[2] += 1
                hj = hs
                have_prev = False
            # initial stage values: previous collocation polynomial, or h c_i f(y0)
            zz = np.empty((3, nn))
            if have_prev:
                for i in range(3):
                    s = 1.0 + c[i]
                    # Lagrange basis through nodes 0, c1, c2, c3 (value 0 at node 0)
                    for r in range(nn):
                        acc = 0.0
                        for j in range(3):
                            lj = s / c[j]
                            for p in range(3):
                                if p != j:
                                    lj *= (s - c[p]) / (c[j] - c[p])
                            acc += lj * z[j, r]
                        zz[i, r] = acc - z[2, r]
            else:
                for i in range(3):
                    for r in range(nn):
                        zz[i, r] = hs * c[i] * f0[r]
            converged = False
            theta_bad = False
            old = 0.0
            fs = np.empty((3, nn))
            for it in range(max_iter):
                ok_all = True
                for i in range(3):
                    fi, oki = _f(y + zz[i], u, m, loads, n)
                    stats[0] += 1
                    if not oki:
                        ok_all = False
                        break
                    fs[i] = fi
                if not ok_all:
                    break
                rhs = np.empty(3 * nn)
                for i in range(3):
                    for r in range(nn):
                        acc = -zz[i, r]
                        for j in range(3):
                            acc += hs * a[i, j] * fs[j, r]
                        rhs[i * nn + r] = acc
                dz = _lu_solve(lu, piv, rhs)
                stats[3] += 1
                nrm = 0.0
                for i in range(3):
                    for r in range(nn):
                        zz[i, r] += dz[i * nn + r]
                        w = (tol_q if r < n else tol_v) * (1.0 + abs(y[r]))
                        nrm += (dz[i * nn + r] / w) ** 2
                nrm = np.sqrt(nrm / (3 * nn))
                if not np.isfinite(nrm):
                    break
                if it > 0:
                    theta = nrm / old
                    if theta > 0.9:
                        # stagnation at the round-off floor of M^-1 is convergence
                        converged = nrm <= stall_ok
                        theta_bad = not converged
                        break
                if nrm <= 1.0:
                    converged = True
                    break
                old = nrm
            if converged:
                for r in range(nn):
                    y[r] += zz[2, r]
                for i in range(3):
                    for r in range(nn):
                        z[i, r] = zz[i, r]
                f0 = fs[2].copy()  # f at the last iterate (a starting guess only)
                have_prev = True
                done_sub += 1
                # a slow iteration: refresh the Jacobian for the next step
                if it >= slow_iter and not fresh:
                    jac, okj = state_jacobian(y, u, m, loads, n, full_v)
                    stats[0] += (nn if full_v else n) - (2 if m.floating else -1)
                    stats[1] += 1
                    lu, piv, ok = _lu(_radau_matrix(jac, hs, a))
                    stats[2] += 1
                    fresh = True
                else:
                    fresh = False
                continue
            # failure: fresh Jacobian first, then split the step
            if not fresh:
                jac, okj = state_jacobian(y, u, m, loads, n, full_v)
                stats[0] += (nn if full_v else n) - (2 if m.floating else -1)
                stats[1] += 1
                if not okj:
                    return qs[:rec], qds[:rec], False, stats
                lu, piv, ok = _lu(_radau_matrix(jac, hs, a))
                stats[2] += 1
                fresh = True
                have_prev = False
                continue
            if sub >= 64 or theta_bad and sub >= 64:
                return qs[:rec], qds[:rec], False, stats
            sub *= 2
            done_sub *= 2
            hs = h / sub
            stats[4] += 1
            fresh = False  # the Jacobian is still fresh; force the LU update only
            have_prev = False
        sub = max(1, sub // 2) if sub > 1 else 1
        k += 1
        if k % every == 0:
            qs[rec] = y[:n]
            qds[rec] = y[n:]
            rec += 1
    return qs, qds, True, stats
