"""One integrator for every model: Python-level RK4 over ``model.forward_dynamics``.

:func:`rk4_step` is the same Runge-Kutta-Nystrom form of classical RK4 as the numba loop
:func:`tdacm.system.kernels.rk4_run` (so a GVS model gives bit-for-bit comparable results
through either path), but it calls ``forward_dynamics(q, qd, u)`` of any object: the GVS model
and the CC baseline are then timed and compared with the same integrator and step.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def rk4_step(model, q, qd, u, dt):
    """One RK4 step of ``qdd = model.forward_dynamics(q, qd, u)`` (``u`` held constant)."""
    fd = model.forward_dynamics
    a1 = fd(q, qd, u)
    a2 = fd(q + 0.5 * dt * qd, qd + 0.5 * dt * a1, u)
    a3 = fd(q + 0.5 * dt * (qd + 0.5 * dt * a1), qd + 0.5 * dt * a2, u)
    a4 = fd(q + dt * (qd + 0.5 * dt * a2), qd + dt * a3, u)
    q_new = q + dt * qd + dt * dt / 6.0 * (a1 + a2 + a3)
    qd_new = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q_new, qd_new


def rk4_simulate(model, q0, qd0, duration, dt, u=None, record_every: int = 1):
    """Integrate with :func:`rk4_step`; ``u`` constant, ``None`` or ``u(t, q, qd)`` (held over a
    step).  Returns ``t (N,), q (N, n), qd (N, n)``."""
    q = np.asarray(q0, dtype=float).copy()
    qd = np.zeros_like(q) if qd0 is None else np.asarray(qd0, dtype=float).copy()
    nsteps = int(round(duration / dt))
    ufun: Callable | None = u if callable(u) else None
    ts, qs, qds = [0.0], [q.copy()], [qd.copy()]
    for k in range(nsteps):
        uk = ufun(k * dt, q, qd) if ufun is not None else u
        q, qd = rk4_step(model, q, qd, uk, dt)
        if (k + 1) % record_every == 0:
            ts.append((k + 1) * dt)
            qs.append(q.copy())
            qds.append(qd.copy())
    return np.array(ts), np.array(qs), np.array(qds)
