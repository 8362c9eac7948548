"""The forward-dynamics terms ``M``, ``C qdot`` and ``tau_ext`` (paper eqs. (9)-(11), (16)) in
one recursion along the rods, written for speed.

The same recursion and the same floating-point operations, in the same order, as
:func:`tdacm.system.kernels.coupled_terms_env` with ``want_c = False`` (the arithmetic of each
entry is unchanged, so the results are identical), but:

* the Jacobian ``J`` (6 x n) is stored by rows, so that ``Ad^-1``, the tangent operator
  and ``M += w J^T Mb J`` (eq. (10)) run as loops over the columns (twists) with no dependence
  between iterations; written from index 0 over views (no wrap-around test on the index) and
  in place, the compiler vectorizes them (the same operations on several columns at once,
  each column's arithmetic unchanged);
* only the columns of ``J`` that can be non-zero are visited: a column of a strain coordinate
  becomes non-zero at the first Magnus step of its section (eq. (9): the rod's columns before
  that step are exactly zero), so the products and sums with the later sections' columns,
  which add exact zeros, are skipped;
* ``J_dot`` is not propagated (the forward dynamics needs only ``J_dot qdot``), nor ``Z_dot``;
* ``J^T Mb`` is formed once per column for ``M += w J^T Mb J``, whose upper triangle only is
  summed (every entry receives the same sums as its mirror: the lower triangle is copied at
  the end); the tangent coefficients are scalars; the drone's six sines and cosines are
  computed once for its rotation, Euler-rate matrix and its rate, which serve both the
  Jacobian and ``B(q)``, and ``B u`` is summed without forming ``B``;
* the scratch arrays of an evaluation are row blocks of eight arrays (:func:`workspace`),
  which :func:`rk4_steps` allocates once per call instead of once per evaluation;
* what depends on the model only is computed once when it is built (:func:`run_constants`,
  the last fields of :class:`~tdacm.system.kernels.ModelArrays`), with the operations the
  recursion performed per evaluation: the model part of each step's ``Z`` (``h B``,
  ``h/2 (B_1 + B_2)``) and Zanna's ``sqrt(3) h^2 / 12``; the non-zero columns of the basis
  blocks at the Magnus and Gauss points and of the rows of ``K`` and ``D``, whose sums skip
  exact zeros (``0 * x`` adds an exact zero to a sum); and which order-4 steps have equal
  samples (an order-0 basis), taken as one-sample steps (their commutators are exact zeros).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import kernel
from .._linalg import cholesky_into, cholesky_substitute
from ..aero import layout as AL
from ..lie.blocks import ad_scalars, compose_rp_into, expmap_rp_into
from ..lie.euler import euler_rates_into, rot_zyx_into
from ..lie.se3 import tangent_coefficients_scalars
from . import bodies as K

_C4 = np.sqrt(3.0) / 12.0


@kernel
def _copy_into(dst, src):
    """``dst[:, :] = src`` (2-D) without the runtime a slice assignment needs."""
    for i in range(dst.shape[0]):
        for k in range(dst.shape[1]):
            dst[i, k] = src[i, k]


@kernel
def _tangent_cols(om, co, x, c0, c1):
    """``x[:, c] <- T(Omega) x[:, c]`` for the twists ``c0 <= c < c1`` (columns of ``x``,
    6 x k): ``x + sum a_i ad(Omega)^i x``, the recursion of
    :func:`tdacm.lie.blocks.tangent_apply_into`; ``co = (a_1..a_4, ...)``.  The loop over the
    columns has no dependence between iterations and works in place (six arrays: the compiler
    vectorizes it)."""
    k0, k1, k2, u0, u1, u2 = om[0], om[1], om[2], om[3], om[4], om[5]
    a1, a2, a3, a4 = co[0], co[1], co[2], co[3]
    # views from c0: a loop from 0 has non-negative indices (no wrap-around test: vectorized)
    x0, x1, x2, x3, x4, x5 = (
        x[0, c0:c1],
        x[1, c0:c1],
        x[2, c0:c1],
        x[3, c0:c1],
        x[4, c0:c1],
        x[5, c0:c1],
    )
    o0, o1, o2, o3, o4, o5 = x0, x1, x2, x3, x4, x5
    for c in range(c1 - c0):
        p0, p1, p2, p3, p4, p5 = x0[c], x1[c], x2[c], x3[c], x4[c], x5[c]
        t0, t1, t2, t3, t4, t5 = p0, p1, p2, p3, p4, p5
        p0, p1, p2, p3, p4, p5 = ad_scalars(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        t0 += a1 * p0
        t1 += a1 * p1
        t2 += a1 * p2
        t3 += a1 * p3
        t4 += a1 * p4
        t5 += a1 * p5
        p0, p1, p2, p3, p4, p5 = ad_scalars(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        t0 += a2 * p0
        t1 += a2 * p1
        t2 += a2 * p2
        t3 += a2 * p3
        t4 += a2 * p4
        t5 += a2 * p5
        p0, p1, p2, p3, p4, p5 = ad_scalars(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        t0 += a3 * p0
        t1 += a3 * p1
        t2 += a3 * p2
        t3 += a3 * p3
        t4 += a3 * p4
        t5 += a3 * p5
        p0, p1, p2, p3, p4, p5 = ad_scalars(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        o0[c] = t0 + a4 * p0
        o1[c] = t1 + a4 * p1
        o2[c] = t2 + a4 * p2
        o3[c] = t3 + a4 * p3
        o4[c] = t4 + a4 * p4
        o5[c] = t5 + a4 * p5


@kernel
def _tangent_rate_col(om, co, x, out, dout):
    """``out[:, 0] = T(Omega) x[:, 0]`` and ``dout = T_dot x[:, 0]`` for the twist
    ``x[:, 0] = Omega_dot`` (the rate recursion of :func:`tdacm.lie.blocks.tangent_apply_into`:
    ``D_i = ad(Omega_dot) P_{i-1} + ad(Omega) D_{i-1}``,
    ``T_dot x = sum b_i (w . w_dot) P_i + a_i D_i``)."""
    k0, k1, k2, u0, u1, u2 = om[0], om[1], om[2], om[3], om[4], om[5]
    e0, e1, e2, e3, e4, e5 = x[0, 0], x[1, 0], x[2, 0], x[3, 0], x[4, 0], x[5, 0]
    wwd = om[0] * e0 + om[1] * e1 + om[2] * e2
    p0, p1, p2, p3, p4, p5 = e0, e1, e2, e3, e4, e5
    t0, t1, t2, t3, t4, t5 = p0, p1, p2, p3, p4, p5
    d0 = d1 = d2 = d3 = d4 = d5 = 0.0
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    for i in range(4):
        ai = co[i]
        bi = co[4 + i] * wwd
        c0, c1, c2, c3, c4, c5 = ad_scalars(k0, k1, k2, u0, u1, u2, p0, p1, p2, p3, p4, p5)
        f0, f1, f2, f3, f4, f5 = ad_scalars(e0, e1, e2, e3, e4, e5, p0, p1, p2, p3, p4, p5)
        g0, g1, g2, g3, g4, g5 = ad_scalars(k0, k1, k2, u0, u1, u2, d0, d1, d2, d3, d4, d5)
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
    out[0, 0], out[1, 0], out[2, 0], out[3, 0], out[4, 0], out[5, 0] = t0, t1, t2, t3, t4, t5
    dout[0], dout[1], dout[2], dout[3], dout[4], dout[5] = s0, s1, s2, s3, s4, s5


@kernel
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


@kernel
def _cols_adinv(r, p, x, ncols):
    """``Ad(g)^-1`` applied to the first ``ncols`` columns of ``x`` (6 x n, twists as columns;
    :func:`tdacm.lie.blocks.adinv_apply`); the loop over the columns vectorizes."""
    r00, r01, r02 = r[0, 0], r[0, 1], r[0, 2]
    r10, r11, r12 = r[1, 0], r[1, 1], r[1, 2]
    r20, r21, r22 = r[2, 0], r[2, 1], r[2, 2]
    p0, p1, p2 = p[0], p[1], p[2]
    x0, x1, x2, x3, x4, x5 = x[0], x[1], x[2], x[3], x[4], x[5]
    for c in range(ncols):
        a0, a1, a2 = x0[c], x1[c], x2[c]
        b0 = x3[c] - (p1 * a2 - p2 * a1)
        b1 = x4[c] - (p2 * a0 - p0 * a2)
        b2 = x5[c] - (p0 * a1 - p1 * a0)
        x0[c] = r00 * a0 + r10 * a1 + r20 * a2
        x1[c] = r01 * a0 + r11 * a1 + r21 * a2
        x2[c] = r02 * a0 + r12 * a1 + r22 * a2
        x3[c] = r00 * b0 + r10 * b1 + r20 * b2
        x4[c] = r01 * b0 + r11 * b1 + r21 * b2
        x5[c] = r02 * b0 + r12 * b1 + r22 * b2


@kernel
def _matvec_c(j, x, ncols, out):
    """``out = J x`` (6,) over the first ``ncols`` columns of ``J`` (the others are zero)."""
    for i in range(6):
        acc = 0.0
        for k in range(ncols):
            acc += j[i, k] * x[k]
        out[i] = acc


@kernel
def _tmatvec_add_c(j, f, weight, ncols, out):
    """``out += weight J^T f`` (:func:`tdacm.system.kernels._tmatvec_add`) over the first
    ``ncols`` columns of ``J``."""
    f0, f1, f2, f3, f4, f5 = f[0], f[1], f[2], f[3], f[4], f[5]
    j0, j1, j2, j3, j4, j5 = j[0], j[1], j[2], j[3], j[4], j[5]
    for k in range(ncols):
        out[k] += weight * (
            0.0 + j0[k] * f0 + j1[k] * f1 + j2[k] * f2 + j3[k] * f3 + j4[k] * f4 + j5[k] * f5
        )


@kernel
def _add_body_c(mass6, j, eta, jdq, weight, ncols, m_out, cqd_out, mj):
    """``M += w J^T Mb J`` (its upper triangle; :func:`_mirror` fills the lower one) and
    ``C qdot += w J^T (Mb J_dot qdot + coad(eta) Mb eta)`` (paper eqs. (10), (11)) over the
    first ``ncols`` columns of ``J`` (6 x n); ``mj`` is a (6, n) scratch array
    (:func:`tdacm.system.kernels._add_body`, ``want_c = False``)."""
    for r in range(6):
        mr = mass6[r]
        jr = j[r]
        mjr = mj[r]
        for a in range(ncols):
            mjr[a] = jr[a] * mr
    for a in range(ncols):
        x0, x1, x2, x3, x4, x5 = mj[0, a], mj[1, a], mj[2, a], mj[3, a], mj[4, a], mj[5, a]
        # views from column a: the loop from 0 vectorizes (no wrap-around test)
        row = m_out[a, a:ncols]
        j0, j1, j2, j3, j4, j5 = j[0, a:], j[1, a:], j[2, a:], j[3, a:], j[4, a:], j[5, a:]
        for b in range(ncols - a):
            acc = 0.0 + x0 * j0[b] + x1 * j1[b] + x2 * j2[b] + x3 * j3[b]
            acc = acc + x4 * j4[b] + x5 * j5[b]
            row[b] += weight * acc
    j0, j1, j2, j3, j4, j5 = j[0], j[1], j[2], j[3], j[4], j[5]
    f0, f1, f2, f3, f4, f5 = K.body_bias_wrench(mass6, eta, jdq)
    for a in range(ncols):
        cqd_out[a] += weight * (
            j0[a] * f0 + j1[a] * f1 + j2[a] * f2 + j3[a] * f3 + j4[a] * f4 + j5[a] * f5
        )


@kernel
def _mirror(m_out, n):
    """The lower triangle of ``M`` from its upper one (every entry ``(a, b)`` received the same
    sums as ``(b, a)`` would have: ``M`` is exactly symmetric)."""
    for a in range(n):
        for b in range(a + 1, n):
            m_out[b, a] = m_out[a, b]


@kernel
def _zanna_cols(z, c4, xi1, xi2, b0, b1, xc, ns):
    """The order-4 Magnus ``Z`` columns (:func:`tdacm.lie.magnus.magnus_step_into`, Zanna's
    scheme): ``xc[:, 1 + c] = h/2 (b0_c + b1_c) + c4 (ad(xi1) b1_c - ad(xi2) b0_c)`` for the
    basis columns ``c < ns`` at the two sample points, the first term ``z`` computed once
    (:func:`run_constants`).  A loop over the columns from index 0 over row views, without
    dependence between iterations: the compiler vectorizes it (each column's arithmetic
    unchanged)."""
    k0, k1, k2, u0, u1, u2 = xi1[0], xi1[1], xi1[2], xi1[3], xi1[4], xi1[5]
    l0, l1, l2, w0, w1, w2 = xi2[0], xi2[1], xi2[2], xi2[3], xi2[4], xi2[5]
    a0, a1, a2, a3, a4, a5 = b0[0, :ns], b0[1, :ns], b0[2, :ns], b0[3, :ns], b0[4, :ns], b0[5, :ns]
    e0, e1, e2, e3, e4, e5 = b1[0, :ns], b1[1, :ns], b1[2, :ns], b1[3, :ns], b1[4, :ns], b1[5, :ns]
    h0, h1, h2, h3, h4, h5 = z[0, :ns], z[1, :ns], z[2, :ns], z[3, :ns], z[4, :ns], z[5, :ns]
    o0, o1, o2 = xc[0, 1 : ns + 1], xc[1, 1 : ns + 1], xc[2, 1 : ns + 1]
    o3, o4, o5 = xc[3, 1 : ns + 1], xc[4, 1 : ns + 1], xc[5, 1 : ns + 1]
    for c in range(ns):
        p0, p1, p2, p3, p4, p5 = a0[c], a1[c], a2[c], a3[c], a4[c], a5[c]
        r0, r1, r2, r3, r4, r5 = e0[c], e1[c], e2[c], e3[c], e4[c], e5[c]
        t0, t1, t2, t3, t4, t5 = ad_scalars(k0, k1, k2, u0, u1, u2, r0, r1, r2, r3, r4, r5)
        s0, s1, s2, s3, s4, s5 = ad_scalars(l0, l1, l2, w0, w1, w2, p0, p1, p2, p3, p4, p5)
        o0[c] = h0[c] + c4 * (t0 - s0)
        o1[c] = h1[c] + c4 * (t1 - s1)
        o2[c] = h2[c] + c4 * (t2 - s2)
        o3[c] = h3[c] + c4 * (t3 - s3)
        o4[c] = h4[c] + c4 * (t4 - s4)
        o5[c] = h5[c] + c4 * (t5 - s5)


def run_constants(h, xi0s, bs):
    """What the forward recursion takes from the model only, computed once when the model is
    built (the same floating-point operations as the recursion performed per evaluation, so
    its results are unchanged): per Magnus step ``k`` of length ``h[k]`` with the basis blocks
    ``bs[k]`` and reference strains ``xi0s[k]`` at its one or two sample points,

    * ``step_z`` (n_steps, 6, w): ``h B`` (one sample) or ``h/2 (B_1 + B_2)`` (two: the first
      term of Zanna's ``Z``, :func:`tdacm.lie.magnus.magnus_step`);
    * ``step_c4`` (n_steps,): ``sqrt(3) h^2 / 12`` (two samples; 0 with one);
    * ``step_one`` (n_steps,) int: 1 when the step takes one sample: the order-2 steps, and the
      order-4 steps whose two samples are equal (a basis constant along the step, e.g. order 0:
      there ``ad(xi_1) xi_2``, ``ad(xi_1) B_2 - ad(xi_2) B_1`` and ``ad(v_1) v_2`` are exact
      zeros and ``h/2 (xi_1 + xi_2) = h xi_1`` exactly, so the order-2 step gives the same
      numbers);
    * ``step_nzc`` (n_steps, 6, w) int and ``step_nzn`` (n_steps, 6) int: the columns of every
      row of the basis blocks where a sample is non-zero, increasing.
    """
    h = np.asarray(h, float)
    ns, p, _, w = bs.shape
    if p == 2:
        z = 0.5 * h[:, None, None] * (bs[:, 0] + bs[:, 1])
        c4 = _C4 * h * h
        one = np.array(
            [np.array_equal(bs[k, 0], bs[k, 1]) and np.array_equal(xi0s[k, 0], xi0s[k, 1])
             for k in range(ns)],
            dtype=np.int64,
        )  # fmt: skip
    else:
        z = h[:, None, None] * bs[:, 0]
        c4 = np.zeros(ns)
        one = np.ones(ns, dtype=np.int64)
    nzc, nzn = nonzero_columns(bs)
    return np.ascontiguousarray(z), c4, one, nzc, nzn


def nonzero_columns(b):
    """``(cols, counts)`` of basis blocks ``b`` (..., 6, w) or (..., p, 6, w) (the samples'
    union): ``cols[..., r, :counts[..., r]]`` the increasing columns where row ``r`` is
    non-zero (the rest of ``cols`` zero)."""
    nz = b != 0.0
    if b.ndim == 4:
        nz = nz.any(axis=1)
    w = nz.shape[-1]
    counts = nz.sum(axis=-1).astype(np.int64)
    # the non-zero columns first, in increasing order (a stable sort of "is zero")
    order = np.argsort(~nz, axis=-1, kind="stable")
    cols = np.where(np.arange(w) < counts[..., None], order, 0).astype(np.int64)
    return np.ascontiguousarray(cols), counts


def nonzero_rows(b):
    """``(rows, counts)`` of basis blocks ``b`` (n, 6, w): ``rows[i, c, :counts[i, c]]`` the
    increasing rows where column ``c`` of block ``i`` is non-zero."""
    cols, counts = nonzero_columns(np.swapaxes(b, -1, -2))
    return cols, counts


@kernel
def rod_step_rate(h, xi0s, bs, z, c4, one, nzc, nzn, qs, qsd, off, g, j, ncols, eta, jdq, ws):
    """One Magnus step of the pose / Jacobian recursion (paper eqs. (7), (9)) with ``J``
    (6 x n), the twist ``eta = J qdot`` and ``J_dot qdot`` updated in place; the arithmetic of
    :func:`tdacm.system.kernels.rod_step` with ``full_rate = False``.  The step's strain
    coordinates are ``off .. off + len(qs)``; only the first ``ncols`` columns of ``J`` can be
    non-zero after it (the others are left untouched: zero).

    The step's run constants (:func:`run_constants`): ``z`` the part of ``Z`` that depends on
    the model only (``h B`` with one sample, ``h/2 (B_1 + B_2)`` with two), ``c4`` Zanna's
    ``sqrt(3) h^2 / 12``, ``one`` whether the step takes one sample, and the basis block's
    non-zero columns of each row (``nzc[r, :nzn[r]]``, increasing): the sums ``B q`` skip its
    exact zeros, whose products add exact zeros."""
    r, gr, xc, tx, xiv = ws
    omega = xiv[4]
    p = xiv[5, 0:3]
    tdx = xiv[3]  # rows 0-3 hold xi1, xi2, v1, v2 until Z is formed, then T_dot Omega_dot, w, v, e
    ns = qs.shape[0]
    # Magnus step (tdacm.lie.magnus.magnus_step_into): Omega, Z (columns 1..ns), Z_dot qdot
    if one:
        b = bs[0]
        for rr in range(6):
            acc = xi0s[0, rr]
            for t in range(nzn[rr]):
                c = nzc[rr, t]
                acc += b[rr, c] * qs[c]
            omega[rr] = acc * h
            for c in range(ns):
                xc[rr, 1 + c] = z[rr, c]
    else:
        b0 = bs[0]
        b1 = bs[1]
        xi1, xi2, v1, v2 = xiv[0], xiv[1], xiv[2], xiv[3]
        for rr in range(6):
            a1 = xi0s[0, rr]
            a2 = xi0s[1, rr]
            s1 = 0.0
            s2 = 0.0
            # four independent sums in one loop (each in the order of its own loop)
            for t in range(nzn[rr]):
                c = nzc[rr, t]
                a1 += b0[rr, c] * qs[c]
                a2 += b1[rr, c] * qs[c]
                s1 += b0[rr, c] * qsd[c]
                s2 += b1[rr, c] * qsd[c]
            xi1[rr], xi2[rr], v1[rr], v2[rr] = a1, a2, s1, s2
        a12 = ad_scalars(xi1[0], xi1[1], xi1[2], xi1[3], xi1[4], xi1[5],
                  xi2[0], xi2[1], xi2[2], xi2[3], xi2[4], xi2[5])  # fmt: skip
        v12 = ad_scalars(v1[0], v1[1], v1[2], v1[3], v1[4], v1[5],
                  v2[0], v2[1], v2[2], v2[3], v2[4], v2[5])  # fmt: skip
        for rr in range(6):
            omega[rr] = 0.5 * h * (xi1[rr] + xi2[rr]) + c4 * a12[rr]
            xc[rr, ns + 1] = 2.0 * c4 * v12[rr]
        _zanna_cols(z, c4, xi1, xi2, b0, b1, xc, ns)
    # Omega_dot = Z qdot: six independent sums over the columns, each in column order
    if one:  # Z = h B: the basis block's zeros (each row's sum skips exact zeros)
        for rr in range(6):
            acc = 0.0
            for t in range(nzn[rr]):
                c = nzc[rr, t]
                acc += z[rr, c] * qsd[c]
            xc[rr, 0] = acc
    else:
        z0, z1, z2 = xc[0, 1 : ns + 1], xc[1, 1 : ns + 1], xc[2, 1 : ns + 1]
        z3, z4, z5 = xc[3, 1 : ns + 1], xc[4, 1 : ns + 1], xc[5, 1 : ns + 1]
        d0 = d1 = d2 = d3 = d4 = d5 = 0.0
        for c in range(ns):
            qc = qsd[c]
            d0 += z0[c] * qc
            d1 += z1[c] * qc
            d2 += z2[c] * qc
            d3 += z3[c] * qc
            d4 += z4[c] * qc
            d5 += z5[c] * qc
        xc[0, 0], xc[1, 0], xc[2, 0], xc[3, 0], xc[4, 0], xc[5, 0] = d0, d1, d2, d3, d4, d5
    expmap_rp_into(omega, r, p)
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    co = tangent_coefficients_scalars(th)
    _tangent_rate_col(omega, co, xc, tx, tdx)
    _tangent_cols(omega, co, xc, 1, ns + 1 if one else ns + 2)  # T Z, T Z_dot qdot in xc
    # increments before the change of frame; T Omega_dot is the relative twist of the step
    w = xiv[0]
    v = xiv[1]
    e = xiv[2]
    for i in range(6):
        ji = j[i, off : off + ns]
        ti = xc[i, 1 : ns + 1]
        for c in range(ns):
            ji[c] += ti[c]
    for i in range(6):
        w[i] = tx[i, 0]
        v[i] = jdq[i] + tdx[i] + (0.0 if one else xc[i, ns + 1])
        e[i] = eta[i] + tx[i, 0]
    _cols_adinv(r, p, j, ncols)
    _adinv_row(r, p, w)
    _adinv_row(r, p, v)
    _adinv_row(r, p, e)
    t = ad_scalars(w[0], w[1], w[2], w[3], w[4], w[5], e[0], e[1], e[2], e[3], e[4], e[5])
    for i in range(6):
        eta[i] = e[i]
        jdq[i] = v[i] - t[i]
    compose_rp_into(g, gr, r, p)  # g <- g exp(Omega)


@kernel
def _add_point_force_c(j, g, fx, fy, fz, ncols, tau, f):
    """``tau += J^T [0; R^T f]`` (:func:`tdacm.system.kernels._add_point_force`); ``f`` (6,)
    scratch."""
    for i in range(3):
        f[i] = 0.0
        f[3 + i] = g[0, i] * fx + g[1, i] * fy + g[2, i] * fz
    _tmatvec_add_c(j, f, 1.0, ncols, tau)


@njit(cache=True)
def workspace(n, m):
    """Every scratch array of one evaluation of :func:`forward_terms_ws` and
    :func:`forward_dynamics_ws` for a system of ``n`` coordinates with model arrays ``m``: row
    blocks of eight arrays (row slices are views without a reshape, which numba does through a
    library call; one workspace costs about a tenth of the nineteen reshaped views of one
    buffer)."""
    ns = m.bs.shape[3]
    nst = max(n - (6 if m.floating else 0), 1)
    na = m.tendon_d.shape[1]
    nn = np.empty((2, n, n))  # M, its Cholesky factor
    rows = np.empty(
        (42, n)
    )  # C qdot, tau, B u, rhs, y, scratch; J_b, J_dot_b, Mb J, J, J_dot, J_prev
    s6 = np.empty((19, 6))  # f, eta_b, J_dot_b qdot, eta, J_dot qdot, prev, fa, ...; xi1, xi2, ...
    g4 = np.empty((12, 4))  # g_b, g, g_prev
    rot = np.empty((4, 8))  # the rotors' states (tdacm.aero.layout.ROTOR_STATE)
    m33 = np.empty((6, 3, 3))  # R and R copy of the step, R_a, R_b, T, T_dot
    xt = np.empty((12, ns + 2))  # the step's twists [Omega_dot | Z | Z_dot qdot], T Omega_dot
    bs_t = np.empty((nst, na))  # B_s(q)
    return (
        nn[0], rows[0:6], g4[0:4], rows[6:12], rows[12:18], s6[0:12], rot, xt[0:6], xt[6:12],
        m33, s6[12:19], rows[18:24], g4[4:8], rows[24:30], rows[30:36], g4[8:12], rows[36:42],
        bs_t, nn[1],
    )  # fmt: skip


@kernel
def _base_into(q, qd, floating, g_fixed, gb, jb, jbd, m33):
    """:func:`tdacm.system.kernels.base_state` written into ``gb``, ``jb`` and ``jbd`` (the same
    arithmetic); keeps ``R`` and ``T`` in ``m33[3]``, ``m33[4]``."""
    n = q.shape[0]
    for i in range(6):
        for c in range(n):
            jb[i, c] = 0.0
            jbd[i, c] = 0.0
    if not floating:
        _copy_into(gb, g_fixed)
        return
    # the drone's R, T and dT/dt (tdacm.lie.euler), the six sines and cosines computed once,
    # into m33[3], m33[4], m33[5]
    r = m33[3]
    t = m33[4]
    td = m33[5]
    phi, theta, psi, phi_dot, theta_dot = q[0], q[1], q[2], qd[0], qd[1]
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    rot_zyx_into(r, cf, sf, ct, st, np.cos(psi), np.sin(psi))
    euler_rates_into(t, td, cf, sf, ct, st, phi_dot, theta_dot)
    for i in range(4):
        for k in range(4):
            gb[i, k] = 1.0 if i == k else 0.0
    for i in range(3):
        for k in range(3):
            gb[i, k] = r[i, k]
        gb[i, 3] = q[3 + i]
    w0 = w1 = w2 = 0.0
    for k in range(3):
        w0 += t[0, k] * qd[k]
        w1 += t[1, k] * qd[k]
        w2 += t[2, k] * qd[k]
    for i in range(3):
        for k in range(3):
            jb[i, k] = t[i, k]
            jbd[i, k] = td[i, k]
            jb[3 + i, 3 + k] = r[k, i]
    w = (w0, w1, w2)
    for i in range(3):
        for k in range(3):
            acc = 0.0
            for p in range(3):
                acc -= K.skew_entry(w, i, p) * r[k, p]
            jbd[3 + i, 3 + k] = acc


@njit(cache=True)
def forward_terms(q, qd, m, loads, u, aero, contact):
    """``M``, ``C qdot``, ``tau_ext`` (paper eqs. (10), (11), (16)), the last rod's tip pose,
    its ``J`` (6 x n) and its base's ``J_dot`` (6 x n): the outputs of
    :func:`tdacm.system.kernels.coupled_terms_env` with ``want_c = False``, computed with the
    same arithmetic (module docstring); fresh arrays."""
    ws = workspace(q.shape[0], m)
    forward_terms_ws(q, qd, m, loads, u, aero, contact, ws)
    m_out, vn, g, j, jd = ws[0], ws[1], ws[12], ws[13], ws[14]
    return m_out.copy(), vn[0].copy(), vn[1].copy(), g.copy(), j.copy(), jd.copy()


@kernel
def forward_terms_ws(q, qd, m, loads, u, aero, contact, ws):
    """:func:`forward_terms` into the :func:`workspace` ``ws``: ``M`` in ``ws[0]``, ``C qdot``
    and ``tau_ext`` in ``ws[1][0]``, ``ws[1][1]``, the tip pose, ``J`` and the rod base's
    ``J_dot`` (6 x n) in ``ws[12]``, ``ws[13]``, ``ws[14]``."""
    m_out, vn, gb, jb, jbd, v6, rot, xc, tx, m33, xiv, mj, g, j, jd, g_prev, j_prev = ws[:17]
    floating = m.floating
    n = q.shape[0]
    off = 6 if floating else 0
    cqd = vn[0]
    tau = vn[1]
    for i in range(n):
        cqd[i] = 0.0
        tau[i] = 0.0
        for k in range(n):
            m_out[i, k] = 0.0
    grav = loads[0:3]
    _base_into(q, qd, floating, m.g_fixed, gb, jb, jbd, m33)
    nb = off  # the base's Jacobian has non-zero columns only for the drone's coordinates
    f, eb, ebd, eta, jdq, prev, fa = v6[0], v6[1], v6[2], v6[3], v6[4], v6[5], v6[6]
    fb, mb = v6[7, 0:3], v6[7, 3:6]
    air = aero.shape[0] > 0
    drone_air = air and floating and aero[AL.DRONE_ON] > 0.0
    rod_air = air and aero[AL.ROD_ON] > 0.0
    wake = rod_air and aero[AL.WAKE_ON] > 0.0
    ax = ay = az = 0.0
    if wake:
        ax, ay, az = K._rotor_setup(q, qd, u, m, gb, aero, rot)
    nst = m.h.shape[0]
    if floating:
        _matvec_c(jb, qd, n, eb)
        _matvec_c(jbd, qd, n, ebd)
        _add_body_c(m.mb6, jb, eb, ebd, 1.0, nb, m_out, cqd, mj)
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
        _tmatvec_add_c(jb, f, 1.0, nb, tau)
    cont = contact.shape[0] > 0
    for i in range(3):
        mb[i] = 0.0
    probe = cont and K._has_probe(contact)
    ra = m33[2]
    rws = (m33[0], m33[1], xc, tx, xiv)
    pa = xiv[6, 0:3]
    for rod in range(m.rod_steps.shape[0] - 1):
        # rod base: J_a = Ad(g_a^b)^-1 J_b^b (kernels.rod_start)
        ga = m.g_att[rod]
        for i in range(3):
            pa[i] = ga[i, 3]
            for k in range(3):
                ra[i, k] = ga[i, k]
        for i in range(6):
            for c in range(n):
                j[i, c] = jb[i, c]
                jd[i, c] = jbd[i, c]
        _cols_adinv(ra, pa, j, n)
        _cols_adinv(ra, pa, jd, n)
        for i in range(4):  # g = g_b g_a^b (kernels._matmul)
            for c in range(4):
                g[i, c] = 0.0
            for k in range(4):
                aik = gb[i, k]
                for c in range(4):
                    g[i, c] += aik * ga[k, c]
        _matvec_c(jd, qd, n, jdq)
        _matvec_c(j, qd, n, eta)
        nact = nb
        if cont:
            K._rod_base_node(g, eta, prev)
            _copy_into(g_prev, g)
            _copy_into(j_prev, j)
        for k in range(m.rod_steps[rod], m.rod_steps[rod + 1]):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            if c1 > nact:
                nact = c1
            rod_step_rate(
                m.h[k], m.xi0s[k], m.bs[k], m.step_z[k], m.step_c4[k], m.step_one[k] != 0,
                m.step_nzc[k], m.step_nzn[k], q[c0:c1], qd[c0:c1], c0, g, j, nact, eta, jdq, rws,
            )  # fmt: skip
            w = m.step_w[k]
            if w == 0.0:
                continue
            mass6 = m.step_mass[k]
            if K.has_inertia(mass6):
                _add_body_c(mass6, j, eta, jdq, w, nact, m_out, cqd, mj)
            lo = m.step_load[k]
            K.step_wrench(
                f, g, eta, k, lo, mass6, grav, loads, rod_air, aero, nst, rot, ax, ay, az, wake
            )
            _tmatvec_add_c(j, f, w, nact, tau)
            if cont and lo != K.LOAD_GRAVITY:
                hit_a, hit_b = K._node_contact(contact, k, g, eta, prev, fa, fb)
                mb[0] = mb[1] = mb[2] = 0.0
                if lo == K.LOAD_TIP and K._tip_contact(contact, g, eta, fb, mb):
                    hit_b = True
                if hit_a:
                    _add_point_force_c(j_prev, g_prev, fa[0], fa[1], fa[2], n, tau, f)
                if hit_b:
                    _add_point_force_c(j, g, fb[0], fb[1], fb[2], nact, tau, f)
                    if probe and lo == K.LOAD_TIP:
                        for i in range(3):
                            f[i] = mb[i]
                            f[3 + i] = 0.0
                        _tmatvec_add_c(j, f, 1.0, nact, tau)
                _copy_into(g_prev, g)
                _copy_into(j_prev, j)
    _mirror(m_out, n)


@kernel
def _input_force(q, u, m, ws, out):
    """``out = B(q) u`` (paper eqs. (14)-(16); :func:`tdacm.system.kernels.input_matrix`
    times ``u`` with the same arithmetic, the zero blocks of ``B`` skipped); uses ``R`` and
    ``T`` kept by :func:`_base_into`."""
    n = q.shape[0]
    bs_t, m33 = ws[17], ws[9]
    na = m.tendon_d.shape[1]
    off = 6 if m.floating else 0
    ut = 4 if m.floating else 0  # first tension in u
    # B_s(q) (n_s x n_a): kernels.tendon_lengths_and_matrix without the lengths
    for c in range(n - off):
        for i in range(na):
            bs_t[c, i] = 0.0
    K.tendon_accumulate(q[off:], m, ws[10][0], ws[10][1], bs_t, ws[10][0], bool(0))
    if m.floating:
        r = m33[3]
        t = m33[4]
        g = m.gamma
        for i in range(3):
            acc_a = 0.0
            acc_b = 0.0
            for c in range(4):
                a0 = 0.0
                a1 = 0.0
                for k in range(3):
                    a0 += t[k, i] * g[k, c]
                    a1 += r[i, k] * g[3 + k, c]
                acc_a += a0 * u[c]
                acc_b += a1 * u[c]
            out[i] = acc_a
            out[3 + i] = acc_b
    for c in range(n - off):
        acc = 0.0
        for i in range(na):
            acc += bs_t[c, i] * u[ut + i]
        out[off + c] = acc


@kernel
def forward_dynamics_ws(q, qd, u, m, loads, aero, contact, ws, qdd):
    """``qdd = M^-1 (B u + tau_ext - C qdot - D qdot - K)`` (paper eq. (9)) into ``qdd``,
    with the :func:`workspace` ``ws``; returns ``ok`` (False when ``M`` is not positive
    definite).  The arithmetic of :func:`tdacm.system.kernels.forward_dynamics_env`."""
    n = q.shape[0]
    forward_terms_ws(q, qd, m, loads, u, aero, contact, ws)
    mm, vn, lo = ws[0], ws[1], ws[18]
    cqd, tau, bu, rhs, y = vn[0], vn[1], vn[2], vn[3], vn[4]
    _input_force(q, u, m, ws, bu)
    dmp = m.damping
    stf = m.stiffness
    for i in range(n):  # over the columns where row i of D and K can be non-zero
        k0, k1 = m.kd_lo[i], m.kd_hi[i]
        a = 0.0
        for k in range(k0, k1):
            a += dmp[i, k] * qd[k]
        b = 0.0
        for k in range(k0, k1):
            b += stf[i, k] * q[k]
        rhs[i] = bu[i] + tau[i] - cqd[i] - a - b
    if not cholesky_into(mm, n, lo):
        for c in range(n):
            qdd[c] = 0.0
        return False
    cholesky_substitute(lo, n, rhs, y, qdd)
    return True


@njit(cache=True)
def rk4_steps(q0, qd0, u, dt, nsteps, every, m, loads, aero, contact):
    """:func:`tdacm.system.kernels.rk4_run_env` (classical RK4 at constant input, every
    ``every``-th state kept) with one :func:`workspace` for all its evaluations; the same
    arithmetic."""
    n = q0.shape[0]
    nrec = nsteps // every + 1
    qs = np.empty((nrec, n))
    qds = np.empty((nrec, n))
    ws = workspace(n, m)
    st = np.empty((8, n))
    a1, a2, a3, a4, qs_, qds_, q, qd = st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7]
    h2 = 0.5 * dt
    d6 = dt * dt / 6.0
    t6 = dt / 6.0
    for i in range(n):
        q[i] = q0[i]
        qd[i] = qd0[i]
    qs[0] = q
    qds[0] = qd
    rec = 1
    for k in range(nsteps):
        ok1 = forward_dynamics_ws(q, qd, u, m, loads, aero, contact, ws, a1)
        for i in range(n):
            qs_[i] = q[i] + h2 * qd[i]
            qds_[i] = qd[i] + h2 * a1[i]
        ok2 = forward_dynamics_ws(qs_, qds_, u, m, loads, aero, contact, ws, a2)
        for i in range(n):
            qs_[i] = q[i] + h2 * (qd[i] + h2 * a1[i])
            qds_[i] = qd[i] + h2 * a2[i]
        ok3 = forward_dynamics_ws(qs_, qds_, u, m, loads, aero, contact, ws, a3)
        for i in range(n):
            qs_[i] = q[i] + dt * (qd[i] + h2 * a2[i])
            qds_[i] = qd[i] + dt * a3[i]
        ok4 = forward_dynamics_ws(qs_, qds_, u, m, loads, aero, contact, ws, a4)
        if not (ok1 and ok2 and ok3 and ok4):
            return qs[:rec], qds[:rec], False
        for i in range(n):
            q[i] = q[i] + dt * qd[i] + d6 * (a1[i] + a2[i] + a3[i])
            qd[i] = qd[i] + t6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])
        if (k + 1) % every == 0:
            qs[rec] = q
            qds[rec] = qd
            rec += 1
    return qs[:rec], qds[:rec], True
