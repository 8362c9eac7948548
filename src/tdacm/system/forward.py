"""The forward-dynamics terms ``M``, ``C qdot`` and ``tau_ext`` (paper eqs. (9)-(11), (16)) in
one recursion along the rods, written for speed.

The same recursion and the same floating-point operations, in the same order, as
:func:`tdacm.system.kernels.coupled_terms_env` with ``want_c = False`` (the arithmetic of each
entry is unchanged, so the results are identical), but:

* the Jacobian is stored transposed, ``J^T`` (n x 6): each column of ``J`` is a contiguous
  twist, and ``Ad^-1``, ``ad`` and the tangent operator act on one twist at a time held in
  registers;
* only the columns of ``J`` that can be non-zero are visited: a column of a strain coordinate
  becomes non-zero at the first Magnus step of its section (eq. (9): the rod's columns before
  that step are exactly zero), so the products and sums with the later sections' columns,
  which add exact zeros, are skipped;
* ``J_dot`` is not propagated (the forward dynamics needs only ``J_dot qdot``), nor ``Z_dot``;
* ``J^T Mb`` is formed once per column for ``M += w J^T Mb J`` (eq. (10)), and the tangent
  coefficients are scalars instead of arrays: no allocation inside the loop over the steps.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..aero import layout as AL
from ..lie.blocks import expmap_rp_into
from ..lie.se3 import _A1, _A2, _A3, _A4, SMALL_ANGLE, _dseries, _series
from . import kernels as K

_C4 = np.sqrt(3.0) / 12.0


@njit(cache=True)
def tangent_coefficients_scalar(th):
    """:func:`tdacm.lie.se3.tangent_coefficients` as eight scalars (the same arithmetic)."""
    if th < SMALL_ANGLE:
        t2 = th * th
        return (
            _series(_A1, t2), _series(_A2, t2), _series(_A3, t2), _series(_A4, t2),
            _dseries(_A1, t2), _dseries(_A2, t2), _dseries(_A3, t2), _dseries(_A4, t2),
        )  # fmt: skip
    s = np.sin(th)
    c = np.cos(th)
    t2 = th * th
    t3 = t2 * th
    t4 = t2 * t2
    a0 = (4.0 - 4.0 * c - th * s) / (2.0 * t2)
    a1 = (4.0 * th - 5.0 * s + th * c) / (2.0 * t3)
    a2 = (2.0 - 2.0 * c - th * s) / (2.0 * t4)
    a3 = (2.0 * th - 3.0 * s + th * c) / (2.0 * t4 * th)
    p = 5.0 * th * s - t2 * c - 8.0 + 8.0 * c
    r = -8.0 * th - 7.0 * th * c - t2 * s + 15.0 * s
    return (
        a0, a1, a2, a3,
        p / (2.0 * t4), r / (2.0 * t4 * th), p / (2.0 * t4 * t2), r / (2.0 * t4 * t3),
    )  # fmt: skip


@njit(cache=True, inline="always")
def _ad(k0, k1, k2, u0, u1, u2, a0, a1, a2, b0, b1, b2):
    """``ad(xi) x`` for ``xi = [k; u]``, ``x = [a; b]`` (:func:`tdacm.lie.blocks.ad_apply`)."""
    return (
        k1 * a2 - k2 * a1,
        k2 * a0 - k0 * a2,
        k0 * a1 - k1 * a0,
        u1 * a2 - u2 * a1 + k1 * b2 - k2 * b1,
        u2 * a0 - u0 * a2 + k2 * b0 - k0 * b2,
        u0 * a1 - u1 * a0 + k0 * b1 - k1 * b0,
    )


@njit(cache=True)
def _tangent_row(om, co, x, out):
    """``out = T(Omega) x`` for one twist ``x`` (6,): ``x + sum a_i ad(Omega)^i x``, the
    recursion of :func:`tdacm.lie.blocks.tangent_apply_into`; ``co = (a_1..a_4, ...)``."""
    k0, k1, k2, u0, u1, u2 = om[0], om[1], om[2], om[3], om[4], om[5]
    p0, p1, p2, p3, p4, p5 = x[0], x[1], x[2], x[3], x[4], x[5]
    t0, t1, t2, t3, t4, t5 = p0, p1, p2, p3, p4, p5
    for i in range(4):
        ai = co[i]
        p0, p1, p2, p3, p4, p5 = _ad(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        t0 += ai * p0
        t1 += ai * p1
        t2 += ai * p2
        t3 += ai * p3
        t4 += ai * p4
        t5 += ai * p5
    out[0], out[1], out[2], out[3], out[4], out[5] = t0, t1, t2, t3, t4, t5


@njit(cache=True)
def _tangent_rate_row(om, omd, co, x, out, dout):
    """``out = T(Omega) x`` and ``dout = T_dot x`` for one twist (the rate recursion of
    :func:`tdacm.lie.blocks.tangent_apply_into`: ``D_i = ad(Omega_dot) P_{i-1} + ad(Omega)
    D_{i-1}``, ``T_dot x = sum b_i (w . w_dot) P_i + a_i D_i``)."""
    k0, k1, k2, u0, u1, u2 = om[0], om[1], om[2], om[3], om[4], om[5]
    e0, e1, e2, e3, e4, e5 = omd[0], omd[1], omd[2], omd[3], omd[4], omd[5]
    wwd = om[0] * omd[0] + om[1] * omd[1] + om[2] * omd[2]
    p0, p1, p2, p3, p4, p5 = x[0], x[1], x[2], x[3], x[4], x[5]
    t0, t1, t2, t3, t4, t5 = p0, p1, p2, p3, p4, p5
    d0 = d1 = d2 = d3 = d4 = d5 = 0.0
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    for i in range(4):
        ai = co[i]
        bi = co[4 + i] * wwd
        c0, c1, c2, c3, c4, c5 = _ad(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        f0, f1, f2, f3, f4, f5 = _ad(e0, e1, e2, e3, e4, e5, p0, p1, p2, p3, p4, p5)
        g0, g1, g2, g3, g4, g5 = _ad(k0, k1, k2, u0, u1, u2, d0, d1, d2, d3, d4, d5)
        d0, d1, d2, d3, d4, d5 = f0 + g0, f1 + g1, f2 + g2, f3 + g3, f4 + g4, f5 + g5
        t0 += ai * c0
        t1 += ai * c1
        t2 += ai * c2
        t3 += ai * c3
        t4 += ai * c4
        t5 += ai * c5
        s0 += bi * c0 + ai * d0
        s1 += bi * c1 + ai * d1
        s2 += bi * c2 + ai * d2
        s3 += bi * c3 + ai * d3
        s4 += bi * c4 + ai * d4
        s5 += bi * c5 + ai * d5
        p0, p1, p2, p3, p4, p5 = c0, c1, c2, c3, c4, c5
    out[0], out[1], out[2], out[3], out[4], out[5] = t0, t1, t2, t3, t4, t5
    dout[0], dout[1], dout[2], dout[3], dout[4], dout[5] = s0, s1, s2, s3, s4, s5


@njit(cache=True)
def _adinv_row(r, p, x):
    """``x <- Ad(g)^-1 x`` for one twist ``x`` (6,), ``g = (r, p)``
    (:func:`tdacm.lie.blocks.adinv_apply`)."""
    a0, a1, a2 = x[0], x[1], x[2]
    b0 = x[3] - (p[1] * a2 - p[2] * a1)
    b1 = x[4] - (p[2] * a0 - p[0] * a2)
    b2 = x[5] - (p[0] * a1 - p[1] * a0)
    for i in range(3):
        x[i] = r[0, i] * a0 + r[1, i] * a1 + r[2, i] * a2
        x[3 + i] = r[0, i] * b0 + r[1, i] * b1 + r[2, i] * b2


@njit(cache=True)
def _rows_adinv(r, p, jt, ncols):
    for c in range(ncols):
        _adinv_row(r, p, jt[c])


@njit(cache=True)
def _matvec_t(jt, x, ncols, out):
    """``out = J x`` (6,) from ``J^T`` (n x 6), over its first ``ncols`` rows (the others are
    zero)."""
    for i in range(6):
        acc = 0.0
        for k in range(ncols):
            acc += jt[k, i] * x[k]
        out[i] = acc


@njit(cache=True)
def _tmatvec_add_t(jt, f, weight, ncols, out):
    """``out += weight J^T f`` (:func:`tdacm.system.kernels._tmatvec_add`) from ``J^T``."""
    for k in range(ncols):
        a = jt[k]
        out[k] += weight * (
            0.0 + a[0] * f[0] + a[1] * f[1] + a[2] * f[2] + a[3] * f[3] + a[4] * f[4] + a[5] * f[5]
        )


@njit(cache=True)
def _add_body_t(mass6, jt, eta, jdq, weight, ncols, m_out, cqd_out, mj):
    """``M += w J^T Mb J`` and ``C qdot += w J^T (Mb J_dot qdot + coad(eta) Mb eta)`` (paper eqs.
    (10), (11)) with ``J^T`` (n x 6) over its first ``ncols`` rows; ``mj`` is an (n, 6)
    scratch array (:func:`tdacm.system.kernels._add_body`, ``want_c = False``)."""
    for a in range(ncols):
        for r in range(6):
            mj[a, r] = jt[a, r] * mass6[r]
    for a in range(ncols):
        x0, x1, x2, x3, x4, x5 = mj[a, 0], mj[a, 1], mj[a, 2], mj[a, 3], mj[a, 4], mj[a, 5]
        acc = 0.0 + x0 * jt[a, 0] + x1 * jt[a, 1] + x2 * jt[a, 2] + x3 * jt[a, 3]
        acc = acc + x4 * jt[a, 4] + x5 * jt[a, 5]
        m_out[a, a] += weight * acc
        for b in range(a + 1, ncols):
            y = jt[b]
            acc = 0.0 + x0 * y[0] + x1 * y[1] + x2 * y[2] + x3 * y[3] + x4 * y[4] + x5 * y[5]
            m_out[a, b] += weight * acc
            m_out[b, a] += weight * acc
    m0, m1, m2 = mass6[0] * eta[0], mass6[1] * eta[1], mass6[2] * eta[2]
    p0, p1, p2 = mass6[3] * eta[3], mass6[4] * eta[4], mass6[5] * eta[5]
    w0, w1, w2, v0, v1, v2 = eta[0], eta[1], eta[2], eta[3], eta[4], eta[5]
    f0 = mass6[0] * jdq[0] - (m1 * w2 - m2 * w1 + p1 * v2 - p2 * v1)
    f1 = mass6[1] * jdq[1] - (m2 * w0 - m0 * w2 + p2 * v0 - p0 * v2)
    f2 = mass6[2] * jdq[2] - (m0 * w1 - m1 * w0 + p0 * v1 - p1 * v0)
    f3 = mass6[3] * jdq[3] - (p1 * w2 - p2 * w1)
    f4 = mass6[4] * jdq[4] - (p2 * w0 - p0 * w2)
    f5 = mass6[5] * jdq[5] - (p0 * w1 - p1 * w0)
    for a in range(ncols):
        j = jt[a]
        cqd_out[a] += weight * (
            j[0] * f0 + j[1] * f1 + j[2] * f2 + j[3] * f3 + j[4] * f4 + j[5] * f5
        )


@njit(cache=True)
def make_rate_workspace(n, ns):
    """Scratch arrays of :func:`rod_step_rate` (allocated once per evaluation)."""
    return (
        np.empty(6),  # 0 Omega
        np.empty((ns + 2, 6)),  # 1 columns: Omega_dot, Z^T, Z_dot qdot
        np.empty((ns + 2, 6)),  # 2 T(Omega) applied to them
        np.empty(6),  # 3 T_dot Omega_dot
        np.empty((3, 3)),  # 4 R of exp(Omega)
        np.empty(3),  # 5 p of exp(Omega)
        np.empty((4, 6)),  # 6 xi1, xi2, v1, v2 (order 4)
        np.empty((3, 6)),  # 7 relative twist, J_dot qdot, eta
        np.empty((3, 3)),  # 8 copy of the rotation of g
        np.empty((n, 6)),  # 9 J^T Mb
    )


@njit(cache=True)
def rod_step_rate(h, xi0s, bs, qs, qsd, off, g, jt, ncols, eta, jdq, ws):
    """One Magnus step of the pose / Jacobian recursion (paper eqs. (7), (9)) with ``J^T``
    (n x 6), the twist ``eta = J qdot`` and ``J_dot qdot`` updated in place; the arithmetic of
    :func:`tdacm.system.kernels.rod_step` with ``full_rate = False``.  The step's strain
    coordinates are ``off .. off + len(qs)``; only the first ``ncols`` rows of ``J^T`` can be
    non-zero after it (the others are left untouched: zero)."""
    omega, xc, tx, tdx, r, p, xiv, cols, gr, _ = ws
    ns = qs.shape[0]
    order4 = xi0s.shape[0] == 2
    # Magnus step (tdacm.lie.magnus.magnus_step_into): Omega, Z^T (rows 1..ns), Z_dot qdot
    if not order4:
        b = bs[0]
        for rr in range(6):
            acc = xi0s[0, rr]
            for c in range(ns):
                acc += b[rr, c] * qs[c]
            omega[rr] = acc * h
            for c in range(ns):
                xc[1 + c, rr] = h * b[rr, c]
    else:
        b0 = bs[0]
        b1 = bs[1]
        xi1, xi2, v1, v2 = xiv[0], xiv[1], xiv[2], xiv[3]
        for rr in range(6):
            a1 = xi0s[0, rr]
            a2 = xi0s[1, rr]
            s1 = 0.0
            s2 = 0.0
            for c in range(ns):
                a1 += b0[rr, c] * qs[c]
            for c in range(ns):
                a2 += b1[rr, c] * qs[c]
            for c in range(ns):
                s1 += b0[rr, c] * qsd[c]
            for c in range(ns):
                s2 += b1[rr, c] * qsd[c]
            xi1[rr], xi2[rr], v1[rr], v2[rr] = a1, a2, s1, s2
        c4 = _C4 * h * h
        a12 = _ad(xi1[0], xi1[1], xi1[2], xi1[3], xi1[4], xi1[5],
                  xi2[0], xi2[1], xi2[2], xi2[3], xi2[4], xi2[5])  # fmt: skip
        v12 = _ad(v1[0], v1[1], v1[2], v1[3], v1[4], v1[5],
                  v2[0], v2[1], v2[2], v2[3], v2[4], v2[5])  # fmt: skip
        for rr in range(6):
            omega[rr] = 0.5 * h * (xi1[rr] + xi2[rr]) + c4 * a12[rr]
            xc[ns + 1, rr] = 2.0 * c4 * v12[rr]
        for c in range(ns):
            t1 = _ad(xi1[0], xi1[1], xi1[2], xi1[3], xi1[4], xi1[5],
                     b1[0, c], b1[1, c], b1[2, c], b1[3, c], b1[4, c], b1[5, c])  # fmt: skip
            t2 = _ad(xi2[0], xi2[1], xi2[2], xi2[3], xi2[4], xi2[5],
                     b0[0, c], b0[1, c], b0[2, c], b0[3, c], b0[4, c], b0[5, c])  # fmt: skip
            for rr in range(6):
                xc[1 + c, rr] = 0.5 * h * (b0[rr, c] + b1[rr, c]) + c4 * (t1[rr] - t2[rr])
    # Omega_dot = Z qdot
    for i in range(6):
        acc = 0.0
        for c in range(ns):
            acc += xc[1 + c, i] * qsd[c]
        xc[0, i] = acc
    expmap_rp_into(omega, r, p)
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    co = tangent_coefficients_scalar(th)
    _tangent_rate_row(omega, xc[0], co, xc[0], tx[0], tdx)
    for c in range(1, ns + 1):
        _tangent_row(omega, co, xc[c], tx[c])
    if order4:
        _tangent_row(omega, co, xc[ns + 1], tx[ns + 1])
    # increments before the change of frame; T Omega_dot is the relative twist of the step
    w = cols[0]
    v = cols[1]
    e = cols[2]
    for c in range(ns):
        row = jt[off + c]
        src = tx[1 + c]
        for i in range(6):
            row[i] += src[i]
    for i in range(6):
        w[i] = tx[0, i]
        v[i] = jdq[i] + tdx[i] + (tx[ns + 1, i] if order4 else 0.0)
        e[i] = eta[i] + tx[0, i]
    _rows_adinv(r, p, jt, ncols)
    _adinv_row(r, p, w)
    _adinv_row(r, p, v)
    _adinv_row(r, p, e)
    t = _ad(w[0], w[1], w[2], w[3], w[4], w[5], e[0], e[1], e[2], e[3], e[4], e[5])
    for i in range(6):
        eta[i] = e[i]
        jdq[i] = v[i] - t[i]
    # g <- g exp(Omega)
    for i in range(3):
        for k in range(3):
            gr[i, k] = g[i, k]
    for i in range(3):
        acc = 0.0
        for k in range(3):
            acc += gr[i, k] * p[k]
        g[i, 3] += acc
        for c in range(3):
            acc = 0.0
            for k in range(3):
                acc += gr[i, k] * r[k, c]
            g[i, c] = acc


@njit(cache=True)
def _add_point_force_t(jt, g, fx, fy, fz, ncols, tau):
    """``tau += J^T [0; R^T f]`` (:func:`tdacm.system.kernels._add_point_force`)."""
    f = np.zeros(6)
    for i in range(3):
        f[3 + i] = g[0, i] * fx + g[1, i] * fy + g[2, i] * fz
    _tmatvec_add_t(jt, f, 1.0, ncols, tau)


@njit(cache=True)
def forward_terms(q, qd, m, loads, u, aero, contact):
    """``M``, ``C qdot``, ``tau_ext`` (paper eqs. (10), (11), (16)), the last rod's tip pose,
    its ``J^T`` (n x 6) and its base's ``J_dot`` (6 x n): the outputs of
    :func:`tdacm.system.kernels.coupled_terms_env` with ``want_c = False``, computed with the
    same arithmetic (module docstring)."""
    floating = m.floating
    n = q.shape[0]
    off = 6 if floating else 0
    m_out = np.zeros((n, n))
    cqd = np.zeros(n)
    tau = np.zeros(n)
    grav = loads[0:3]
    gb, jb, jbd = K.base_state(q, qd, floating, m.g_fixed, n)
    jbt = np.ascontiguousarray(jb.T)
    jbdt = np.ascontiguousarray(jbd.T)
    nb = off  # the base's Jacobian has non-zero columns only for the drone's coordinates
    f = np.empty(6)
    vec = np.empty((2, 6))
    air = aero.shape[0] > 0
    drone_air = air and floating and aero[AL.DRONE_ON] > 0.0
    rod_air = air and aero[AL.ROD_ON] > 0.0
    wake = rod_air and aero[AL.WAKE_ON] > 0.0
    rot = np.empty((AL.N_ROTORS, AL.ROTOR_STATE))
    ax = ay = az = 0.0
    if wake:
        ax, ay, az = K._rotor_setup(q, qd, u, m, gb, aero, rot)
    nst = m.h.shape[0]
    ws = make_rate_workspace(n, m.bs.shape[3])
    mj = ws[9]
    if floating:
        eb = vec[0]
        _matvec_t(jbt, qd, n, eb)
        _matvec_t(jbdt, qd, n, vec[1])
        _add_body_t(m.mb6, jbt, eb, vec[1], 1.0, nb, m_out, cqd, mj)
        for i in range(6):
            f[i] = loads[3 + i]
        for i in range(3):
            for k in range(3):
                f[3 + i] += m.mb6[3] * gb[k, i] * grav[k]
        if drone_air:
            d0, d1, d2 = K._air_on_drone(gb, eb, aero)
            f[3] += d0
            f[4] += d1
            f[5] += d2
        _tmatvec_add_t(jbt, f, 1.0, nb, tau)
    g = np.eye(4)
    jt = np.zeros((n, 6))
    jd = np.zeros((6, n))
    eta = np.empty(6)
    jdq = np.empty(6)
    cont = contact.shape[0] > 0
    prev = np.empty(6)
    fa = np.empty(6)
    fb = np.empty(3)
    mb = np.zeros(3)
    probe = cont and K._has_probe(contact)
    g_prev = np.eye(4)
    jt_prev = np.zeros((n, 6))
    ra = np.empty((3, 3))
    pa = np.empty(3)
    for rod in range(m.rod_steps.shape[0] - 1):
        # rod base: J_a = Ad(g_a^b)^-1 J_b^b (kernels.rod_start)
        ga = m.g_att[rod]
        for i in range(3):
            pa[i] = ga[i, 3]
            for k in range(3):
                ra[i, k] = ga[i, k]
        jt[:, :] = jbt
        jdt = jbdt.copy()
        _rows_adinv(ra, pa, jt, n)
        _rows_adinv(ra, pa, jdt, n)
        g = K._matmul(gb, ga)
        jd = np.ascontiguousarray(jdt.T)
        _matvec_t(jdt, qd, n, jdq)
        _matvec_t(jt, qd, n, eta)
        nact = nb
        if cont:
            K._rod_base_node(g, eta, prev)
            g_prev[:] = g
            jt_prev[:] = jt
        for k in range(m.rod_steps[rod], m.rod_steps[rod + 1]):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            if c1 > nact:
                nact = c1
            rod_step_rate(
                m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], qd[c0:c1], c0, g, jt, nact, eta, jdq, ws
            )
            w = m.step_w[k]
            if w == 0.0:
                continue
            mass6 = m.step_mass[k]
            if mass6[3] == 0.0 and mass6[0] == 0.0 and mass6[1] == 0.0 and mass6[2] == 0.0:
                pass
            else:
                _add_body_t(mass6, jt, eta, jdq, w, nact, m_out, cqd, mj)
            lo = m.step_load[k]
            if lo == K.LOAD_GRAVITY:
                for i in range(6):
                    f[i] = 0.0
                for i in range(3):
                    for kk in range(3):
                        f[3 + i] += g[kk, i] * (mass6[3] * grav[kk])
            else:
                for i in range(6):
                    f[i] = loads[lo + i]
                for i in range(3):
                    for kk in range(3):
                        f[3 + i] += g[kk, i] * (mass6[3] * grav[kk] + loads[lo + 6 + kk])
                if rod_air:
                    a0, a1, a2 = K._air_on_body(
                        g, eta, k, lo == K.LOAD_TIP, aero, nst, rot, ax, ay, az, wake
                    )
                    f[3] += a0
                    f[4] += a1
                    f[5] += a2
            _tmatvec_add_t(jt, f, w, nact, tau)
            if cont and lo != K.LOAD_GRAVITY:
                hit_a, hit_b = K._node_contact(contact, k, g, eta, prev, fa, fb)
                mb[0] = mb[1] = mb[2] = 0.0
                if lo == K.LOAD_TIP and K._tip_contact(contact, g, eta, fb, mb):
                    hit_b = True
                if hit_a:
                    _add_point_force_t(jt_prev, g_prev, fa[0], fa[1], fa[2], n, tau)
                if hit_b:
                    _add_point_force_t(jt, g, fb[0], fb[1], fb[2], nact, tau)
                    if probe and lo == K.LOAD_TIP:
                        mv = np.array([mb[0], mb[1], mb[2], 0.0, 0.0, 0.0])
                        _tmatvec_add_t(jt, mv, 1.0, nact, tau)
                g_prev[:] = g
                jt_prev[:] = jt
    return m_out, cqd, tau, g, jt, jd
