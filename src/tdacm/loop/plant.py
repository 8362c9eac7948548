"""The plant block: the true coupled model (paper eq. (9)) under disturbances.

:class:`Plant` integrates ``M qdd + (C + D) qd + K = tau_ext + B u`` with the input held over
one control period (``substeps`` RK4 steps inside numba, :func:`tdacm.system.kernels.rk4_run_env`):
the loads (gravity and the ``[disturbances]``: the base wrench ``amplitude sin(2 pi f t)`` on a
drone, the downwash ``downwash + noise N(0, I3)`` on the rod), the wind of ``[wind]`` at the
period's start in the packed aerodynamics, the contact with the obstacles (more RK4 steps a
period near them, the force limit), the health flags and the clock ``t0 + k dt``.

The block's parameters are a :class:`PlantParams` record and its state besides ``(q, qd)`` a
:class:`PlantData`; :func:`plant_step` is its compiled step, which :class:`Plant` calls for
the block loop and the batched engine (:mod:`tdacm.batch`) for every world. Random numbers are
inputs: the caller owns the streams. A period reads 3 standard normals for the downwash noise
(when ``[disturbances]`` has a downwash) and, with Dryden turbulence, 5 per turbulence sample
due (:func:`~tdacm.aero.wind.wind_samples_due`: one per period after the first when the
turbulence is sampled every control period).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from ..aero import layout as AL
from ..aero.wind import (
    N_WIND_NORMALS,
    Wind,
    WindParams,
    WindState,
    wind_params,
    wind_samples_due,
    wind_velocity,
)
from ..contact import layout as CL
from ..contact.config import ContactConfig
from ..contact.geometry import clearance
from ..system.aero import check_aero
from ..system.contact import check_contact
from ..system.kernels import (
    LOAD_GRAVITY,
    LOAD_SLICES,
    contact_nodes,
    forward_dynamics_env,
    rk4_run_env,
)
from ..system.tdacm import TDACM, Loads
from .config import PLANT_SUBSTEPS, DisturbancesConfig
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
    base_wrench_frequency: float = DisturbancesConfig().base_wrench_frequency
    downwash: np.ndarray = field(default_factory=lambda: np.zeros(3))
    downwash_noise: float = DisturbancesConfig().downwash_noise

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

    @property
    def downwash_on(self) -> bool:
        return bool(np.any(self.downwash) or self.downwash_noise > 0)

    def wrench_on(self, floating: bool) -> bool:
        return bool(
            floating and np.any(self.base_wrench_amplitude) and self.base_wrench_frequency > 0
        )

    def loads_at(self, t: float, rng: np.random.Generator, floating: bool) -> dict:
        """``{load name: value}`` of the driven loads at time ``t`` (the downwash noise drawn
        from ``rng``; :func:`disturb`)."""
        p = plant_params(_Shape(floating), self)
        normals = rng.standard_normal(3) if self.downwash_on else np.zeros(3)
        loads = Loads()
        disturb(p, float(t), normals, loads.packed())
        out = {}
        if p.wrench_on:
            out["base_wrench"] = loads.base_wrench.copy()
        if p.downwash_on:
            out["rod_force"] = loads.rod_force.copy()
        return out


class _Shape:
    """What :func:`plant_params` reads of a system for the disturbances alone."""

    def __init__(self, floating: bool):
        self.floating = floating
        self.loads = Loads()


_BW = LOAD_SLICES["base_wrench"].start
_RF = LOAD_SLICES["rod_force"].start


class PlantParams(NamedTuple):
    """The plant's parameters (the record of :func:`plant_step`), besides the system's model
    arrays (a :class:`~tdacm.system.kernels.ModelArrays`, passed apart).

    ``loads`` (27,): the packed loads without the disturbances (gravity and the system's own
    loads). The disturbances: ``wrench_on``, ``wrench_amplitude`` (6,) ``[m; f]`` body frame,
    ``wrench_frequency`` (Hz); ``downwash_on``, ``downwash`` (3,) N/m and ``downwash_noise``.
    ``substeps``: RK4 steps a period. ``aero``: the packed aerodynamics (empty: none; each run
    integrates with its own copy, :attr:`PlantData.aero`, whose wind slot a period sets) and
    ``wind`` its :class:`~tdacm.aero.wind.WindParams` (``has_wind``). The contact: ``contact``
    the packed scene (empty: none), ``contact_substeps`` RK4 steps a period near an obstacle
    (``contact_margin`` m, plus twice the distance the fastest node travels), ``reach`` the
    radius of the arm's bounding sphere (m), ``force_limit`` (N; ``inf``: none) and
    ``node_rod`` the arm of every contact node. ``accelerations``: also compute ``qdd`` at the
    period's end (an IMU reads it)."""

    loads: np.ndarray
    wrench_on: bool
    wrench_amplitude: np.ndarray
    wrench_frequency: float
    downwash_on: bool
    downwash: np.ndarray
    downwash_noise: float
    substeps: int
    aero: np.ndarray
    has_wind: bool
    wind: WindParams
    contact: np.ndarray
    contact_substeps: int
    contact_margin: float
    reach: float
    force_limit: float
    node_rod: np.ndarray
    n_arms: int
    accelerations: bool


class PlantData(NamedTuple):
    """The plant's state besides ``(q, qd)``: the wind's (:class:`~tdacm.aero.wind.WindState`),
    the run's copy of the packed aerodynamics ``aero`` and the period's ``loads`` (27,)."""

    wind: WindState
    aero: np.ndarray
    loads: np.ndarray

    @classmethod
    def initial(cls, p: PlantParams) -> PlantData:
        return cls(WindState.initial(), p.aero.copy(), p.loads.copy())


def plant_params(system, disturbances: Disturbances | None = None,
                 substeps: int = PLANT_SUBSTEPS, aero=None, wind: Wind | None = None,
                 contact=None, contact_substeps: int = ContactConfig().contact_substeps,
                 contact_margin: float = ContactConfig().contact_margin,
                 force_limit: float | None = None,
                 accelerations: bool = False, reach: float = 0.0, node_rod=None) -> PlantParams:  # fmt: skip
    """The :class:`PlantParams` of a plant of ``system`` (module docstring)."""
    d = disturbances or Disturbances()
    floating = bool(system.floating)
    wp = wind_params(wind.parts()) if wind is not None else wind_params(())
    return PlantParams(
        loads=system.loads.packed().copy(),
        wrench_on=d.wrench_on(floating),
        wrench_amplitude=np.array(d.base_wrench_amplitude, float),
        wrench_frequency=float(d.base_wrench_frequency),
        downwash_on=d.downwash_on,
        downwash=np.array(d.downwash, float),
        downwash_noise=float(d.downwash_noise),
        substeps=int(substeps),
        aero=np.empty(0) if aero is None else np.array(aero, float),
        has_wind=wind is not None,
        wind=wp,
        contact=np.empty(0) if contact is None else np.array(contact, float),
        contact_substeps=int(contact_substeps),
        contact_margin=float(contact_margin),
        reach=float(reach),
        force_limit=np.inf if force_limit is None else float(force_limit),
        node_rod=np.zeros(0, np.int64) if node_rod is None else np.asarray(node_rod, np.int64),
        n_arms=len(getattr(system, "arms", ())) or 1,
        accelerations=bool(accelerations),
    )


@njit(cache=True)
def disturb(p, t, normals, loads):
    """The disturbances' loads at time ``t`` into the packed ``loads`` (the base wrench
    ``amplitude sin(2 pi f t)``, the downwash ``downwash + noise normals``)."""
    if p.wrench_on:
        sn = np.sin(2 * np.pi * p.wrench_frequency * t)
        for i in range(6):
            loads[_BW + i] = p.wrench_amplitude[i] * sn
    if p.downwash_on:
        for i in range(3):
            loads[_RF + i] = p.downwash[i] + p.downwash_noise * normals[i]


@njit(cache=True)
def _far(p, m, q, qd, dt):
    """The arm's bounding sphere stays clear of every obstacle over the period."""
    if m.floating:
        c0, c1, c2 = q[3], q[4], q[5]
        v = np.sqrt(qd[3] * qd[3] + qd[4] * qd[4] + qd[5] * qd[5])
    else:
        c0, c1, c2 = m.g_fixed[0, 3], m.g_fixed[1, 3], m.g_fixed[2, 3]
        v = 0.0
    gap = clearance(p.contact, c0, c1, c2) - p.reach
    return gap > p.contact_margin + 2.0 * v * dt


@njit(cache=True)
def plant_step(p, d, m, q, qd, u, dt, t0, k, dist_normals, wind_normals, q_out, qd_out, qdd_out):
    """One control period of the plant (module docstring) on its parameters ``p`` (a
    :class:`PlantParams`), its data ``d`` (a :class:`PlantData`, updated) and the system's
    model arrays ``m``, from ``(q, qd)`` at ``t = t0 + k dt`` under the input ``u`` held over
    the period; ``dist_normals`` (3,) the downwash noise's draws, ``wind_normals`` (rows, 5)
    the turbulence's. Writes the period's end state into ``q_out, qd_out`` (and its
    accelerations into ``qdd_out`` when ``p.accelerations``) and returns ``(ok, tumbled,
    substeps, contact_force)``: ``ok`` false when the integration failed (a singular mass
    matrix; the state is then the last good RK4 step's) or the state is not finite,
    ``tumbled`` when the drone's roll or pitch exceeds :data:`MAX_TILT_RAD`, the RK4 steps
    the period took and the largest contact force on an arm at its end (N; 0 without
    contact)."""
    t = t0 + k * dt
    for i in range(d.loads.shape[0]):
        d.loads[i] = p.loads[i]
    disturb(p, t, dist_normals, d.loads)
    if p.has_wind:
        wind_velocity(p.wind, d.wind, t, wind_normals, d.aero[AL.WIND : AL.WIND + 3])
    n = p.substeps
    env = p.contact.shape[0] > 0 and not _far(p, m, q, qd, dt)
    contact = p.contact if env else p.contact[:0]
    if env:  # near an obstacle: contact_substeps when a node may touch this period
        _, _, _, gap, speed = contact_nodes(q, qd, m, p.contact)
        if gap < p.contact_margin + 2.0 * speed * dt:
            n = p.contact_substeps
    qs, qds, ok = rk4_run_env(q, qd, u, dt / n, n, n, m, d.loads, d.aero, contact)
    last = qs.shape[0] - 1
    finite = True
    for i in range(q.shape[0]):
        q_out[i] = qs[last, i]
        qd_out[i] = qds[last, i]
        finite = finite and np.isfinite(q_out[i]) and np.isfinite(qd_out[i])
    ok = ok and finite
    tumbled = m.floating and max(abs(q_out[0]), abs(q_out[1])) > MAX_TILT_RAD
    if p.accelerations and ok:
        qdd, ok_a = forward_dynamics_env(q_out, qd_out, u, m, d.loads, d.aero, contact)
        if ok_a:
            for i in range(qdd.shape[0]):
                qdd_out[i] = qdd[i]
        ok = ok_a
    force = 0.0
    if env and ok and np.isfinite(p.force_limit):
        # on each arm (its rod's nodes and its tip sphere): the largest over the arms
        _, f, _, _, _ = contact_nodes(q_out, qd_out, m, p.contact)
        per = np.zeros((p.n_arms, 3))
        for j in range(f.shape[0]):
            for c in range(3):
                per[p.node_rod[j], c] += f[j, c]
        for a in range(p.n_arms):
            force = max(force, np.sqrt(per[a, 0] ** 2 + per[a, 1] ** 2 + per[a, 2] ** 2))
    return ok, tumbled, n, force


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
        substeps: int = PLANT_SUBSTEPS,
        disturbances: Disturbances | None = None,
        rng: np.random.Generator | None = None,
        aero: np.ndarray | None = None,
        wind: Wind | None = None,
        accelerations: bool = False,
        contact: np.ndarray | None = None,
        contact_substeps: int = ContactConfig().contact_substeps,
        contact_margin: float = ContactConfig().contact_margin,
        force_limit: float | None = None,
    ):
        if wind is not None and aero is None:
            raise ValueError("wind needs aero (the packed aerodynamics it acts through)")
        aero = None if aero is None else check_aero(system, aero).copy()
        contact = None if contact is None else check_contact(system, contact).copy()
        reach, node_rod = 0.0, None
        if contact is not None:
            m = system.model_arrays
            reach = max(
                np.linalg.norm(m.g_att[i][:3, 3]) + arm.length for i, arm in enumerate(system.arms)
            )
            # 5 % for the axial strains of a full basis
            reach = 1.05 * reach + max(contact[CL.TIP_RADIUS], float(
                np.max(contact[CL.N_HEADER : CL.N_HEADER + m.h.shape[0]])
            ))  # fmt: skip
            # the rod of every node of contact_nodes (its base, Gauss points and tip)
            node_rod = np.array([
                rod
                for rod in range(m.rod_steps.shape[0] - 1)
                for k in [-1, *range(m.rod_steps[rod], m.rod_steps[rod + 1])]
                if k < 0 or (m.step_w[k] != 0.0 and m.step_load[k] != LOAD_GRAVITY)
            ])  # fmt: skip
            probe = float(np.linalg.norm(contact[CL.PROBE : CL.PROBE + 3]))
            if probe > 0.0:  # the tip sphere on a rigid probe ahead of the tip
                reach += probe
        self.system = system
        self.disturbances = disturbances or Disturbances()
        #: the record of the compiled step (:func:`plant_step`)
        self.params = plant_params(
            system, self.disturbances, substeps, aero, wind, contact, contact_substeps,
            contact_margin, force_limit, accelerations, reach, node_rod,
        )  # fmt: skip
        self.wind = wind
        self.rng = rng if rng is not None else np.random.default_rng(0)
        #: the state the plant was built with, at t = 0: where :meth:`reset` without ``q0``
        #: starts
        self.initial = PlantState(0.0, np.array(q0, float), np.array(qd0, float))
        self.reset()

    @property
    def substeps(self) -> int:
        return self.params.substeps

    @property
    def aero(self) -> np.ndarray | None:
        """The packed aerodynamics (``None``: none)."""
        return self.params.aero if self.params.aero.size else None

    @property
    def contact(self) -> np.ndarray | None:
        """The packed contact scene (``None``: none)."""
        return self.params.contact if self.params.contact.size else None

    @property
    def force_limit(self) -> float | None:
        f = self.params.force_limit
        return None if not np.isfinite(f) else float(f)

    @property
    def accelerations(self) -> bool:
        return self.params.accelerations

    def reseed(self, rng: np.random.Generator, wind: Wind | None) -> None:
        """Draw the disturbances from ``rng`` and the turbulence from ``wind``'s generator
        (another seed's streams; the wind of the same kind as the plant's)."""
        self.rng = rng
        if (wind is None) != (self.wind is None):
            raise ValueError("reseed: the wind must be of the plant's kind")
        self.wind = wind
        if wind is not None:
            self.params = self.params._replace(wind=wind_params(wind.parts()))
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
        #: the number of RK4 steps of the last period
        self.last_substeps = self.params.substeps
        self._t0, self._k = float(t), 0  # t = t0 + k dt, without accumulated round-off
        self.data = PlantData.initial(self.params)
        if self.wind is not None:  # a seeded wind replays from its start; the plant advances
            self.wind.reset()  # the wind's own state
            self.data = self.data._replace(wind=self.wind.state)
        return self.state

    def advance(self, u: np.ndarray, dt: float) -> PlantState:
        """One period under ``u`` held over ``dt`` (:func:`plant_step`), the random draws from
        the plant's and the turbulence's generators."""
        s, p = self.state, self.params
        n = self.system.n
        dist = self.rng.standard_normal(3) if p.downwash_on else np.zeros(3)
        due = wind_samples_due(p.wind, self.data.wind, s.t) if p.has_wind else 0
        wind_n = self.wind.normals(due) if due else np.zeros((0, N_WIND_NORMALS))
        q, qd, qdd = np.empty(n), np.empty(n), np.empty(n)
        ok, tumbled, substeps, force = plant_step(
            p, self.data, self.system.model_arrays, s.q, s.qd, np.asarray(u, float), float(dt),
            self._t0, self._k, dist, wind_n, q, qd, qdd,
        )  # fmt: skip
        self.ok, self.tumbled = bool(ok), bool(tumbled)
        self.last_substeps = int(substeps)
        self._k += 1
        t = self._t0 + self._k * dt
        self.state = PlantState(t, q, qd, qdd if (p.accelerations and self.ok) else None)
        if self.ok and force > p.force_limit:
            self.over_limit = force_limit_reason(force, p.force_limit, t)
        return self.state


def force_limit_reason(force: float, limit: float, t: float) -> str:
    """Why a run ends with a contact force above its limit (``Termination.FORCE_LIMIT``)."""
    return f"contact force {force:.3f} N above the limit {limit:g} N at t = {t:.2f} s"
