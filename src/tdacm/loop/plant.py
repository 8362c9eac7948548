"""The plant block: the true coupled model (paper eq. (9)) under disturbances.

:class:`Plant` integrates ``M qdd + (C + D) qd + K = tau_ext + B u`` with the input held over
one control period (``substeps`` RK4 steps inside numba, :func:`tdacm.system.kernels.rk4_run`).
Disturbances are loads by name (the attributes of :class:`~tdacm.system.tdacm.Loads`), never
packed indices: :class:`Disturbances` gives, at time ``t``, the values of the loads it drives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..aero.layout import set_wind
from ..aero.wind import Wind
from ..contact import layout as CL
from ..contact.geometry import clearance
from ..system.aero import check_aero
from ..system.contact import check_contact
from ..system.kernels import (
    LOAD_GRAVITY,
    contact_nodes,
    forward_dynamics,
    forward_dynamics_aero,
    forward_dynamics_env,
    rk4_run,
    rk4_run_aero,
    rk4_run_env,
)
from ..system.tdacm import TDACM, Loads
from .config import DisturbancesConfig
from .data import PlantState

#: Roll or pitch (rad) beyond which the drone counts as tumbled and the run ends
#: (:attr:`~tdacm.loop.Termination.TUMBLED`): the model's ZYX Euler coordinates are singular at
#: a pitch of 90 degrees, and a quadrotor tilted this far has lost its thrust against gravity.
MAX_TILT_RAD = float(np.radians(80.0))


@dataclass(frozen=True)
class Disturbances:
    """The scenario's ``[disturbances]`` (paper, test C):

    * ``base_wrench_amplitude`` (6,), ``base_wrench_frequency`` (Hz): a structural vibration,
      ``W_b^b = amplitude sin(2 pi f t)`` on the drone, in its body frame ``[m; f]``;
    * ``downwash`` (3,) and ``downwash_noise``: the rotors' downwash on the rod, an inertial
      force density (N/m) ``downwash + noise N(0, I)`` redrawn every control period.
    """

    base_wrench_amplitude: np.ndarray = field(default_factory=lambda: np.zeros(6))
    base_wrench_frequency: float = 0.0
    downwash: np.ndarray = field(default_factory=lambda: np.zeros(3))
    downwash_noise: float = 0.0

    @classmethod
    def from_config(cls, c: DisturbancesConfig) -> Disturbances:
        """From the ``[disturbances]`` record."""
        return cls(
            np.asarray(c.base_wrench_amplitude, float),
            float(c.base_wrench_frequency),
            np.asarray(c.downwash, float),
            float(c.downwash_noise),
        )

    @property
    def active(self) -> bool:
        return bool(
            (np.any(self.base_wrench_amplitude) and self.base_wrench_frequency > 0)
            or np.any(self.downwash)
            or self.downwash_noise > 0
        )

    def loads_at(self, t: float, rng: np.random.Generator, floating: bool) -> dict:
        """``{load name: value}`` of the driven loads at time ``t``."""
        out = {}
        if floating and np.any(self.base_wrench_amplitude) and self.base_wrench_frequency > 0:
            out["base_wrench"] = self.base_wrench_amplitude * np.sin(
                2 * np.pi * self.base_wrench_frequency * t
            )
        if np.any(self.downwash) or self.downwash_noise > 0:
            out["rod_force"] = self.downwash + self.downwash_noise * rng.standard_normal(3)
        return out


class Plant:
    """The simulated TD-ACM. ``advance(u, dt)`` holds ``u`` over ``dt`` and returns the new
    :class:`PlantState`; ``ok`` turns false when the integration fails (singular mass matrix
    or a non-finite state), ``tumbled`` true when the drone's roll or pitch exceeds
    :data:`MAX_TILT_RAD`.

    ``aero``: the packed aerodynamics of the system (:func:`tdacm.system.aero.aero_array`),
    integrated inside the kernels (the rotor wake follows the state and the thrusts at every
    stage); ``wind`` (a :class:`~tdacm.aero.Wind`) sets its uniform wind at the start of every
    period.  Without ``aero`` the plant is exactly the aerodynamically empty model.

    ``contact``: the packed contact scene (:func:`tdacm.system.contact.contact_array`).  The
    penalty contact is stiff (316 rad/s for the default tip stiffness and the 10 g camera,
    about 1000 rad/s for the rod's) and its regularized friction more so (a damping
    ``mu F_n / v_slip``): with 0.02 s periods, sliding and sticking on a tilted plane diverge
    with 8 RK4 steps a period and agree within 0.1 % from 16 steps on with a 40x finer
    integration (``tests/contact``); the default 32 keeps a factor 2.  So a period that starts with a node sphere within
    ``contact_margin`` of an obstacle (plus twice the distance the fastest node travels in a
    period) is integrated with ``contact_substeps`` RK4 steps instead of ``substeps``.  A period
    whose bounding sphere of the arm (centred on the drone or the clamp, through every point
    the rods and the tip sphere can reach) stays that far from every obstacle is integrated
    without the contact array at all: far from the obstacles the plant is the contact-free one
    (the same arithmetic, the same cost).
    """

    def __init__(
        self,
        system: TDACM,
        q0,
        qd0,
        substeps: int = 4,
        disturbances: Disturbances | None = None,
        rng: np.random.Generator | None = None,
        aero: np.ndarray | None = None,
        wind: Wind | None = None,
        accelerations: bool = False,
        contact: np.ndarray | None = None,
        contact_substeps: int = 32,
        contact_margin: float = 0.01,
        force_limit: float | None = None,
    ):
        if wind is not None and aero is None:
            raise ValueError("wind needs aero (the packed aerodynamics it acts through)")
        self.aero = None if aero is None else check_aero(system, aero).copy()
        self.wind = wind
        self.contact = None if contact is None else check_contact(system, contact).copy()
        self.contact_substeps = int(contact_substeps)
        self.contact_margin = float(contact_margin)
        #: N: the largest contact force (tip sphere plus rod, magnitude of the sum) allowed;
        #: beyond it :attr:`over_limit` says so (the loop ends the run: ``FORCE_LIMIT``)
        self.force_limit = None if force_limit is None else float(force_limit)
        self.over_limit: str | None = None
        #: the number of RK4 steps of the last period
        self.last_substeps = int(substeps)
        if self.contact is not None:
            m = system.model_arrays
            reach = max(
                np.linalg.norm(m.g_att[i][:3, 3]) + arm.length for i, arm in enumerate(system.arms)
            )
            # 5 % for the axial strains of a full basis
            self._reach = 1.05 * reach + max(self.contact[CL.TIP_RADIUS], float(
                np.max(self.contact[CL.N_HEADER : CL.N_HEADER + m.h.shape[0]])
            ))  # fmt: skip
            # the rod of every node of contact_nodes (its base, Gauss points and tip)
            self._node_rod = np.array([
                rod
                for rod in range(m.rod_steps.shape[0] - 1)
                for k in [-1, *range(m.rod_steps[rod], m.rod_steps[rod + 1])]
                if k < 0 or (m.step_w[k] != 0.0 and m.step_load[k] != LOAD_GRAVITY)
            ])  # fmt: skip
            probe = float(np.linalg.norm(self.contact[CL.PROBE : CL.PROBE + 3]))
            if probe > 0.0:  # the tip sphere on a rigid probe ahead of the tip
                self._reach += probe
        self.system = system
        self.substeps = int(substeps)
        self.disturbances = disturbances or Disturbances()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        # the plant's own loads: gravity of the system plus the disturbances, by name
        self._loads = Loads(gravity=system.loads.gravity.copy())
        self._base = system.loads.packed().copy()
        #: also compute the accelerations at the end of each period (for an IMU)
        self.accelerations = bool(accelerations)
        #: the state the plant was built with, at t = 0: where :meth:`reset` without ``q0``
        #: starts
        self.initial = PlantState(0.0, np.array(q0, float), np.array(qd0, float))
        self.reset()

    def reset(self, q0=None, qd0=None, t: float = 0.0) -> PlantState:
        """Start at ``(q0, qd0)`` at time ``t``: without ``q0``, the initial state
        (:attr:`initial`); without ``qd0``, at rest. The disturbances' random stream goes on
        (a seeded wind replays from its start)."""
        if q0 is None:
            q0, qd0 = self.initial.q, self.initial.qd if qd0 is None else qd0
        q0 = np.array(q0, float)
        qd0 = np.zeros_like(q0) if qd0 is None else np.array(qd0, float)
        self.state = PlantState(float(t), q0, qd0)
        self.ok = True
        self.over_limit = None
        self.tumbled = False
        self._t0, self._k = float(t), 0  # t = t0 + k dt, without accumulated round-off
        if self.wind is not None:
            self.wind.reset()  # a seeded wind replays from its start
        return self.state

    def advance(self, u: np.ndarray, dt: float) -> PlantState:
        s = self.state
        loads = self._loads
        loads.packed()[:] = self._base
        for name, value in self.disturbances.loads_at(s.t, self.rng, self.system.floating).items():
            getattr(loads, name)[:] = value  # a view into the packed loads
        h = dt / self.substeps
        aero = self.aero
        if self.contact is not None and not self._far(s, dt):
            return self._advance_env(u, dt, loads)
        self.last_substeps = self.substeps
        u = np.asarray(u, float)
        m, packed = self.system.model_arrays, loads.packed()
        if aero is None:
            qs, qds, ok = rk4_run(s.q, s.qd, u, h, self.substeps, self.substeps, m, packed)
            accel = lambda q, qd: forward_dynamics(q, qd, u, m, packed)  # noqa: E731
        else:
            if self.wind is not None:
                set_wind(aero, self.wind.velocity(s.t))
            qs, qds, ok = rk4_run_aero(
                s.q, s.qd, u, h, self.substeps, self.substeps, m, packed, aero
            )
            accel = lambda q, qd: forward_dynamics_aero(q, qd, u, m, packed, aero)  # noqa: E731
        return self._end_period(qs[-1].copy(), qds[-1].copy(), ok, dt, accel)

    def _end_period(self, q, qd, ok, dt: float, accel) -> PlantState:
        """The state at the end of the period ``(q, qd)`` with the integrator's ``ok``: the
        health flags, the clock and, when asked, the accelerations ``accel(q, qd)``."""
        self.ok = bool(ok and np.all(np.isfinite(q)) and np.all(np.isfinite(qd)))
        self.tumbled = self.system.floating and max(abs(q[0]), abs(q[1])) > MAX_TILT_RAD
        self._k += 1
        qdd = None
        if self.accelerations and self.ok:
            qdd, ok_a = accel(q, qd)
            self.ok = bool(ok_a)
        self.state = PlantState(self._t0 + self._k * dt, q, qd, qdd)
        return self.state

    def _far(self, s: PlantState, dt: float) -> bool:
        """The arm's bounding sphere stays clear of every obstacle over the period."""
        if self.system.floating:
            c, v = s.q[3:6], float(np.linalg.norm(s.qd[3:6]))
        else:
            c, v = self.system.model_arrays.g_fixed[:3, 3], 0.0
        gap = clearance(self.contact, c[0], c[1], c[2]) - self._reach
        return gap > self.contact_margin + 2.0 * v * dt

    def _advance_env(self, u: np.ndarray, dt: float, loads: Loads) -> PlantState:
        """:meth:`advance` with contact (and the aerodynamics, if any): one kernel for both."""
        s = self.state
        m = self.system.model_arrays
        aero = np.empty(0) if self.aero is None else self.aero
        if self.aero is not None and self.wind is not None:
            set_wind(aero, self.wind.velocity(s.t))
        _, _, _, gap, speed = contact_nodes(s.q, s.qd, m, self.contact)
        near = gap < self.contact_margin + 2.0 * speed * dt
        n = self.contact_substeps if near else self.substeps
        self.last_substeps = n
        u = np.asarray(u, float)
        qs, qds, ok = rk4_run_env(s.q, s.qd, u, dt / n, n, n, m, loads.packed(), aero, self.contact)
        q, qd = qs[-1].copy(), qds[-1].copy()
        self._end_period(
            q, qd, ok, dt,
            lambda q, qd: forward_dynamics_env(q, qd, u, m, loads.packed(), aero, self.contact),
        )  # fmt: skip
        if self.force_limit is not None and self.ok:
            _, f, _, _, _ = contact_nodes(q, qd, m, self.contact)
            # on each arm (the rod's nodes and its tip sphere): the largest over the arms
            per = np.zeros((self._node_rod.max() + 1, 3))
            np.add.at(per, self._node_rod, f)
            total = float(np.max(np.linalg.norm(per, axis=1)))
            if total > self.force_limit:
                self.over_limit = (
                    f"contact force {total:.3f} N above the limit {self.force_limit:g} N "
                    f"at t = {self.state.t:.2f} s"
                )
        return self.state
