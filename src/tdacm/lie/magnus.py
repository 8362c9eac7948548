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

from .blocks import ad_apply, ad_vec

#: Abscissae (fraction of the step) of the sample points of each Magnus order.
MAGNUS_POINTS = {2: np.array([0.5]), 4: np.array([0.5 - np.sqrt(3) / 6, 0.5 + np.sqrt(3) / 6])}

_C4 = np.sqrt(3.0) / 12.0


@njit(cache=True)
def _strain(xi0, b, q):
    out = xi0.copy()
    for r in range(6):
        acc = 0.0
        for c in range(q.shape[0]):
            acc += b[r, c] * q[c]
        out[r] += acc
    return out


@njit(cache=True)
def magnus_step(h, xi0s, bs, q, qd):
    """One Magnus step.

    Parameters
    ----------
    h : step length (m)
    xi0s : (p, 6) reference strain at the ``p`` sample points (``p = 1`` order 2, ``2`` order 4)
    bs : (p, 6, n_s) basis at the sample points
    q, qd : (n_s,) strain coordinates and their rates

    Returns ``Omega (6,)``, ``Z (6, n_s)``, ``Z_dot qdot (6,)`` and ``Z_dot (6, n_s)``
    (``Z_dot`` is zero for order 2).
    """
    ns = q.shape[0]
    if xi0s.shape[0] == 1:
        omega = h * _strain(xi0s[0], bs[0], q)
        return omega, h * bs[0], np.zeros(6), np.zeros((6, ns))
    xi1 = _strain(xi0s[0], bs[0], q)
    xi2 = _strain(xi0s[1], bs[1], q)
    c = _C4 * h * h
    omega = 0.5 * h * (xi1 + xi2) + c * ad_vec(xi1, xi2)
    t1 = np.empty((6, ns))
    t2 = np.empty((6, ns))
    ad_apply(xi1, bs[1], t1)
    ad_apply(xi2, bs[0], t2)
    z = 0.5 * h * (bs[0] + bs[1]) + c * (t1 - t2)
    v1 = _strain(np.zeros(6), bs[0], qd)
    v2 = _strain(np.zeros(6), bs[1], qd)
    ad_apply(v1, bs[1], t1)
    ad_apply(v2, bs[0], t2)
    zd = c * (t1 - t2)
    return omega, z, 2.0 * c * ad_vec(v1, v2), zd
