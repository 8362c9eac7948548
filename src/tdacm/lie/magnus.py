"""Magnus expansions for one step of ``g' = g xi(X)`` along the rod (paper eq. (7)).

A step over ``[X_k, X_k + h]`` (``h`` in metres) samples the strain at one point (order 2) or
two Gauss points (order 4, Zanna's scheme).  With ``xi(X) = xi0(X) + B(X) q`` the step returns
the Magnus exponent ``Omega`` and ``Z = dOmega/dq`` (6 x n_s), which the Jacobian recursion
needs, and ``Z_dot`` for the Jacobian's time derivative:

* order 2: ``Omega = h xi(X + h/2)``, ``Z = h B(X + h/2)``, ``Z_dot = 0``;
* order 4: ``Omega = h/2 (xi1 + xi2) + sqrt(3) h^2/12 ad(xi1) xi2``,
  ``Z = h/2 (B1 + B2) + sqrt(3) h^2/12 (ad(xi1) B2 - ad(xi2) B1)``,
  ``Z_dot = sqrt(3) h^2/12 (ad(B1 qdot) B2 - ad(B2 qdot) B1)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import allocating, kernel
from .blocks import ad_apply, ad_vec

#: Abscissae (fraction of the step) of the sample points of each Magnus order.
MAGNUS_POINTS = {2: np.array([0.5]), 4: np.array([0.5 - np.sqrt(3) / 6, 0.5 + np.sqrt(3) / 6])}

_C4 = np.sqrt(3.0) / 12.0


@kernel
def _strain_into(xi0, b, q, out):
    for r in range(6):
        acc = xi0[r]
        for c in range(q.shape[0]):
            acc += b[r, c] * q[c]
        out[r] = acc


@allocating
def magnus_step_into(h, xi0s, bs, q, qd, omega, z, zdq, zd, work):
    """One Magnus step written into ``omega (6,)``, ``z (6, n_s)``, ``zdq = Z_dot qdot (6,)``
    and ``zd = Z_dot (6, n_s)`` (zero for order 2); ``work`` is a (6, 6, n_s) scratch array.

    Parameters: ``h`` step length (m); ``xi0s`` (p, 6) reference strain and ``bs`` (p, 6, n_s)
    basis at the ``p`` sample points (``p = 1`` order 2, ``2`` order 4); ``q, qd`` (n_s,).
    """
    ns = q.shape[0]
    if xi0s.shape[0] == 1:
        _strain_into(xi0s[0], bs[0], q, omega)
        for r in range(6):
            omega[r] *= h
            zdq[r] = 0.0
            for c in range(ns):
                z[r, c] = h * bs[0, r, c]
                zd[r, c] = 0.0
        return
    xi1 = np.empty(6)
    xi2 = np.empty(6)
    v1 = np.empty(6)
    v2 = np.empty(6)
    zero = np.zeros(6)
    _strain_into(xi0s[0], bs[0], q, xi1)
    _strain_into(xi0s[1], bs[1], q, xi2)
    _strain_into(zero, bs[0], qd, v1)
    _strain_into(zero, bs[1], qd, v2)
    c4 = _C4 * h * h
    a12 = ad_vec(xi1, xi2)
    v12 = ad_vec(v1, v2)
    t1 = work[2]
    t2 = work[3]
    ad_apply(xi1, bs[1], t1)
    ad_apply(xi2, bs[0], t2)
    for r in range(6):
        omega[r] = 0.5 * h * (xi1[r] + xi2[r]) + c4 * a12[r]
        zdq[r] = 2.0 * c4 * v12[r]
        for c in range(ns):
            z[r, c] = 0.5 * h * (bs[0, r, c] + bs[1, r, c]) + c4 * (t1[r, c] - t2[r, c])
    ad_apply(v1, bs[1], t1)
    ad_apply(v2, bs[0], t2)
    for r in range(6):
        for c in range(ns):
            zd[r, c] = c4 * (t1[r, c] - t2[r, c])


@njit(cache=True)
def magnus_step(h, xi0s, bs, q, qd):
    """Allocating form of :func:`magnus_step_into`: returns ``Omega (6,)``, ``Z (6, n_s)``,
    ``Z_dot qdot (6,)`` and ``Z_dot (6, n_s)``."""
    ns = q.shape[0]
    omega = np.empty(6)
    z = np.empty((6, ns))
    zdq = np.empty(6)
    zd = np.empty((6, ns))
    magnus_step_into(h, xi0s, bs, q, qd, omega, z, zdq, zd, np.empty((6, 6, ns)))
    return omega, z, zdq, zd
