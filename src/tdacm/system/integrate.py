"""Time integration of the coupled model.

* ``method="rk4"``: classical fixed-step Runge-Kutta, the integrator of control loops; with a
  constant input the whole loop runs inside numba (:func:`tdacm.system.kernels.rk4_run`).
* ``method="rosenbrock"``: the linearly implicit ROS34PW2 W-method of :mod:`tdacm.system.stiff`
  (numba), for stiff strain bases (torsion, elongation, shear); fixed step ``dt`` (default
  :data:`ROSENBROCK_DT`) or, with ``rtol`` given, adaptive steps of at most ``dt`` with
  embedded error control.
* ``method="radau"``: the 3-stage Radau IIA method (order 5, L-stable) of
  :func:`tdacm.system.stiff.radau_run`, applied to the mass-matrix form ``M(q) qdd = F`` (no
  ``M^-1``), velocities eliminated (a 3n-dimensional stage system), Newton matrix from the
  current stage mass matrices and the constant ``K``, ``D``; fixed step ``dt`` (default
  :data:`RADAU_DT`, 10 ms) with dense output at ``record_dt``, or, with ``rtol`` given,
  adaptive steps of at most ``dt`` (embedded RADAU5 error estimate; slow on the stiff rods,
  see ``docs/model.md``).
* ``method="adaptive"``: scipy's ``solve_ivp`` (DOP853 by default) with error control, for
  accuracy studies.
* ``method="auto"`` (the default): RK4 unless the model is stiff (:func:`is_stiff`: a basis
  with torsion, elongation or shear and an RK4 step :meth:`TDACM.suggested_dt` below
  :data:`STIFF_DT`, 1 ms), then ``"radau"`` (see ``docs/benchmarks.md``: more than 20x faster
  than ``"rosenbrock"`` at the same accuracy rule on the 18-DoF rod of ``tdacm bench``).  The
  paper system (``suggested_dt`` = 10 ms) integrates with RK4 exactly as before.

Inputs are either a constant vector ``u`` or a callable ``u(t, q, qd) -> u`` (held constant over
each RK4 step, a zero-order hold; evaluated at every stage by the adaptive integrator).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from . import kernels as K
from . import stiff as ST

#: Below this RK4 step (s) ``method="auto"`` switches to the Radau integrator (stiff bases).
STIFF_DT = 1e-3
#: Default fixed step of ``method="rosenbrock"`` (s).
ROSENBROCK_DT = 2.5e-3
#: Default fixed step of ``method="radau"`` (s) and its Newton settings.
RADAU_DT = 1e-2
#: Newton settings of ``method="radau"``: stop when ``theta / (1 - theta) |dZ| <= 1`` with the
#: weights ``newton_tol (1 + |q|)``; at most ``max_iter`` iterations before the step is halved.
RADAU_NEWTON = {"newton_tol": 1e-6, "max_iter": 8}


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


def is_stiff(system) -> bool:
    """True when a rod has torsion, elongation or shear strains and RK4 would need steps below
    :data:`STIFF_DT` (bending-only bases stay with RK4 whatever their order)."""
    has = any(sec.basis.stiff for arm in system.arms for sec in arm.sections)
    return has and system.suggested_dt() < STIFF_DT


def simulate(
    system,
    q0,
    qd0=None,
    duration: float = 1.0,
    dt: float | None = None,
    u: np.ndarray | Callable | None = None,
    method: str = "auto",
    record_dt: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    adaptive_solver: str = "DOP853",
    progress: bool = False,
) -> SimulationResult:
    """Integrate the TD-ACM from ``(q0, qd0)`` for ``duration`` seconds.

    ``method``: ``"auto"`` (default), ``"rk4"``, ``"rosenbrock"``, ``"radau"`` or
    ``"adaptive"`` (module docstring).  ``dt`` is the RK4 step (default
    :meth:`TDACM.suggested_dt`), the Rosenbrock step (default :data:`ROSENBROCK_DT`) or the
    Radau step (default :data:`RADAU_DT`) - the largest step when ``rtol`` is given; ignored by
    the adaptive method except as the output spacing when ``record_dt`` is None.  States are
    recorded every ``record_dt`` (default ``dt``; any spacing for Radau, which interpolates).
    ``rtol``/``atol``: tolerances of the adaptive method (default 1e-8 / 1e-10) and, if given,
    of the Rosenbrock and Radau methods (``atol`` for the positions; the velocities use
    ``atol * 100``). ``adaptive_solver``: the :func:`scipy.integrate.solve_ivp` method of the
    adaptive method.
    """
    q0 = system._q(q0, "q0")
    qd0 = np.zeros(system.n) if qd0 is None else system._q(qd0, "qd0")
    duration = V.positive("duration", duration)
    if method not in ("auto", "rk4", "rosenbrock", "radau", "adaptive"):
        raise ValueError(
            f"method must be 'auto', 'rk4', 'rosenbrock', 'radau' or 'adaptive', got {method!r}"
        )
    if method == "auto":
        method = "radau" if is_stiff(system) else "rk4"
    if dt is None:
        dt = {"rosenbrock": ROSENBROCK_DT, "radau": RADAU_DT}.get(method) or system.suggested_dt()
    else:
        dt = V.positive("dt", dt)
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
    if method == "radau":
        return _radau(system, q0, qd0, u, duration, dt, record_dt, rtol, atol)
    if method == "rosenbrock":
        return _rosenbrock(system, q0, qd0, u, duration, dt, record_dt, rtol, atol)
    rtol = 1e-8 if rtol is None else rtol
    atol = 1e-10 if atol is None else atol
    return _adaptive(system, q0, qd0, u, duration, record_dt, rtol, atol, adaptive_solver)


def _rosenbrock(system, q0, qd0, u, duration, dt, record_dt, rtol, atol):
    """ROS34PW2 at constant input (one numba call) or with ``u(t, q, qd)`` held over every
    ``record_dt`` interval (a zero-order hold at the recording rate)."""
    m, loads = system.model_arrays, system.loads.packed()
    adaptive = rtol is not None
    rt = V.positive("rtol", rtol) if adaptive else 0.0
    at = (1e-6 if atol is None else V.positive("atol", atol)) if adaptive else 0.0
    if not adaptive:
        k = record_dt / dt
        if abs(k - round(k)) > 1e-9 * max(1.0, k):
            raise ValueError(f"record_dt ({record_dt}) must be a multiple of dt ({dt})")
    if not callable(u):
        uc = system._u(u)
        t, qs, qds, ok, _, _, _ = ST.rosw_run(
            q0, qd0, uc, duration, record_dt, dt, dt, rt, at, 100.0 * at, m, loads
        )
        msg = "" if ok else "stopped: singular mass or iteration matrix, or step size underflow"
        return SimulationResult(t, qs, qds, np.tile(uc, (qs.shape[0], 1)), ok, msg)
    h = [dt]  # the adaptive step carries over from one interval to the next

    def advance(q, qd, uk):
        _, qq, qqd, ok, _, _, h[0] = ST.rosw_run(
            q, qd, uk, record_dt, record_dt, h[0] if adaptive else dt, dt, rt, at, 100.0 * at,
            m, loads,
        )  # fmt: skip
        return (qq[-1], qqd[-1]) if ok else None

    res, failed = _held_input_run(system, u, q0, qd0, duration, record_dt, advance)
    msg = ""
    if failed is not None:
        msg = f"stopped at t = {failed * record_dt:.4f} s: singular matrix or step underflow"
    return SimulationResult(*res, failed is None, msg)


def _held_input_run(system, u, q0, qd0, duration, record_dt, advance):
    """A stiff integrator with ``u(t, q, qd)`` held over every ``record_dt`` interval (a
    zero-order hold at the recording rate): ``advance(q, qd, u_k)`` integrates one interval
    and returns the end state, or ``None`` if it failed. Returns the arrays ``(t, q, qd, u)``
    up to the failure and the index of the failed interval (``None``: completed)."""
    nrec = int(np.floor(duration / record_dt + 1e-9))
    q, qd = q0.copy(), qd0.copy()
    ts, qs, qds, us = [0.0], [q.copy()], [qd.copy()], []
    failed = None
    for k in range(nrec):
        uk = system._u(u(k * record_dt, q, qd))
        us.append(uk)
        end = advance(q, qd, uk)
        if end is None:
            failed = k
            break
        q, qd = end
        ts.append((k + 1) * record_dt)
        qs.append(q.copy())
        qds.append(qd.copy())
    u_arr = np.array((us + [us[-1]]) if us else [np.zeros(system.n_u)])[: len(ts)]
    return (np.array(ts), np.array(qs), np.array(qds), u_arr), failed


def _radau(system, q0, qd0, u, duration, dt, record_dt, rtol, atol):
    """Radau IIA at constant input (one numba call) or with ``u(t, q, qd)`` held over every
    ``record_dt`` interval (a zero-order hold at the recording rate; each interval restarts
    the iteration from a fresh acceleration)."""
    m, loads = system.model_arrays, system.loads.packed()
    nw = RADAU_NEWTON
    adaptive = rtol is not None
    rt = V.positive("rtol", rtol) if adaptive else 0.0
    at = (1e-6 if atol is None else V.positive("atol", atol)) if adaptive else 0.0
    msg_bad = "stopped: the Newton iteration failed down to 1 ns steps (or a singular matrix)"

    def run(q, qd, uk, span, h):
        args = (rt, at, 100.0 * at, nw["newton_tol"], nw["max_iter"], m, loads)
        try:
            return ST.radau_run(q, qd, uk, span, record_dt, h, dt, *args)
        except np.linalg.LinAlgError:  # a singular stage matrix (LAPACK raises)
            return np.zeros(1), q[None].copy(), qd[None].copy(), False, None

    if not callable(u):
        uc = system._u(u)
        t, qs, qds, ok, _ = run(q0, qd0, uc, duration, dt)
        return SimulationResult(
            t, qs, qds, np.tile(uc, (qs.shape[0], 1)), ok, "" if ok else msg_bad
        )

    def advance(q, qd, uk):
        _, qq, qqd, ok, _ = run(q, qd, uk, record_dt, min(dt, record_dt))
        return (qq[-1], qqd[-1]) if ok else None

    res, failed = _held_input_run(system, u, q0, qd0, duration, record_dt, advance)
    return SimulationResult(*res, failed is None, "" if failed is None else msg_bad)


def _rk4_callable(system, q0, qd0, ufun, dt, nsteps, every, progress):
    m = system.model_arrays
    q, qd = q0.copy(), qd0.copy()
    ts, qs, qds, us = [0.0], [q.copy()], [qd.copy()], []
    bar = None
    if progress:
        from tqdm import tqdm

        from .._log import progress_enabled

        bar = tqdm(total=nsteps, desc="simulate", unit="step", disable=not progress_enabled())
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
