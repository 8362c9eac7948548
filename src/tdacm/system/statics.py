"""Static equilibrium of the rod with its base held (paper eq. (9) with ``qdot = qdd = 0``).

The residual on the rod coordinates is ``r(q_s) = B_s(q) u_s + tau_ext(q) - K(q)``; Newton's
method with a finite-difference Jacobian and a backtracking line search solves ``r = 0``.  Large
deflections are reached by ramping loads and inputs in ``load_steps`` increments (a continuation
that also picks the branch connected to the straight rod).
"""

from __future__ import annotations

import numpy as np

from . import kernels as K


def _residual(system, q, u, loads_packed):
    m = system.model_arrays
    zero = np.zeros(system.n)
    _, _, _, tau, _, _, _ = K.coupled_terms(q, zero, m, loads_packed, False)
    r = K.input_matrix(q, m) @ u + tau - m.stiffness @ q
    return r[system.n - system.n_s :]


def solve_equilibrium(system, u=None, q0=None, base_q=None, load_steps=1, tol=1e-12, max_iter=50):
    n, ns = system.n, system.n_s
    off = n - ns
    u = np.zeros(system.n_u) if u is None else system._u(u)
    if q0 is None:
        q = np.zeros(n)
    else:
        q = system._q(q0, "q0").copy()
    if system.floating:
        if base_q is not None:
            from .. import _validate as V

            q[:6] = V.array("base_q", base_q, (6,))
        system.check_regular(q)
    if not isinstance(load_steps, int) or load_steps < 1:
        raise ValueError(f"load_steps must be an integer >= 1, got {load_steps!r}")
    full = system.loads.packed()
    # the held base sees no inputs: only the rod's equations are solved
    u_rod = u.copy()
    if system.floating:
        u_rod[:4] = 0.0
    for step in range(1, load_steps + 1):
        lam = step / load_steps
        loads = full * lam
        ul = u_rod * lam
        for _ in range(max_iter):
            r = _residual(system, q, ul, loads)
            if np.linalg.norm(r) == 0.0:
                break
            jac = np.empty((ns, ns))
            for i in range(ns):
                eps = 1e-7 * max(1.0, abs(q[off + i]))
                qp = q.copy()
                qm = q.copy()
                qp[off + i] += eps
                qm[off + i] -= eps
                jac[:, i] = (
                    _residual(system, qp, ul, loads) - _residual(system, qm, ul, loads)
                ) / (2 * eps)
            dq = np.linalg.solve(jac, -r)
            alpha = 1.0
            r0 = np.linalg.norm(r)
            while alpha > 1e-4:
                qn = q.copy()
                qn[off:] += alpha * dq
                if np.linalg.norm(_residual(system, qn, ul, loads)) < r0:
                    break
                alpha *= 0.5
            q = qn
            if np.linalg.norm(alpha * dq) <= tol * (1.0 + np.linalg.norm(q[off:])):
                break
        else:
            raise RuntimeError(
                f"static equilibrium did not converge at load step {step}/{load_steps} "
                f"(residual {np.linalg.norm(r):.3e}); try more load_steps"
            )
    return q
