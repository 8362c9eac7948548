"""Least squares with the structure of multiple shooting: the window states eliminated per block.

The decision vector of a multiple-shooting fit (:class:`~tdacm.identify.fit.Problem`) is ``p``
parameters followed by every window's initial state (``2 n`` each). A window's state moves
only that window's residuals, so the Jacobian is ``J = [J_p | J_s]`` with ``J_s`` block
diagonal (window ``w``: rows ``R_w``, columns ``C_w``). The normal matrix

``J^T J = [[A, B], [B^T, C]]``, ``A = J_p^T J_p``, ``B_w = J_p[R_w]^T J_w``,
``C = diag(C_w)``, ``C_w = J_w^T J_w``

is solved by eliminating each window's block (the Schur complement
``F = A - sum_w B_w C_w^-1 B_w^T``, the parameters' Fisher information with the states
eliminated): ``O(m (p + 2 n)^2)`` instead of the ``O(m n_z^2)`` of a dense factorization of
the ``m x n_z`` Jacobian (12,000 x 244 for the rod on ``bending:2``: 20 windows of 12 states).

:func:`levenberg_marquardt` is a Levenberg-Marquardt iteration on this structure (Marquardt's
scaling ``lambda diag(J^T J)``, Nielsen's update of ``lambda``, the parameters projected on
their bounds) with the stopping tests of :func:`scipy.optimize.least_squares` (``ftol`` on the
cost's relative decrease, ``xtol`` on the step). :func:`parameter_rows` gives the parameter
rows of ``(J^T J)^-1 J^T`` (the map from residuals to the estimate's first-order error) and
``F^-1``, which the covariances of :mod:`tdacm.identify.fit` use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A window block's diagonal below this share of its largest entry is floored (a state the
#: window's measurements do not see keeps a finite, tiny-step solve).
DIAG_FLOOR = 1e-12


@dataclass
class Blocks:
    """Index of the windows: ``rows[w] = (r0, r1)``, ``cols[w] = (c0, c1)``, ``npar``."""

    npar: int
    rows: list
    cols: list


@dataclass
class Normal:
    """The pieces of ``J^T J`` and ``J^T r`` (see the module docstring)."""

    a: np.ndarray  # (p, p)
    b: list  # (p, k_w)
    c: list  # (k_w, k_w)
    gp: np.ndarray  # (p,)
    gs: list  # (k_w,)


def normal(jac: np.ndarray, r: np.ndarray, blocks: Blocks) -> Normal:
    p = blocks.npar
    jp = jac[:, :p]
    b, c, gs = [], [], []
    for (r0, r1), (c0, c1) in zip(blocks.rows, blocks.cols, strict=True):
        jw = jac[r0:r1, c0:c1]
        b.append(jp[r0:r1].T @ jw)
        c.append(jw.T @ jw)
        gs.append(jw.T @ r[r0:r1])
    return Normal(jp.T @ jp, b, c, jp.T @ r, gs)


def _chol_solve(m: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        lo = np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(m, rhs, rcond=None)[0]
    y = np.linalg.solve(lo, rhs)
    return np.linalg.solve(lo.T, y)


def solve_damped(ne: Normal, lam: float, diag_p: np.ndarray, diag_s: list):
    """``delta`` solving ``(J^T J + lam D) delta = -J^T r`` with ``D = diag(diag_p, diag_s)``,
    the window blocks eliminated first. Returns ``(delta_p, [delta_w])``."""
    p = ne.a.shape[0]
    f = ne.a + lam * np.diag(diag_p)
    rhs = -ne.gp.copy()
    cinv_bt, cinv_g = [], []
    for bw, cw, gw, dw in zip(ne.b, ne.c, ne.gs, diag_s, strict=True):
        cd = cw + lam * np.diag(dw)
        x = _chol_solve(cd, np.column_stack([bw.T, gw]) if p else gw[:, None])
        xb, xg = (x[:, :p], x[:, p]) if p else (np.zeros((len(gw), 0)), x[:, 0])
        cinv_bt.append(xb)
        cinv_g.append(xg)
        if p:
            f -= bw @ xb
            rhs += bw @ xg
    dp = _chol_solve(f, rhs) if p else np.zeros(0)
    ds = [-xg - xb @ dp for xb, xg in zip(cinv_bt, cinv_g, strict=True)]
    return dp, ds


def _scaling(ne: Normal):
    dp = np.diag(ne.a).copy()
    ds = []
    for cw in ne.c:
        d = np.diag(cw).copy()
        ds.append(np.maximum(d, DIAG_FLOOR * max(float(np.max(d, initial=0.0)), 1e-300)))
    if dp.size:
        dp = np.maximum(dp, DIAG_FLOOR * max(float(np.max(dp)), 1e-300))
    return dp, ds


@dataclass
class Result:
    """What :func:`levenberg_marquardt` returns (the fields of ``least_squares``'s result
    that the fit reads)."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float  # half the sum of squares, as least_squares
    nfev: int
    njev: int
    success: bool
    message: str


def levenberg_marquardt(fun, jac, z0, blocks: Blocks, lb=None, ub=None, ftol=1e-7, xtol=1e-7,
                        max_nfev=40, lam0=1e-3) -> Result:  # fmt: skip
    """Minimize ``|fun(z)|^2`` from ``z0`` (see the module docstring); ``jac(z)`` the dense
    ``m x n_z`` Jacobian, ``blocks`` its windows, ``lb``/``ub`` bounds (enforced by
    projection). Stops when an accepted step lowers the cost by less than ``ftol`` of it, when
    the step is below ``xtol (xtol + |z|)``, or after ``max_nfev`` evaluations of ``fun``."""
    n = z0.size
    lb = np.full(n, -np.inf) if lb is None else np.asarray(lb, float)
    ub = np.full(n, np.inf) if ub is None else np.asarray(ub, float)
    z = np.clip(np.asarray(z0, float), lb, ub)
    r = fun(z)
    f = float(r @ r)
    nfev, njev = 1, 0
    lam, nu = lam0, 2.0
    message, success = "the maximum number of function evaluations is exceeded", False
    j = None
    need_jac = True
    while nfev < max_nfev:
        if need_jac:
            j = jac(z)
            njev += 1
            ne = normal(j, r, blocks)
            diag_p, diag_s = _scaling(ne)
            need_jac = False
        dp, ds = solve_damped(ne, lam, diag_p, diag_s)
        delta = np.zeros(n)
        delta[: blocks.npar] = dp
        for (c0, c1), d in zip(blocks.cols, ds, strict=True):
            delta[c0:c1] = d
        zn = np.clip(z + delta, lb, ub)
        step = zn - z
        rn = fun(zn)
        nfev += 1
        fn = float(rn @ rn) if np.all(np.isfinite(rn)) else np.inf
        lin = r + j @ step
        pred = f - float(lin @ lin)
        actual = f - fn
        small_step = np.linalg.norm(step) < xtol * (xtol + np.linalg.norm(z))
        if pred > 0 and actual > 1e-4 * pred:
            rho = actual / pred
            z, r = zn, rn
            f_old, f = f, fn
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            need_jac = True
            if actual < ftol * f_old:
                message, success = "`ftol` termination condition is satisfied.", True
                break
            if small_step:
                message, success = "`xtol` termination condition is satisfied.", True
                break
        else:
            if small_step or pred <= 0 and np.isfinite(fn) and abs(actual) <= ftol * f:
                message, success = "`xtol` termination condition is satisfied.", True
                break
            lam *= nu
            nu *= 2.0
    if need_jac or j is None:
        j = jac(z)
        njev += 1
    return Result(z, r, j, 0.5 * f, nfev, njev, success, message)


def parameter_rows(jac: np.ndarray, blocks: Blocks):
    """``(h, f_inv)``: the parameter rows ``h`` (p x m) of ``(J^T J)^-1 J^T`` and
    ``F^-1 = [(J^T J)^-1]_{pp}``, by eliminating each window's states: ``h = F^-1 Jt^T`` with
    ``Jt`` the parameter columns made orthogonal, window by window, to that window's state
    columns (``Jt[R_w] = J_p[R_w] - J_w C_w^+ B_w^T``) and ``F = Jt^T Jt``."""
    p = blocks.npar
    jt = np.array(jac[:, :p], copy=True)
    for (r0, r1), (c0, c1) in zip(blocks.rows, blocks.cols, strict=True):
        if c1 == c0:
            continue
        jw = jac[r0:r1, c0:c1]
        coef = np.linalg.lstsq(jw, jt[r0:r1], rcond=None)[0]
        jt[r0:r1] -= jw @ coef
    f_inv = np.linalg.pinv(jt.T @ jt)
    return f_inv @ jt.T, f_inv
