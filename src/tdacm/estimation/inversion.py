"""Rod strains from measured tendon lengths (initialization of the estimator).

The encoders measure ``dl = l(q_s) - l(q_ref)`` for each tendon (``l`` the model's path lengths,
paper eq. (13): ``dl/dq_s = -B_s^T``). With at least as many independent tendons as strains the
strains follow by nonlinear least squares,

    q_s = argmin sum_i w_i (l_i(q_s) - l_i(q_ref) - dl_i)^2,

solved by Gauss-Newton (the map is nearly linear: for parallel tendons on a constant-curvature
rod it is exactly ``dl = L r (k_y sin a - k_z cos a)``-type linear), which converges in 2-3
iterations. The paper's four tendons in two antagonistic pairs over-determine the two bending
strains; a pair's common mode is the residual (it detects slack or a mis-zeroed encoder).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..system.tdacm import TDACM
from .kernels import tendon_lengths_and_jacobian


@dataclass(frozen=True)
class InversionResult:
    q_s: np.ndarray  # (n_s,) strains
    residual: np.ndarray  # (n_a,) l(q_s) - l(q_ref) - dl (m)
    iterations: int
    rank: int  # rank of dl/dq_s at the solution (n_s when the strains are all observable)
    success: bool


def strains_from_tendon_lengths(
    system: TDACM,
    delta_lengths,
    q_ref=None,
    q0=None,
    tol: float = 1e-12,
    max_iter: int = 30,
) -> InversionResult:
    """Least-squares strains ``q_s`` whose tendon-length changes from ``q_ref`` (strains of the
    zeroing configuration, default straight) match ``delta_lengths`` (n_a,).

    ``q0`` is the starting guess (default ``q_ref``). Converged when the Gauss-Newton step is
    below ``tol (1 + |q_s|)``; ``success`` also requires full column rank (otherwise the
    minimum-norm step is taken and the unobservable strains stay at ``q0``)."""
    m = system.model_arrays
    ns, na = system.n_s, system.n_a
    dl = np.asarray(delta_lengths, dtype=float)
    if dl.shape != (na,) or not np.all(np.isfinite(dl)):
        raise ValueError(f"delta_lengths must be {na} finite tendon-length changes, got {dl!r}")
    qr = np.zeros(ns) if q_ref is None else np.asarray(q_ref, dtype=float)
    if qr.shape != (ns,):
        raise ValueError(f"q_ref must hold the {ns} strains, got shape {qr.shape}")
    qs = qr.copy() if q0 is None else np.asarray(q0, dtype=float).copy()
    if qs.shape != (ns,):
        raise ValueError(f"q0 must hold the {ns} strains, got shape {qs.shape}")
    l_ref = tendon_lengths_and_jacobian(qr, m)[0]
    qs, iterations, converged = strains_gauss_newton(m, l_ref, dl, qs, float(tol), int(max_iter))
    lengths, jac = tendon_lengths_and_jacobian(qs, m)
    rank = int(np.linalg.matrix_rank(jac))
    return InversionResult(qs, lengths - l_ref - dl, iterations, rank, converged and rank == ns)


@njit(cache=True)
def strains_gauss_newton(m, l_ref, dl, qs0, tol, max_iter):
    """The Gauss-Newton iterations of :func:`strains_from_tendon_lengths` on the model arrays
    ``m``: from ``qs0``, the strains whose lengths minus ``l_ref`` match ``dl``; returns
    ``(q_s, iterations, converged)``."""
    qs = qs0.copy()
    converged = False
    iterations = 0
    for it in range(1, max_iter + 1):
        iterations = it
        lengths, jac = tendon_lengths_and_jacobian(qs, m)
        r = lengths - l_ref - dl
        step = np.linalg.lstsq(jac, -r, rcond=1e-10)[0]
        qs = qs + step
        if np.linalg.norm(step) <= tol * (1.0 + np.linalg.norm(qs)):
            converged = True
            break
    return qs, iterations, converged
