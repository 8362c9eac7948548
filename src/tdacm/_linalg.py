"""``np.linalg.solve`` for the small float64 systems of the control period.

``np.linalg.solve`` spends most of its ~8 us on a 6 x 6 system in generic argument handling
(array wrapping, dtype promotion, stacking checks); :func:`solve` calls the same LAPACK
gufunc under the same error state, so the results are bit-identical and a singular matrix
still raises ``LinAlgError("Singular matrix")``. Anything but a float64 square matrix and a
float64 ``(M,)`` or ``(M, K)`` right-hand side goes to ``np.linalg.solve`` unchanged.

For jitted code: :func:`lu_factor` / :func:`lu_solve` (LU with partial pivoting, numba; the
stiff integrators' Newton systems and the target filter's Gauss-Newton steps), and
:func:`solve_small`, the same as a ``(x, ok)`` solve that flags a singular matrix instead of
raising (LAPACK's ``dgesv`` fails on an exactly zero pivot; so does this), and
:func:`svd_solve`, the SVD solves of the servo (floored or damped small singular values) and
of the joint rates (the pseudo-inverse).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._jit import kernel

try:  # numpy's private gufuncs (numpy >= 2); np.linalg.solve is the fallback
    from numpy.linalg import _umath_linalg as _ul

    _SOLVE1, _SOLVE = _ul.solve1, _ul.solve
except (ImportError, AttributeError):  # pragma: no cover
    _SOLVE1 = _SOLVE = None


def _singular(err, flag):
    raise np.linalg.LinAlgError("Singular matrix")


def solve(a, b) -> np.ndarray:
    """``np.linalg.solve(a, b)`` (same LAPACK call, same errors) with less overhead."""
    if (
        _SOLVE is None
        or type(a) is not np.ndarray
        or type(b) is not np.ndarray
        or a.dtype != np.float64
        or b.dtype != np.float64
        or a.ndim != 2
        or a.shape[0] != a.shape[1]
        or not 1 <= b.ndim <= 2
        or b.shape[0] != a.shape[0]
    ):
        return np.linalg.solve(a, b)
    with np.errstate(
        call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"
    ):
        return (_SOLVE1 if b.ndim == 1 else _SOLVE)(a, b, signature="dd->d")


@njit(cache=True)
def lu_factor(a):
    """LU factorization with partial pivoting of a copy of ``a``: ``(lu, piv, ok)``
    (:func:`lu_inplace`)."""
    lu = a.copy()
    piv = np.empty(a.shape[0], np.int64)
    ok = lu_inplace(lu, piv)
    return lu, piv, ok


@njit(cache=True)
def lu_inplace(lu, piv):
    """LU factorization with partial pivoting of ``lu`` (real or complex) in place, the row
    permutation in ``piv``; False if a pivot is zero or not finite (singular)."""
    n = lu.shape[0]
    for k in range(n):
        piv[k] = k
    for k in range(n):
        p = k
        big = abs(lu[k, k])
        for i in range(k + 1, n):
            if abs(lu[i, k]) > big:
                big = abs(lu[i, k])
                p = i
        if big == 0.0 or not np.isfinite(big):
            return False
        if p != k:
            for c in range(n):
                lu[k, c], lu[p, c] = lu[p, c], lu[k, c]
            piv[k], piv[p] = piv[p], piv[k]
        for i in range(k + 1, n):
            f = lu[i, k] / lu[k, k]
            lu[i, k] = f
            if f != 0.0:
                for c in range(k + 1, n):
                    lu[i, c] -= f * lu[k, c]
    return True


@njit(cache=True)
def lu_solve(lu, piv, b):
    """``A^-1 b`` from :func:`lu_factor` (real), in a new array (:func:`lu_solve_into`)."""
    y = np.empty(b.shape[0])
    lu_solve_into(lu, piv, b, y)
    return y


@njit(cache=True)
def lu_solve_into(lu, piv, b, y):
    """``y = A^-1 b`` from :func:`lu_factor` (real or complex), no allocation."""
    n = b.shape[0]
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


@njit(cache=True)
def solve_small(a, b):
    """``(a^-1 b, ok)`` for a small dense ``a`` by :func:`lu_factor`; ``ok`` is False (and
    ``x`` zero) when a pivot is zero or not finite."""
    lu, piv, ok = lu_factor(a)
    if not ok:
        return np.zeros(b.shape[0]), False
    return lu_solve(lu, piv, b), True


#: ``kind`` of :func:`svd_solve`
SVD_PINV, SVD_FLOOR, SVD_DAMPED = 0, 1, 2


@njit(cache=True)
def svd_solve(a, b, kind, param):
    """``V diag(f(sigma)) U^T b`` from the thin SVD ``a = U diag(sigma) V^T``, with ``f`` by
    ``kind``: :data:`SVD_PINV` the pseudo-inverse, ``1 / sigma`` for ``sigma > param
    sigma_max`` and 0 below (``np.linalg.pinv(a, rcond=param) @ b``); :data:`SVD_FLOOR`
    ``1 / max(sigma, param)``; :data:`SVD_DAMPED` ``sigma / (sigma^2 + param^2)``."""
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    k = sv.shape[0]
    cut = param * sv[0]
    w = np.zeros(k)
    for i in range(k):
        if kind == SVD_PINV and not sv[i] > cut:
            continue
        acc = 0.0
        for r in range(a.shape[0]):
            acc += u[r, i] * b[r]
        if kind == SVD_PINV:
            w[i] = acc / sv[i]
        elif kind == SVD_FLOOR:
            w[i] = acc * (1.0 / max(sv[i], param))
        else:
            w[i] = acc * (sv[i] / (sv[i] * sv[i] + param * param))
    x = np.zeros(a.shape[1])
    for c in range(a.shape[1]):
        acc = 0.0
        for i in range(k):
            acc += vt[i, c] * w[i]
        x[c] = acc
    return x


@kernel
def cholesky_into(a, n, lo):
    """``a[:n, :n] = L L^T`` into the lower triangle of ``lo`` (row by row); ``False`` if ``a``
    is not positive definite (a pivot ``<= 0``). Only the lower triangle of ``a`` is read."""
    for i in range(n):
        for k in range(i + 1):
            s = a[i, k]
            for p in range(k):
                s -= lo[i, p] * lo[k, p]
            if i == k:
                if s <= 0.0:
                    return False
                lo[i, i] = np.sqrt(s)
            else:
                lo[i, k] = s / lo[k, k]
    return True


@kernel
def cholesky_substitute(lo, n, b, y, x):
    """``x = L^-T L^-1 b`` for the lower factor ``lo`` of :func:`cholesky_into`: forward
    substitution into ``y``, backward into ``x``. ``b``, ``y`` and ``x`` may be one array
    (the same operations in the same order either way)."""
    for i in range(n):
        s = b[i]
        for p in range(i):
            s -= lo[i, p] * y[p]
        y[i] = s / lo[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, n):
            s -= lo[p, i] * x[p]
        x[i] = s / lo[i, i]
