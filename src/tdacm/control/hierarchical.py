"""The TD-ACM low-level controller: adaptive law + hierarchical drone loop + allocation.

Paper, "Adaptive Controller" (end): the drone's lateral motion is produced by tilting. Each
control step:

1. the adaptive law (:mod:`.adaptive`) gives the translational rows of ``tau_a`` for the
   reference ``q_d`` with the attitude taken as tracked (roll/pitch reference = current
   roll/pitch, so the outer loop does not react to inner-loop errors through the inertial
   coupling);
2. translational loop: ``F = |(tau_a4, tau_a5, tau_a6)|`` and (paper)
   ``theta_d = atan((tau_a4 cos psi_d + tau_a5 sin psi_d) / F)``,
   ``phi_d = atan((tau_a4 sin psi_d - tau_a5 cos psi_d) / F)``, clipped to ``max_tilt`` and
   smoothed by a first-order filter (time constant ``attitude_filter``) whose derivative is
   the roll/pitch reference rate;
3. attitude loop: the adaptive law is re-evaluated with the new roll/pitch reference; its
   rotational rows ``tau_a[0:3]`` (Euler-coordinate torques ``T^T tau_b``) give the body
   torque ``tau_b = T^-T tau_a[0:3]``;
4. allocation: thrust ``= F`` projected on the actual thrust axis ``R_b e_3``, motors through
   ``Gamma`` with saturation; tendon tensions ``>= 0`` from ``tau_a[6:]``
   (:mod:`.allocation`);
5. adaptation ``Delta_hat <- Delta_hat - A_a s_q dt``.

For a fixed base (ground tests) only steps 1, 4 (tendons) and 5 apply.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._linalg import solve as _solve
from ..lie.euler import euler_rate_matrix
from ..system.tdacm import TDACM
from .adaptive import AdaptiveController, AdaptiveGains
from .allocation import allocate_tensions, allocate_thrusts
from .config import LAW_DEFAULTS, ControlLawConfig
from .model import EstimatedModel


def attitude_from_force(force, psi_d: float, exact: bool = False):
    """``(F, phi_d, theta_d)`` from the desired inertial force (paper's formulas; with
    ``exact`` the ZYX inversion ``phi = asin(.)``, ``theta = atan2(., f_z)``)."""
    f = np.asarray(force, float)
    big_f = float(np.linalg.norm(f))
    if big_f < 1e-9:
        return 0.0, 0.0, 0.0
    c, s = np.cos(psi_d), np.sin(psi_d)
    a = f[0] * c + f[1] * s
    b = f[0] * s - f[1] * c
    if exact:
        phi = float(np.arcsin(np.clip(b / big_f, -1.0, 1.0)))
        theta = float(np.arctan2(a, f[2]))
        return big_f, phi, theta
    return big_f, float(np.arctan(b / big_f)), float(np.arctan(a / big_f))


def default_gains(system: TDACM, q=None, law: ControlLawConfig = LAW_DEFAULTS) -> AdaptiveGains:
    """Diagonal gains of the rates of ``law`` (:class:`~.config.ControlLawConfig`: ``beta``,
    damping and adaptation rates per coordinate group), scaled by the effective inertia of each
    coordinate at ``q`` (``1 / (M0^-1)_ii``, the inertia seen with the other coordinates
    free): the drone's roll/pitch and the rod strains are strongly coupled
    (``M_07 ~ 2 M_77``), and gains scaled by ``diag(M0)`` would be too high for the coupled
    modes at 50 Hz. ``A_p = A_d beta`` satisfies the gain condition for every ``eps > 1/2``.
    The horizontal damping rate is low because the horizontal velocity of a real drone is an
    estimate (3-5 mm/s RMS with the default pose sensor): a stiffer damping turns that noise
    into tilt commands that shake the camera (docs/control.md). On the sliding surface
    ``s_q = 0`` the same error's slow part ``b`` (below about 1 Hz, which the pose sensor
    cannot remove, :func:`tdacm.estimation.hover_estimate_limits`) leaves the drone
    ``b / beta`` away from its reference: the horizontal ``beta``
    (``horizontal_position_rate``, 1/s) trades that offset against the position noise fed to
    the tilt command."""
    q = np.zeros(system.n) if q is None else np.asarray(q, float)
    m = 1.0 / np.diag(np.linalg.inv(system.terms(q, np.zeros(system.n)).M))
    fl, ns = system.floating, system.n_s
    return AdaptiveGains.from_rates(
        m,
        law.rates("position", fl, ns),
        law.rates("damping", fl, ns),
        law.rates("adaptation", fl, ns),
    )


@dataclass(frozen=True)
class ControlStep:
    """Everything one low-level control step produced."""

    u: np.ndarray  # [thrusts (4), tensions (n_a)] or tensions
    tau: np.ndarray  # tau_a
    q_ref: np.ndarray  # reference used (roll/pitch from the translational loop)
    e: np.ndarray
    s: np.ndarray
    V: float
    thrust_total: float
    thrust_saturated: bool
    tension_saturated: bool
    tension_residual: float
    delta_hat: np.ndarray


class TDACMController:
    """Low-level controller of a TD-ACM (floating or fixed base); see module docstring.

    Parameters
    ----------
    system:
        The true system (structure, limits, ``Gamma``); the law uses ``model``.
    model:
        :class:`EstimatedModel` (default: 10 % perturbation, seed 0).
    gains:
        :class:`AdaptiveGains` (default :func:`default_gains`).
    law:
        The law's parameters (:class:`~.config.ControlLawConfig`: pretension, tilt limit and
        filter, minimum lift, the rates of the default gains, unused when ``gains`` is given).
    exact_attitude:
        Invert the attitude with the exact ZYX formulas instead of the paper's.
    """

    def __init__(
        self,
        system: TDACM,
        model: EstimatedModel | None = None,
        gains: AdaptiveGains | None = None,
        law: ControlLawConfig = LAW_DEFAULTS,
        exact_attitude: bool = False,
    ):
        self.system = system
        self.model = EstimatedModel(system) if model is None else model
        if gains is None:
            gains = default_gains(system, law=law)
        self.gains = gains
        self.config = law
        self.law = AdaptiveController(self.model, self.gains)
        self.pretension = float(law.pretension)
        self.max_tilt = float(law.max_tilt)
        self.attitude_filter = float(law.attitude_filter)
        self.exact_attitude = bool(exact_attitude)
        self.max_tilt_rate = float(law.max_tilt_rate)
        self.min_lift = float(law.min_lift)

        self._weight = float(system.total_mass * np.linalg.norm(system.loads.gravity))
        self.n = system.n
        self._att = None  # filtered roll/pitch command
        self._att_rate = np.zeros(2)

    @classmethod
    def from_config(cls, system, model, q_star, law: ControlLawConfig) -> TDACMController:
        """The scenario's controller: the gains of ``law`` at the desired configuration
        ``q_star`` (:func:`default_gains`) and the rest of ``law``."""
        return cls(system, model, default_gains(system, q_star, law), law)

    def reset(self, q=None):
        self.law.reset()
        self._att = None if q is None else np.asarray(q, float)[:2].copy()
        self._att_rate = np.zeros(2)

    def step(self, q, qd, q_d, qd_d, qdd_d, dt: float) -> ControlStep:
        sysm = self.system
        q = np.asarray(q, float)
        qd = np.asarray(qd, float)
        q_ref = np.asarray(q_d, float).copy()
        qd_ref = np.asarray(qd_d, float).copy()
        qdd_ref = np.asarray(qdd_d, float).copy()
        terms = self.model.terms(q, qd)
        thrust_total, thrust_sat = 0.0, False
        if sysm.floating:
            if self._att is None:
                self._att = q[:2].copy()
            # outer (translational) pass: the attitude is taken as tracked (zero roll/pitch
            # error), so the force does not react to the inner loop's errors through the
            # inertial coupling M_hat[3:6, 0:2] (that feedback chattered at 25 Hz)
            q_ref[:2] = q[:2]
            qd_ref[:2] = qd[:2]
            qdd_ref[:2] = 0.0
            out = self.law.law(q, qd, q_ref, qd_ref, qdd_ref, terms)
            force = out.tau[3:6].copy()
            force[2] = max(force[2], self.min_lift * self._weight)
            big_f, phi_d, theta_d = attitude_from_force(force, q_ref[2], self.exact_attitude)
            # min/max (and np.minimum/np.maximum below): np.clip's results, NaN included, at
            # a fraction of its call overhead (about 10 us a call)
            mt = self.max_tilt
            raw = np.array([min(max(phi_d, -mt), mt), min(max(theta_d, -mt), mt)])
            a = min(1.0, dt / max(self.attitude_filter, 1e-9))
            lim = self.max_tilt_rate * dt
            step = np.minimum(np.maximum(a * (raw - self._att), -lim), lim)
            new = self._att + step
            self._att_rate = step / dt
            self._att = new
            q_ref[:2] = self._att
            qd_ref[:2] = self._att_rate
            out = self.law.law(q, qd, q_ref, qd_ref, qdd_ref, terms)
            t_mat = euler_rate_matrix(q[0], q[1])
            torque_b = _solve(t_mat.T, out.tau[:3])
            r_b = sysm.base_pose(q)[:3, :3]
            thrust_total = max(0.0, float(out.tau[3:6] @ r_b[:, 2]))
            ta = allocate_thrusts(sysm.base.gamma, torque_b, thrust_total, sysm.base.max_thrust)
            thrusts, thrust_sat = ta.thrusts, ta.saturated
            tau_s = out.tau[6:]
        else:
            out = self.law.law(q, qd, q_ref, qd_ref, qdd_ref, terms)
            thrusts = np.zeros(0)
            tau_s = out.tau
        b_s = sysm.tendon_matrix(q)
        if sysm.n_rods == 1:
            tal = allocate_tensions(b_s, tau_s, sysm.tendons.max_tension, self.pretension)
            tensions, tension_sat, residual = tal.tensions, tal.saturated, tal.residual
        else:  # B_s is block-diagonal over the arms: one allocation per arm, its own T_max
            tensions, tension_sat, residual = _allocate_arms(sysm, b_s, tau_s, self.pretension)
        self.law.adapt(out.s, dt)
        u = np.concatenate((thrusts, tensions))
        return ControlStep(
            u,
            out.tau,
            q_ref,
            out.e,
            out.s,
            out.V,
            thrust_total,
            thrust_sat,
            tension_sat,
            residual,
            self.law.delta_hat.copy(),
        )


def _allocate_arms(system, b_s, tau_s, pretension: float):
    """``(tensions, saturated, residual)`` of a system with several arms: ``B_s`` (eq. (13))
    is block-diagonal (arm k's tendons act on arm k's strains only), so the bounded least
    squares splits into one :func:`allocate_tensions` per arm with that arm's ``T_max``;
    the residual is the norm over the arms."""
    q_off = system.n - system.n_s  # the drone's coordinates and thrusts come first
    u_off = system.n_u - system.n_a
    out, sat, res2 = [], False, 0.0
    for arm in system.arms:
        rows = slice(arm.strains.start - q_off, arm.strains.stop - q_off)
        cols = slice(arm.tensions.start - u_off, arm.tensions.stop - u_off)
        tal = allocate_tensions(b_s[rows, cols], tau_s[rows], arm.tendons.max_tension, pretension)
        out.append(tal.tensions)
        sat = sat or tal.saturated
        res2 += tal.residual**2
    return np.concatenate(out), sat, float(np.sqrt(res2))
