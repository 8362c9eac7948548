"""Structured products of the SE(3) operators with blocks of twists (6 x c), as numba loops.

These are the hot path of the rod recursion.  numba sends every ``@`` to BLAS, whose call
overhead dominates for 3x3 and 6x6 operands; exploiting the block structure of ``ad``, ``Ad^-1``
and ``S`` with plain loops is about ten times faster.  Each function has a dense reference in
:mod:`tdacm.lie.se3`, and the tests compare them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import kernel
from .se3 import _exp_coefficients, tangent_coefficients_scalars


@njit(cache=True, inline="always")
def _cross_into(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, inline="always")
def ad_scalars(k0, k1, k2, u0, u1, u2, a0, a1, a2, b0, b1, b2):
    """``ad(xi) x`` for ``xi = [k; u]`` and ``x = [a; b]`` given as scalars:
    ``[k x a; u x a + k x b]`` (a 6-tuple)."""
    return (
        k1 * a2 - k2 * a1,
        k2 * a0 - k0 * a2,
        k0 * a1 - k1 * a0,
        u1 * a2 - u2 * a1 + k1 * b2 - k2 * b1,
        u2 * a0 - u0 * a2 + k2 * b0 - k0 * b2,
        u0 * a1 - u1 * a0 + k0 * b1 - k1 * b0,
    )


@kernel
def ad_apply(xi, x, out):
    """``out = ad(xi) @ x``: each column ``[a; b]`` -> ``[k x a; u x a + k x b]``."""
    k0, k1, k2, u0, u1, u2 = xi[0], xi[1], xi[2], xi[3], xi[4], xi[5]
    for c in range(x.shape[1]):
        out[0, c], out[1, c], out[2, c], out[3, c], out[4, c], out[5, c] = ad_scalars(
            k0, k1, k2, u0, u1, u2, x[0, c], x[1, c], x[2, c], x[3, c], x[4, c], x[5, c]
        )


@njit(cache=True)
def ad_vec(xi, v):
    """``ad(xi) @ v`` for one twist ``v``."""
    out = np.empty(6)
    out[0], out[1], out[2], out[3], out[4], out[5] = ad_scalars(
        xi[0], xi[1], xi[2], xi[3], xi[4], xi[5], v[0], v[1], v[2], v[3], v[4], v[5]
    )
    return out


@kernel
def adinv_apply(r, p, x):
    """``Ad(g)^-1 @ x`` in place for ``g = (r, p)``: ``[a; b] -> [R^T a; R^T (b - p x a)]``."""
    for c in range(x.shape[1]):
        a0, a1, a2 = x[0, c], x[1, c], x[2, c]
        b0 = x[3, c] - (p[1] * a2 - p[2] * a1)
        b1 = x[4, c] - (p[2] * a0 - p[0] * a2)
        b2 = x[5, c] - (p[0] * a1 - p[1] * a0)
        for i in range(3):
            x[i, c] = r[0, i] * a0 + r[1, i] * a1 + r[2, i] * a2
            x[3 + i, c] = r[0, i] * b0 + r[1, i] * b1 + r[2, i] * b2


@kernel
def skew_apply_sub(mu, x, out):
    """``out -= S(mu) @ x`` with ``S(mu) = [[m~, f~], [f~, 0]]``."""
    m0, m1, m2, f0, f1, f2 = mu[0], mu[1], mu[2], mu[3], mu[4], mu[5]
    for c in range(x.shape[1]):
        a0, a1, a2 = x[0, c], x[1, c], x[2, c]
        b0, b1, b2 = x[3, c], x[4, c], x[5, c]
        out[0, c] -= m1 * a2 - m2 * a1 + f1 * b2 - f2 * b1
        out[1, c] -= m2 * a0 - m0 * a2 + f2 * b0 - f0 * b2
        out[2, c] -= m0 * a1 - m1 * a0 + f0 * b1 - f1 * b0
        out[3, c] -= f1 * a2 - f2 * a1
        out[4, c] -= f2 * a0 - f0 * a2
        out[5, c] -= f0 * a1 - f1 * a0


@kernel
def compose_rp_into(g, gr, r, p):
    """``g <- g [r p; 0 1]`` in place for a 4x4 (or 3x4) pose ``g``; ``gr`` is 3x3 scratch."""
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


@kernel
def expmap_rp_into(xi, r, p):
    """``exp(xi^)`` written into rotation ``r`` (3x3) and translation ``p`` (3,) (Rodrigues)."""
    k0, k1, k2 = xi[0], xi[1], xi[2]
    th = np.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    c1, c2 = _exp_coefficients(th)
    s1 = 1.0 - th * th * c2  # sin(th)/th
    # K^2 = k k^T - th^2 I
    q00 = -(k1 * k1 + k2 * k2)
    q11 = -(k0 * k0 + k2 * k2)
    q22 = -(k0 * k0 + k1 * k1)
    q01 = k0 * k1
    q02 = k0 * k2
    q12 = k1 * k2
    r[0, 0] = 1.0 + c1 * q00
    r[1, 1] = 1.0 + c1 * q11
    r[2, 2] = 1.0 + c1 * q22
    r[0, 1] = c1 * q01 - s1 * k2
    r[1, 0] = c1 * q01 + s1 * k2
    r[0, 2] = c1 * q02 + s1 * k1
    r[2, 0] = c1 * q02 - s1 * k1
    r[1, 2] = c1 * q12 - s1 * k0
    r[2, 1] = c1 * q12 + s1 * k0
    # p = (I + c1 K + c2 K^2) u
    u0, u1, u2 = xi[3], xi[4], xi[5]
    p[0] = (1.0 + c2 * q00) * u0 + (c2 * q01 - c1 * k2) * u1 + (c2 * q02 + c1 * k1) * u2
    p[1] = (c2 * q01 + c1 * k2) * u0 + (1.0 + c2 * q11) * u1 + (c2 * q12 - c1 * k0) * u2
    p[2] = (c2 * q02 - c1 * k1) * u0 + (c2 * q12 + c1 * k0) * u1 + (1.0 + c2 * q22) * u2


@njit(cache=True)
def expmap_rp(xi):
    """``exp(xi^)`` as rotation ``R`` (3x3) and translation ``p`` (3,) (Rodrigues form)."""
    r = np.empty((3, 3))
    p = np.empty(3)
    expmap_rp_into(xi, r, p)
    return r, p


@kernel
def tangent_apply_into(omega, omega_dot, x, n_rate, tx, tdx, work):
    """``tx = T(Omega) X`` for all columns and ``tdx = T_dot X`` for the first ``n_rate`` columns.

    With ``P_i = ad(Omega)^i X`` and ``D_i = d(ad(Omega)^i)/dt X`` built by the recursion
    ``D_i = ad(Omega_dot) P_{i-1} + ad(Omega) D_{i-1}``:
    ``T X = X + sum a_i P_i`` and ``T_dot X = sum (b_i (w . w_dot)) P_i + a_i D_i``.
    ``work`` is a (5, 6, c) scratch array.
    """
    c = x.shape[1]
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    co = tangent_coefficients_scalars(th)
    prev = work[0]
    cur = work[1]
    dprev = work[2]
    dcur = work[3]
    tmp = work[4]
    for r in range(6):
        for k in range(c):
            tx[r, k] = x[r, k]
            prev[r, k] = x[r, k]
        for k in range(n_rate):
            tdx[r, k] = 0.0
            dprev[r, k] = 0.0
    wwd = omega[0] * omega_dot[0] + omega[1] * omega_dot[1] + omega[2] * omega_dot[2]
    for i in range(4):
        ad_apply(omega, prev, cur)
        if n_rate > 0:
            ad_apply(omega_dot, prev[:, :n_rate], dcur[:, :n_rate])
            ad_apply(omega, dprev[:, :n_rate], tmp[:, :n_rate])
        ai = co[i]
        bi = co[4 + i] * wwd
        for r in range(6):
            for k in range(c):
                tx[r, k] += ai * cur[r, k]
            for k in range(n_rate):
                dcur[r, k] += tmp[r, k]
                tdx[r, k] += bi * cur[r, k] + ai * dcur[r, k]
        prev, cur = cur, prev
        dprev, dcur = dcur, dprev


@njit(cache=True)
def tangent_apply(omega, omega_dot, z, want_rate):
    """Allocating form of :func:`tangent_apply_into`: ``T Z`` and (if ``want_rate``) ``T_dot Z``."""
    c = z.shape[1]
    tz = np.empty((6, c))
    tdz = np.zeros((6, c))
    work = np.empty((5, 6, c))
    tangent_apply_into(omega, omega_dot, z, c if want_rate else 0, tz, tdz, work)
    return tz, tdz
