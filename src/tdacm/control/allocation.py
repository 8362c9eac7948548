"""Allocation of the generalized forces ``tau_a`` to the real inputs.

* Motors: the body wrench ``[tau_x, tau_y, tau_z, f_z]`` -> four thrusts through the rows
  ``[0, 1, 2, 5]`` of the paper's ``Gamma`` (invertible for a ``+`` quadrotor), clipped to
  ``[0, max_thrust]`` (:func:`allocate_thrusts`).
* Tendons: ``B_s(q) T = tau_s`` with ``0 <= T <= T_max`` (tendons only pull). With two
  antagonistic pairs the common mode of each pair is free; it is set to the pretension
  ``T_pre`` when possible. Solved as a bounded least-squares problem on
  ``[B_s; w I] T = [tau_s; w T_pre]`` with a small ``w`` (a strictly convex box-constrained QP,
  solved exactly by a primal active-set method in numba, :func:`box_least_squares`; any
  number of tendons); the result never has a negative tension, and :class:`TendonAllocation`
  reports whether a bound was active and the generalized force could not be produced exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .._linalg import cholesky_substitute
from .._linalg import solve as _solve
from .config import LAW_DEFAULTS


@njit(cache=True)
def _solve_free(h, c, x, w, out):
    """``out[free] = H_ff^-1 (c_f - H_fa x_a)`` by Cholesky (``H`` symmetric positive definite);
    written out by hand: tiny systems, and a fraction of the compile time of LAPACK's."""
    n = h.shape[0]
    idx = np.empty(n, np.int64)
    nf = 0
    for i in range(n):
        if w[i] == 0:
            idx[nf] = i
            nf += 1
    a = np.zeros((nf, nf))
    r = np.zeros(nf)
    for p in range(nf):
        i = idx[p]
        r[p] = c[i]
        for j in range(n):
            if w[j] != 0:
                r[p] -= h[i, j] * x[j]
        for s in range(nf):
            a[p, s] = h[i, idx[s]]
    for p in range(nf):  # Cholesky a = L L^T in place (lower triangle)
        d = a[p, p]
        for s in range(p):
            d -= a[p, s] * a[p, s]
        d = np.sqrt(max(d, 1e-300))
        a[p, p] = d
        for t in range(p + 1, nf):
            v = a[t, p]
            for s in range(p):
                v -= a[t, s] * a[p, s]
            a[t, p] = v / d
    cholesky_substitute(a, nf, r, r, r)
    out[:] = x
    for p in range(nf):
        out[idx[p]] = r[p]


@njit(cache=True)
def box_least_squares(a, b, lo, hi, max_iter=100):
    """``argmin |a x - b|^2`` subject to ``lo <= x <= hi``, for ``a`` of full column rank
    (a strictly convex QP with Hessian ``H = a^T a``): the primal active-set method (Nocedal and
    Wright, Algorithm 16.3) with bound constraints, from the feasible start ``clip(0)``. Exact
    in a finite number of steps (each step adds a blocking bound or drops the bound with the
    most negative multiplier)."""
    n = a.shape[1]
    h = a.T @ a
    c = a.T @ b
    x = np.empty(n)
    w = np.zeros(n, np.int64)  # 0 free, -1 at lo, +1 at hi
    for i in range(n):
        x[i] = min(max(0.0, lo), hi)
        if x[i] <= lo:
            w[i] = -1
        elif x[i] >= hi:
            w[i] = 1
    xn = np.empty(n)
    for _ in range(max_iter):
        _solve_free(h, c, x, w, xn)
        d = xn - x
        step = 0.0
        scale = 1.0
        for i in range(n):
            step = max(step, abs(d[i]))
            scale = max(scale, 1.0 + abs(x[i]))
        if step <= 1e-14 * scale:
            g = h @ x - c  # multipliers of the active bounds: g_i >= 0 at lo, <= 0 at hi
            worst, k = 0.0, -1
            for i in range(n):
                m = g[i] if w[i] == -1 else (-g[i] if w[i] == 1 else 0.0)
                if m < worst:
                    worst, k = m, i
            if k < 0:
                return x
            w[k] = 0
            continue
        alpha, block = 1.0, -1
        for i in range(n):
            if w[i] != 0:
                continue
            if d[i] < 0.0 and x[i] + d[i] < lo:
                r = (lo - x[i]) / d[i]
                if r < alpha:
                    alpha, block = r, i
            elif d[i] > 0.0 and x[i] + d[i] > hi:
                r = (hi - x[i]) / d[i]
                if r < alpha:
                    alpha, block = r, i
        for i in range(n):
            x[i] += alpha * d[i]
        if block >= 0:
            w[block] = -1 if d[block] < 0.0 else 1
            x[block] = lo if d[block] < 0.0 else hi
    return x


@dataclass(frozen=True)
class TendonAllocation:
    tensions: np.ndarray
    residual: float  # |B_s T - tau_s|
    saturated: bool  # a bound (0 or T_max) was active and the demand was not met
    at_max: bool
    at_zero: bool


def allocate_tensions(
    b_s,
    tau_s,
    max_tension: float,
    pretension: float = LAW_DEFAULTS.pretension,
    weight: float = 1e-3,
    tol: float = 1e-6,
) -> TendonAllocation:
    """Tendon tensions ``0 <= T <= max_tension`` with ``B_s T ~= tau_s`` (see module doc).

    ``weight`` (relative to the column norm of ``B_s``) trades the pretension target against
    exactness; with the paper's antagonistic pairs it only acts on the free common mode.
    """
    b = np.asarray(b_s, dtype=float)
    tau = np.asarray(tau_s, dtype=float)
    if b.ndim != 2 or tau.shape != (b.shape[0],):
        raise ValueError(f"B_s must be (n_s, n_a) and tau_s (n_s,), got {b.shape}, {tau.shape}")
    if max_tension <= 0 or pretension < 0 or pretension > max_tension:
        raise ValueError("need 0 <= pretension <= max_tension and max_tension > 0")
    t, resid, at_max, at_zero = allocate_tensions_kernel(
        np.ascontiguousarray(b), np.ascontiguousarray(tau), float(max_tension),
        float(pretension), float(weight),
    )  # fmt: skip
    scale = max(1.0, float(np.linalg.norm(tau)))
    saturated = bool((at_max or at_zero) and resid > tol * scale + 1e-9)
    return TendonAllocation(t, resid, saturated, at_max, at_zero)


@njit(cache=True)
def allocate_tensions_kernel(b, tau, max_tension, pretension, weight):
    """The bounded least squares of :func:`allocate_tensions` on checked arrays:
    ``(T, |B_s T - tau_s|, any T at T_max, any T at 0)``."""
    ns, na = b.shape
    big = 0.0
    for j in range(na):
        col = 0.0
        for i in range(ns):
            col += b[i, j] * b[i, j]
        big = max(big, np.sqrt(col))
    w = weight * max(big, 1e-12)
    a = np.zeros((ns + na, na))
    rhs = np.empty(ns + na)
    for i in range(ns):
        rhs[i] = tau[i]
        for j in range(na):
            a[i, j] = b[i, j]
    for j in range(na):
        a[ns + j, j] = w
        rhs[ns + j] = w * pretension
    t = box_least_squares(a, rhs, 0.0, max_tension)
    at_max = False
    at_zero = False
    for j in range(na):
        t[j] = min(max(t[j], 0.0), max_tension)
        at_max = at_max or t[j] >= max_tension - 1e-9
        at_zero = at_zero or t[j] <= 1e-9
    r2 = 0.0
    for i in range(ns):
        acc = -tau[i]
        for j in range(na):
            acc += b[i, j] * t[j]
        r2 += acc * acc
    return t, np.sqrt(r2), at_max, at_zero


@dataclass(frozen=True)
class ThrustAllocation:
    thrusts: np.ndarray
    requested: np.ndarray  # before clipping
    saturated: bool


def allocate_thrusts(gamma, torque_body, thrust: float, max_thrust: float) -> ThrustAllocation:
    """Motor thrusts for a body torque and a total thrust through ``Gamma`` (rows 0, 1, 2, 5),
    clipped to ``[0, max_thrust]``; ``saturated`` tells whether clipping was needed."""
    g4 = np.asarray(gamma, float)[[0, 1, 2, 5]]
    req = _solve(g4, np.concatenate((np.asarray(torque_body, float), [thrust])))
    f = np.minimum(np.maximum(req, 0.0), max_thrust)  # np.clip, without its overhead
    return ThrustAllocation(f, req, bool(np.any(np.abs(f - req) > 1e-9)))
