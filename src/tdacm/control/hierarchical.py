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

The block's parameters are a :class:`ControllerParams` record and its state a
:class:`ControllerState`; :func:`controller_step` is its compiled step (one world), which
:class:`TDACMController` calls and the batched engine (:mod:`tdacm.batch`) calls for every
world. The law is the adaptive one (:data:`LAW_ADAPTIVE`) or the PD + gravity law of
:mod:`.pd` (:data:`LAW_PD`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from .._linalg import lu_factor, lu_solve_into
from ..system.kernels import tendon_matrix
from ..system.tdacm import TDACM
from .adaptive import AdaptiveController, AdaptiveGains, law_into
from .allocation import allocate_tensions_kernel
from .config import LAW_DEFAULTS, ControlLawConfig
from .model import EstimatedModel, ModelParams, estimated_terms, model_params

#: the laws of :func:`controller_step`: the adaptive sliding-mode law (paper eqs. S2-S10) and
#: PD + gravity (:mod:`.pd`)
LAW_ADAPTIVE, LAW_PD = 0, 1


def attitude_from_force(force, psi_d: float, exact: bool = False):
    """``(F, phi_d, theta_d)`` from the desired inertial force (paper's formulas; with
    ``exact`` the ZYX inversion ``phi = asin(.)``, ``theta = atan2(., f_z)``;
    :func:`attitude_from_force_into`)."""
    f = np.asarray(force, float)
    big_f, phi, theta = attitude_from_force_into(
        float(f[0]), float(f[1]), float(f[2]), float(psi_d), bool(exact)
    )
    return float(big_f), float(phi), float(theta)


@njit(cache=True)
def attitude_from_force_into(f0, f1, f2, psi_d, exact):
    """The attitude of a desired inertial force ``(f0, f1, f2)`` (module docstring, step 2):
    ``(F, phi_d, theta_d)``, zeros for a vanishing force."""
    big_f = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if big_f < 1e-9:
        return 0.0, 0.0, 0.0
    c, s = np.cos(psi_d), np.sin(psi_d)
    a = f0 * c + f1 * s
    b = f0 * s - f1 * c
    if exact:
        return big_f, np.arcsin(min(max(b / big_f, -1.0), 1.0)), np.arctan2(a, f2)
    return big_f, np.arctan(b / big_f), np.arctan(a / big_f)


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


class ControllerParams(NamedTuple):
    """The low-level controller's parameters (the record of :func:`controller_step`), besides
    the model arrays of its private gravity-only model (a
    :class:`~tdacm.system.kernels.ModelArrays`, passed apart so that a batch of worlds shares
    it).

    ``model``: the estimated model's record (:class:`~.model.ModelParams`, its loads, scales,
    damping ``D_hat``, gravity feed-forward and rotor drag). The law (``law``: :data:`LAW_ADAPTIVE` or
    :data:`LAW_PD`): ``beta`` (n,), ``a_d``, ``a_p``, ``a_a`` (n, n). The drone loop:
    ``max_tilt`` (rad), ``attitude_filter`` (s), ``max_tilt_rate`` (rad/s), ``min_lift_force``
    (N, ``min_lift`` times the weight), ``exact_attitude``, ``max_thrust`` (N) and the LU
    factors ``g4_lu`` (4, 4), ``g4_piv`` (4,) of ``Gamma[[0, 1, 2, 5]]``. The tendons:
    ``pretension`` (N) and, per arm, ``max_tension`` (k,) and the rows of its strains in
    ``tau_s`` and columns of its tensions ``arm_rows``, ``arm_cols`` (k, 2) (``B_s`` is
    block-diagonal over the arms)."""

    law: int
    model: ModelParams
    beta: np.ndarray
    a_d: np.ndarray
    a_p: np.ndarray
    a_a: np.ndarray
    max_tilt: float
    attitude_filter: float
    max_tilt_rate: float
    min_lift_force: float
    exact_attitude: bool
    max_thrust: float
    g4_lu: np.ndarray
    g4_piv: np.ndarray
    pretension: float
    max_tension: np.ndarray
    arm_rows: np.ndarray
    arm_cols: np.ndarray


class ControllerState(NamedTuple):
    """The low-level controller's state: the adaptation's ``delta_hat`` (n,), the filtered
    roll/pitch command ``att`` (2,) and its rate ``att_rate`` (2,), and ``att_set`` (1,) bool
    (``att`` holds a command: false after a reset, it is then taken from ``q``)."""

    delta_hat: np.ndarray
    att: np.ndarray
    att_rate: np.ndarray
    att_set: np.ndarray

    @classmethod
    def initial(cls, n: int) -> ControllerState:
        return cls(np.zeros(n), np.zeros(2), np.zeros(2), np.zeros(1, np.bool_))


class ControllerWork(NamedTuple):
    """Scratch and outputs of :func:`controller_step` besides ``u``, ``tau``, ``q_ref``: the
    estimated terms ``m_hat``, ``cd_hat`` (``C_hat + D_hat``), ``d_hat`` (unused), ``k_hat``,
    the reference ``qd_ref``, ``qdd_ref``, the errors ``e``, ``edot``, the law's ``qd_r``,
    ``qdd_r`` and sliding variable ``s`` of the period, and four entries of thrust scratch."""

    m_hat: np.ndarray
    cd_hat: np.ndarray
    d_hat: np.ndarray
    k_hat: np.ndarray
    qd_ref: np.ndarray
    qdd_ref: np.ndarray
    e: np.ndarray
    edot: np.ndarray
    qd_r: np.ndarray
    qdd_r: np.ndarray
    s: np.ndarray
    thrust: np.ndarray

    @classmethod
    def empty(cls, n: int) -> ControllerWork:
        return cls(
            np.empty((n, n)), np.empty((n, n)), np.empty((0, 0)), np.empty(n), np.empty(n),
            np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n),
            np.empty(8),
        )  # fmt: skip


@njit(cache=True)
def _law(p, work, q, qd, q_ref, delta_hat, tau):
    """The law of ``p`` at ``(q, qdot)`` for the reference ``q_ref`` and ``work.qd_ref``,
    ``work.qdd_ref``: ``tau`` and the rows ``e, edot, s, qd_r, qdd_r`` of ``work``; returns
    ``V`` (without the ``Delta_tilde`` term)."""
    n = q.shape[0]
    e, edot = work.e, work.edot
    for i in range(n):
        e[i] = q[i] - q_ref[i]
        edot[i] = qd[i] - work.qd_ref[i]
    if p.law == LAW_PD:  # tau = K_hat + M_hat qdd_d - A_d edot - A_p e (:mod:`.pd`)
        v = 0.0
        for i in range(n):
            acc = work.k_hat[i]
            me = 0.0
            pe = 0.0
            for j in range(n):
                acc += work.m_hat[i, j] * work.qdd_ref[j]
                acc -= p.a_d[i, j] * edot[j] + p.a_p[i, j] * e[j]
                me += work.m_hat[i, j] * edot[j]
                pe += p.a_p[i, j] * e[j]
            tau[i] = acc
            work.s[i] = edot[i] + p.beta[i] * e[i]
            work.qd_r[i] = work.qd_ref[i]
            work.qdd_r[i] = work.qdd_ref[i]
            v += 0.5 * (edot[i] * me + e[i] * pe)
        return v
    return law_into(
        work.m_hat, work.cd_hat, work.k_hat, e, edot, work.qd_ref, work.qdd_ref, p.beta, p.a_d,
        p.a_p, delta_hat, work.qd_r, work.qdd_r, work.s, tau,
    )  # fmt: skip


@njit(cache=True)
def controller_step(p, st, m, q, qd, q_d, qd_d, qdd_d, dt, u, tau, q_ref, work):
    """One period of the low-level controller (module docstring) on its parameters ``p`` (a
    :class:`ControllerParams`), its state ``st`` (a :class:`ControllerState`, updated) and the
    model arrays ``m`` of its private model: the estimated terms at the estimate ``(q, qd)``
    (:func:`~.model.estimated_terms`), the law for the reference ``(q_d, qd_d, qdd_d)`` in the
    two passes of the drone loop, the allocation and the adaptation over ``dt``. Writes ``u``
    (n_u,) ``[thrusts (4), tensions]`` or the tensions, ``tau`` (n,) ``tau_a`` and ``q_ref``
    (n,) the reference the law tracked; ``work`` a :class:`ControllerWork` (its ``e``, ``s``
    are the period's). Returns ``(V, thrust_saturated, tension_saturated, thrust_total,
    tension_residual)``."""
    n = q.shape[0]
    floating = m.floating
    off = 6 if floating else 0
    mp = p.model
    estimated_terms(q, qd, m, mp.loads, mp.mass_scale, mp.damping, mp.stiffness_scale,
                    mp.gravity_scale, mp.gravity_feedforward, mp.rotor_drag, mp.rotor_drag_k,
                    True, work.m_hat, work.cd_hat, work.d_hat, work.k_hat)  # fmt: skip
    qd_ref, qdd_ref = work.qd_ref, work.qdd_ref
    for i in range(n):
        q_ref[i] = q_d[i]
        qd_ref[i] = qd_d[i]
        qdd_ref[i] = qdd_d[i]
    thrust_total = 0.0
    thrust_sat = False
    if floating:
        if not st.att_set[0]:
            st.att[0] = q[0]
            st.att[1] = q[1]
            st.att_set[0] = True
        # outer (translational) pass: the attitude is taken as tracked (zero roll/pitch
        # error), so the force does not react to the inner loop's errors through the
        # inertial coupling M_hat[3:6, 0:2] (that feedback chattered at 25 Hz)
        q_ref[0] = q[0]
        q_ref[1] = q[1]
        qd_ref[0] = qd[0]
        qd_ref[1] = qd[1]
        qdd_ref[0] = 0.0
        qdd_ref[1] = 0.0
        _law(p, work, q, qd, q_ref, st.delta_hat, tau)
        f2 = max(tau[5], p.min_lift_force)
        _, phi_d, theta_d = attitude_from_force_into(tau[3], tau[4], f2, q_ref[2],
                                                      p.exact_attitude)  # fmt: skip
        # the command clipped to max_tilt, then a first-order filter of time constant
        # attitude_filter whose step is bounded by max_tilt_rate dt
        mt = p.max_tilt
        a = min(1.0, dt / max(p.attitude_filter, 1e-9))
        lim = p.max_tilt_rate * dt
        raw0 = min(max(phi_d, -mt), mt)
        raw1 = min(max(theta_d, -mt), mt)
        st0 = min(max(a * (raw0 - st.att[0]), -lim), lim)
        st1 = min(max(a * (raw1 - st.att[1]), -lim), lim)
        st.att[0] = st.att[0] + st0
        st.att[1] = st.att[1] + st1
        st.att_rate[0] = st0 / dt
        st.att_rate[1] = st1 / dt
        # inner (attitude) pass: the filtered roll/pitch command
        q_ref[0] = st.att[0]
        q_ref[1] = st.att[1]
        qd_ref[0] = st.att_rate[0]
        qd_ref[1] = st.att_rate[1]
        v = _law(p, work, q, qd, q_ref, st.delta_hat, tau)
        # body torque tau_b = T^-T tau_a[0:3] (T of paper eq. (4), upper triangular form)
        cf, sf = np.cos(q[0]), np.sin(q[0])
        ct, stt = np.cos(q[1]), np.sin(q[1])
        t0 = tau[0]
        r = (tau[2] + stt * t0) / ct
        tb1 = cf * tau[1] + sf * r
        tb2 = -sf * tau[1] + cf * r
        # thrust along the actual thrust axis R_b e_3 (third column of Rz Ry Rx)
        cp, sp = np.cos(q[2]), np.sin(q[2])
        z0 = cp * stt * cf + sp * sf
        z1 = sp * stt * cf - cp * sf
        z2 = ct * cf
        thrust_total = max(0.0, tau[3] * z0 + tau[4] * z1 + tau[5] * z2)
        # motors through Gamma[[0, 1, 2, 5]], clipped to [0, max_thrust]
        rhs = work.thrust[:4]
        req = work.thrust[4:]
        rhs[0] = t0
        rhs[1] = tb1
        rhs[2] = tb2
        rhs[3] = thrust_total
        lu_solve_into(p.g4_lu, p.g4_piv, rhs, req)
        for k in range(4):
            f = min(max(req[k], 0.0), p.max_thrust)
            if abs(f - req[k]) > 1e-9:
                thrust_sat = True
            u[k] = f
    else:
        v = _law(p, work, q, qd, q_ref, st.delta_hat, tau)
    # tendons: B_s(q) T = tau_s with 0 <= T <= T_max and the pretension, arm by arm (B_s is
    # block-diagonal over the arms: arm k's tendons act on arm k's strains only)
    b_s = tendon_matrix(q[off:], m)
    uo = 4 if floating else 0
    tension_sat = False
    res2 = 0.0
    residual = 0.0
    for k in range(p.arm_rows.shape[0]):
        r0, r1 = p.arm_rows[k, 0], p.arm_rows[k, 1]
        c0, c1 = p.arm_cols[k, 0], p.arm_cols[k, 1]
        tau_k = tau[off + r0 : off + r1]
        tens, resid, at_max, at_zero = allocate_tensions_kernel(
            np.ascontiguousarray(b_s[r0:r1, c0:c1]), tau_k, p.max_tension[k], p.pretension, 1e-3
        )
        nrm = 0.0
        for i in range(tau_k.shape[0]):
            nrm += tau_k[i] * tau_k[i]
        scale = max(1.0, np.sqrt(nrm))
        if (at_max or at_zero) and resid > 1e-6 * scale + 1e-9:
            tension_sat = True
        for j in range(tens.shape[0]):
            u[uo + c0 + j] = tens[j]
        res2 += resid * resid
        residual = resid
    if p.arm_rows.shape[0] > 1:  # the norm over the arms
        residual = np.sqrt(res2)
    # adaptation Delta_hat <- Delta_hat - A_a s dt (explicit Euler; none for PD + gravity)
    if p.law == LAW_ADAPTIVE:
        s = work.s
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += p.a_a[i, j] * s[j]
            st.delta_hat[i] = st.delta_hat[i] - acc * dt
    return v, thrust_sat, tension_sat, thrust_total, residual


def controller_params(
    system: TDACM, model: EstimatedModel, gains: AdaptiveGains, law: ControlLawConfig,
    exact_attitude: bool = False, kind: int = LAW_ADAPTIVE,
) -> ControllerParams:  # fmt: skip
    """The :class:`ControllerParams` of the controller of ``system`` on ``model`` with
    ``gains`` and the law's parameters ``law`` (checked: ``ValueError`` naming what is
    wrong)."""
    if kind not in (LAW_ADAPTIVE, LAW_PD):
        raise ValueError(f"kind must be LAW_ADAPTIVE or LAW_PD, got {kind!r}")
    mp = model.system.model_arrays
    ms = system.model_arrays
    if mp.floating != ms.floating or any(
        not np.array_equal(getattr(mp, f), getattr(ms, f)) for f in _TENDON_FIELDS
    ):
        raise ValueError("robot: the controller's model has another tendon geometry")
    weight = float(system.total_mass * np.linalg.norm(system.loads.gravity))
    if system.floating:
        g4 = np.ascontiguousarray(np.asarray(system.base.gamma, float)[[0, 1, 2, 5]])
        lu, piv, ok = lu_factor(g4)
        if not ok:
            raise ValueError("robot.drone: the motor layout's Gamma rows [0, 1, 2, 5] are singular")
        max_thrust = float(system.base.max_thrust)
    else:
        lu, piv, max_thrust = np.eye(4), np.arange(4, dtype=np.int64), 0.0
    q_off = system.n - system.n_s  # the drone's coordinates and thrusts come first
    u_off = system.n_u - system.n_a
    rows = [(a.strains.start - q_off, a.strains.stop - q_off) for a in system.arms]
    cols = [(a.tensions.start - u_off, a.tensions.stop - u_off) for a in system.arms]
    c = np.ascontiguousarray
    return ControllerParams(
        law=int(kind),
        model=model_params(model),
        beta=c(gains.beta, float),
        a_d=c(gains.A_d, float),
        a_p=c(gains.A_p, float),
        a_a=c(gains.A_a, float),
        max_tilt=float(law.max_tilt),
        attitude_filter=float(law.attitude_filter),
        max_tilt_rate=float(law.max_tilt_rate),
        min_lift_force=float(law.min_lift) * weight,
        exact_attitude=bool(exact_attitude),
        max_thrust=max_thrust,
        g4_lu=c(lu),
        g4_piv=c(piv, np.int64),
        pretension=float(law.pretension),
        max_tension=np.array([a.tendons.max_tension for a in system.arms], float),
        arm_rows=np.array(rows, np.int64).reshape(-1, 2),
        arm_cols=np.array(cols, np.int64).reshape(-1, 2),
    )


#: the model arrays ``B_s(q)`` reads: the controller computes the tendon matrix on its model,
#: which must have the true system's tendon geometry
_TENDON_FIELDS = ("bg", "xi0g", "wq", "g_col", "g_nc", "tendon_d", "tendon_dd", "tendon_on")


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
    kind:
        The law: :data:`LAW_ADAPTIVE` (the paper's) or :data:`LAW_PD` (PD + gravity).
    """

    def __init__(
        self,
        system: TDACM,
        model: EstimatedModel | None = None,
        gains: AdaptiveGains | None = None,
        law: ControlLawConfig = LAW_DEFAULTS,
        exact_attitude: bool = False,
        kind: int = LAW_ADAPTIVE,
    ):
        self.system = system
        self.model = EstimatedModel(system) if model is None else model
        if gains is None:
            gains = default_gains(system, law=law)
        self.gains = gains
        self.config = law
        # the law's own object (its lyapunov(), its gains' checks); the step is compiled
        self.law = AdaptiveController(self.model, self.gains)
        self.n = system.n
        self.params = controller_params(system, self.model, gains, law, exact_attitude, kind)
        self._revision = self.model.revision
        self.state = ControllerState.initial(self.n)
        self._work = ControllerWork.empty(self.n)

    @classmethod
    def from_config(cls, system, model, q_star, law: ControlLawConfig, kind: int = LAW_ADAPTIVE):
        """The scenario's controller: the gains of ``law`` at the desired configuration
        ``q_star`` (:func:`default_gains`) and the rest of ``law``."""
        return cls(system, model, default_gains(system, q_star, law), law, kind=kind)

    @property
    def exact_attitude(self) -> bool:
        return self.params.exact_attitude

    @exact_attitude.setter
    def exact_attitude(self, value: bool) -> None:
        self.params = self.params._replace(exact_attitude=bool(value))

    @property
    def pretension(self) -> float:
        return self.params.pretension

    @property
    def delta_hat(self) -> np.ndarray:
        return self.state.delta_hat

    def _renew(self) -> None:
        """Take the model's current parameter errors (after ``model.reseed``) into the
        parameters."""
        self.params = controller_params(
            self.system, self.model, self.gains, self.config, self.exact_attitude, self.params.law
        )
        self._revision = self.model.revision

    def reset(self, q=None):
        self.state = ControllerState.initial(self.n)
        if q is not None and self.system.floating:
            self.state.att[:] = np.asarray(q, float)[:2]
            self.state.att_set[0] = True

    def step(self, q, qd, q_d, qd_d, qdd_d, dt: float) -> ControlStep:
        """One period (:func:`controller_step`)."""
        if self._revision != self.model.revision:
            self._renew()
        c = np.ascontiguousarray
        q, qd = c(q, dtype=float), c(qd, dtype=float)
        n = self.n
        u = np.empty(self.system.n_u)
        tau = np.empty(n)
        q_ref = np.empty(n)
        w = self._work
        v, thrust_sat, tension_sat, total, residual = controller_step(
            self.params, self.state, self.model.system.model_arrays, q, qd, c(q_d, dtype=float),
            c(qd_d, dtype=float), c(qdd_d, dtype=float), float(dt), u, tau, q_ref, w,
        )  # fmt: skip
        return ControlStep(
            u, tau, q_ref, w.e.copy(), w.s.copy(), float(v), float(total), bool(thrust_sat),
            bool(tension_sat), float(residual), self.state.delta_hat.copy(),
        )  # fmt: skip
