"""Time integration of the coupled model.

* ``method="rk4"``: classical fixed-step Runge-Kutta, the integrator of control loops; with a
  constant input the whole loop runs inside numba (:func:`tdacm.system.kernels.rk4_run`).
* ``method="adaptive"``: scipy's ``solve_ivp`` (DOP853 by default) with error control, for
  accuracy studies.

Inputs are either a constant vector ``u`` or a callable ``u(t, q, qd) -> u`` (held constant over
each RK4 step, a zero-order hold; evaluated at every stage by the adaptive integrator).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from . import kernels as K


@dataclass
class SimulationResult:
    """Time series of a simulation: ``t`` (N,), ``q`` and ``qd`` (N, n), ``u`` (N, n_u)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    completed: bool = True
    message: str = ""

    def save(self, path) -> None:
        np.savez(path, t=self.t, q=self.q, qd=self.qd, u=self.u)


def simulate(
    system,
    q0,
    qd0=None,
    duration: float = 1.0,
    dt: float | None = None,
    u: np.ndarray | Callable | None = None,
    method: str = "rk4",
    record_dt: float | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    solver: str = "DOP853",
    progress: bool = False,
) -> SimulationResult:
    """Integrate the TD-ACM from ``(q0, qd0)`` for ``duration`` seconds.

    ``dt`` is the RK4 step (default :meth:`TDACM.suggested_dt`; ignored by the adaptive method except as the output spacing when
    ``record_dt`` is None); states are recorded every ``record_dt`` (default ``dt``).
    """
    q0 = system._q(q0, "q0")
    qd0 = np.zeros(system.n) if qd0 is None else system._q(qd0, "qd0")
    duration = V.positive("duration", duration)
    dt = system.suggested_dt() if dt is None else V.positive("dt", dt)
    record_dt = dt if record_dt is None else V.positive("record_dt", record_dt)
    every = max(1, int(round(record_dt / dt)))
    system.check_regular(q0)
    m = system.model_arrays
    if u is None:
        u = np.zeros(system.n_u)
    if method == "rk4":
        nsteps = int(round(duration / dt))
        if not callable(u):
            uc = system._u(u)
            loads = system.loads.packed()
            qs, qds, ok = K.rk4_run(q0, qd0, uc, dt, nsteps, every, m, loads)
            t = np.arange(qs.shape[0]) * dt * every
            msg = "" if ok else "stopped: mass matrix singular (Euler singularity)"
            return SimulationResult(t, qs, qds, np.tile(uc, (qs.shape[0], 1)), ok, msg)
        return _rk4_callable(system, q0, qd0, u, dt, nsteps, every, progress)
    if method == "adaptive":
        return _adaptive(system, q0, qd0, u, duration, record_dt, rtol, atol, solver)
    raise ValueError(f"method must be 'rk4' or 'adaptive', got {method!r}")


def _rk4_callable(system, q0, qd0, ufun, dt, nsteps, every, progress):
    m = system.model_arrays
    q, qd = q0.copy(), qd0.copy()
    ts, qs, qds, us = [0.0], [q.copy()], [qd.copy()], []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=nsteps, desc="simulate", unit="step")
    ok, msg = True, ""
    for k in range(nsteps):
        uk = system._u(ufun(k * dt, q, qd))
        us.append(uk)
        qq, qqd, ok = K.rk4_run(q, qd, uk, dt, 1, 1, m, system.loads.packed())
        if not ok or not np.all(np.isfinite(qq[-1])):
            ok, msg = (
                False,
                f"stopped at t = {k * dt:.4f} s: singular mass matrix or non-finite state",
            )
            break
        q, qd = qq[-1], qqd[-1]
        if (k + 1) % every == 0:
            ts.append((k + 1) * dt)
            qs.append(q.copy())
            qds.append(qd.copy())
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    u_arr = np.array(us[::every] + [us[-1]] if us else [np.zeros(system.n_u)])[: len(ts)]
    return SimulationResult(np.array(ts), np.array(qs), np.array(qds), u_arr, ok, msg)


def _adaptive(system, q0, qd0, u, duration, record_dt, rtol, atol, solver):
    from scipy.integrate import solve_ivp

    m = system.model_arrays
    n = system.n
    loads = system.loads.packed()
    if callable(u):
        ufun = u
    else:
        u_const = system._u(u)

        def ufun(t, q, qd):
            return u_const

    def rhs(t, x):
        q, qd = x[:n], x[n:]
        qdd, ok = K.forward_dynamics(q, qd, system._u(ufun(t, q, qd)), m, loads)
        if not ok:
            raise FloatingPointError(f"mass matrix singular at t = {t}")
        return np.concatenate([qd, qdd])

    t_eval = np.arange(0.0, duration + 0.5 * record_dt, record_dt)
    t_eval = t_eval[t_eval <= duration]
    sol = solve_ivp(
        rhs,
        (0.0, duration),
        np.concatenate([q0, qd0]),
        method=solver,
        t_eval=t_eval,
        rtol=rtol,
        atol=atol,
    )
    q, qd = sol.y[:n].T, sol.y[n:].T
    uu = np.array([system._u(ufun(t, a, b)) for t, a, b in zip(sol.t, q, qd, strict=True)])
    return SimulationResult(sol.t, q, qd, uu, sol.success, sol.message)
