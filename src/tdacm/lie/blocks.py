"""Structured products of the SE(3) operators with blocks of twists (6 x c), as numba loops.

These are the hot path of the rod recursion.  numba sends every ``@`` to BLAS, whose call
overhead dominates for 3x3 and 6x6 operands; exploiting the block structure of ``ad``, ``Ad^-1``
and ``S`` with plain loops is about ten times faster.  Each function has a dense reference in
:mod:`tdacm.lie.se3`, and the tests compare them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .se3 import _exp_coefficients, tangent_coefficients


@njit(cache=True, inline="always")
def _cross_into(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def ad_apply(xi, x, out):
    """``out = ad(xi) @ x``: each column ``[a; b]`` -> ``[k x a; u x a + k x b]``."""
    k0, k1, k2, u0, u1, u2 = xi[0], xi[1], xi[2], xi[3], xi[4], xi[5]
    for c in range(x.shape[1]):
        a0, a1, a2 = x[0, c], x[1, c], x[2, c]
        b0, b1, b2 = x[3, c], x[4, c], x[5, c]
        out[0, c] = k1 * a2 - k2 * a1
        out[1, c] = k2 * a0 - k0 * a2
        out[2, c] = k0 * a1 - k1 * a0
        out[3, c] = u1 * a2 - u2 * a1 + k1 * b2 - k2 * b1
        out[4, c] = u2 * a0 - u0 * a2 + k2 * b0 - k0 * b2
        out[5, c] = u0 * a1 - u1 * a0 + k0 * b1 - k1 * b0


@njit(cache=True)
def ad_vec(xi, v):
    """``ad(xi) @ v`` for one twist ``v``."""
    out = np.empty(6)
    k0, k1, k2, u0, u1, u2 = xi[0], xi[1], xi[2], xi[3], xi[4], xi[5]
    a0, a1, a2, b0, b1, b2 = v[0], v[1], v[2], v[3], v[4], v[5]
    out[0] = k1 * a2 - k2 * a1
    out[1] = k2 * a0 - k0 * a2
    out[2] = k0 * a1 - k1 * a0
    out[3] = u1 * a2 - u2 * a1 + k1 * b2 - k2 * b1
    out[4] = u2 * a0 - u0 * a2 + k2 * b0 - k0 * b2
    out[5] = u0 * a1 - u1 * a0 + k0 * b1 - k1 * b0
    return out


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def expmap_rp(xi):
    """``exp(xi^)`` as rotation ``R`` (3x3) and translation ``p`` (3,) (Rodrigues form)."""
    k0, k1, k2 = xi[0], xi[1], xi[2]
    th = np.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    c1, c2 = _exp_coefficients(th)
    # sin(th)/th = 1 - th^2 c2
    s1 = 1.0 - th * th * c2
    kk = np.empty((3, 3))
    kk[0, 0] = -(k1 * k1 + k2 * k2)
    kk[1, 1] = -(k0 * k0 + k2 * k2)
    kk[2, 2] = -(k0 * k0 + k1 * k1)
    kk[0, 1] = kk[1, 0] = k0 * k1
    kk[0, 2] = kk[2, 0] = k0 * k2
    kk[1, 2] = kk[2, 1] = k1 * k2
    r = np.empty((3, 3))
    v = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            r[i, j] = c1 * kk[i, j]
            v[i, j] = c2 * kk[i, j]
        r[i, i] += 1.0
        v[i, i] += 1.0
    r[0, 1] -= s1 * k2
    r[1, 0] += s1 * k2
    r[0, 2] += s1 * k1
    r[2, 0] -= s1 * k1
    r[1, 2] -= s1 * k0
    r[2, 1] += s1 * k0
    v[0, 1] -= c1 * k2
    v[1, 0] += c1 * k2
    v[0, 2] += c1 * k1
    v[2, 0] -= c1 * k1
    v[1, 2] -= c1 * k0
    v[2, 1] += c1 * k0
    p = np.empty(3)
    for i in range(3):
        p[i] = v[i, 0] * xi[3] + v[i, 1] * xi[4] + v[i, 2] * xi[5]
    return r, p


@njit(cache=True)
def tangent_apply(omega, omega_dot, z, want_rate):
    """``T(Omega) Z`` and (if ``want_rate``) ``T_dot Z`` without forming 6x6 matrices.

    With ``P_i = ad(Omega)^i Z`` and ``D_i = d(ad(Omega)^i)/dt Z`` built by the recursion
    ``D_i = ad(Omega_dot) P_{i-1} + ad(Omega) D_{i-1}``:
    ``T Z = Z + sum a_i P_i`` and ``T_dot Z = sum (b_i (w . w_dot)) P_i + a_i D_i``.
    """
    c = z.shape[1]
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    a, b = tangent_coefficients(th)
    tz = z.copy()
    tdz = np.zeros((6, c))
    prev = z.copy()
    cur = np.empty((6, c))
    dprev = np.zeros((6, c))
    dcur = np.empty((6, c))
    tmp = np.empty((6, c))
    wwd = omega[0] * omega_dot[0] + omega[1] * omega_dot[1] + omega[2] * omega_dot[2]
    for i in range(4):
        ad_apply(omega, prev, cur)
        if want_rate:
            ad_apply(omega_dot, prev, dcur)
            ad_apply(omega, dprev, tmp)
            dcur += tmp
        ai = a[i]
        bi = b[i] * wwd
        for r in range(6):
            for k in range(c):
                tz[r, k] += ai * cur[r, k]
                if want_rate:
                    tdz[r, k] += bi * cur[r, k] + ai * dcur[r, k]
        prev, cur = cur, prev
        if want_rate:
            dprev, dcur = dcur, dprev
    return tz, tdz
