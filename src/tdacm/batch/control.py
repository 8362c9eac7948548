"""The low-level controller of one world as a compiled function over plain arrays.

:func:`controller_period` is :meth:`tdacm.loop.lowlevel.AdaptiveLowLevel.step` (that is,
:meth:`tdacm.control.TDACMController.step`) without Python objects: the estimated terms of
:meth:`tdacm.control.EstimatedModel.terms`, the adaptive sliding-mode law (paper eqs. S2-S10)
in the hierarchical drone loop (two passes with the roll/pitch command filter), the thrust
allocation through the rows ``[0, 1, 2, 5]`` of ``Gamma`` and the tendon allocation, and the
adaptation ``Delta_hat <- Delta_hat - A_a s_q dt``. Its inputs are a :class:`ControllerArrays`
and the model arrays of the controller's model (both built once from the Python block by
:func:`controller_arrays`, so the compiled controller is the block's twin and never a second
truth), the controller state (:func:`controller_state`), a scratch array
(:func:`controller_work`) and the estimate and reference of the period.

Per-world parameters: every array of :class:`ControllerArrays` may be stacked along a leading
world axis (the engine indexes it inside its ``prange`` loop), and so may the model's
stiffness, damping, step masses and drone inertia: numba builds a world's
:class:`~tdacm.system.kernels.ModelArrays` and :class:`ControllerArrays` from rows of the
stacks inside compiled code (:func:`tdacm.batch.plant.model_of_world`; tested in a
``prange`` loop); worlds that share a robot share the rest of the model arrays. The records
are flat (no NamedTuple inside a NamedTuple): numba's parallel loops refuse nested ones. A
world is one call with one world's rows: the function allocates only what the model kernels
it calls return (``coupled_terms``, ``tendon_matrix``, the tendon allocation's small
least-squares arrays) and two 3 x 3 temporaries with the rotor drag, so one world per GPU
thread is a translation.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._linalg import lu_factor, lu_solve_into
from ..control.adaptive import AdaptiveController, law_into
from ..control.allocation import _allocate_tensions_kernel
from ..control.hierarchical import TDACMController
from ..control.model import EstimatedModel
from ..lie.euler import rot_zyx
from ..loop.ablation import TruthAblation
from ..loop.lowlevel import AdaptiveLowLevel
from ..system.kernels import ModelArrays, coupled_terms, tendon_matrix

#: ``params`` of :class:`ControllerArrays`: tendon pretension target (N)
P_PRETENSION = 0
#: bound on the commanded roll and pitch (rad)
P_MAX_TILT = 1
#: the attitude filter's gain over one period, ``min(1, dt / max(attitude_filter, 1e-9))``
P_FILTER_GAIN = 2
#: the attitude command's largest step over one period, ``max_tilt_rate dt`` (rad)
P_TILT_STEP = 3
#: the smallest vertical force of the outer pass, ``min_lift`` times the weight (N)
P_MIN_LIFT_FORCE = 4
#: largest motor thrust (N)
P_MAX_THRUST = 5
#: largest tendon tension (N)
P_MAX_TENSION = 6
#: 1: the exact ZYX inversion of :func:`~tdacm.control.hierarchical.attitude_from_force`
P_EXACT_ATTITUDE = 7
#: 1: the estimated gravity load is fed forward in ``K_hat``
P_GRAVITY_FF = 8
#: 1: the model knows the drone's rotor drag (``P_ROTOR_DRAG_K``)
P_ROTOR_DRAG = 9
#: (3,) the model's rotor drag ``k_r_hat`` along the body axes (N s/m)
P_ROTOR_DRAG_K = 10
#: the control period the filter constants were computed for (s)
P_DT = 13
N_PARAMS = 14

#: rows of ``coord`` (per coordinate): ``sqrt(1 + d_m)`` (``M_hat = S_m M S_m``, ``C_hat``)
C_MASS_SCALE = 0
#: ``sqrt(1 + d_d)`` (``D_hat = S_d D S_d``)
C_DAMPING_SCALE = 1
#: ``1 + d_k`` (``K_hat = (1 + d_k) K``)
C_STIFFNESS_SCALE = 2
#: ``1 + d_g`` (the estimated gravity load ``(1 + d_g) tau_ext``)
C_GRAVITY_SCALE = 3
#: the gain ``beta`` (diagonal) of ``s_q = edot + beta e``
C_BETA = 4
N_COORD = 5

#: ``gains[G_AD]`` is ``A_d``, then ``A_p`` and ``A_a`` (each n x n)
G_AD, G_AP, G_AA = 0, 1, 2

# rows of the scratch array (controller_work)
_W_QD_REF, _W_QDD_REF, _W_E, _W_EDOT, _W_QD_R, _W_QDD_R, _W_S, _W_K = range(8)
N_WORK = 8


class ControllerArrays(NamedTuple):
    """The low-level controller of one world as arrays (:func:`controller_arrays`), besides
    the model arrays of its private gravity-only model (a
    :class:`~tdacm.system.kernels.ModelArrays`, passed apart: numba's parallel loops take no
    NamedTuple inside a NamedTuple).

    ``loads`` (27,): the private model's packed loads (gravity only); ``params``
    (:data:`N_PARAMS`,): the scalars, by the ``P_*`` indices; ``coord`` (:data:`N_COORD`, n):
    the model errors and ``beta``, by the ``C_*`` rows; ``damping`` (n, n): the constant
    ``D_hat = S_d D S_d``; ``gains`` (3, n, n): ``A_d, A_p, A_a`` by the ``G_*`` indices;
    ``g4_lu`` (4, 4) and ``g4_piv`` (4,): the LU factors of ``Gamma[[0, 1, 2, 5]]`` (identity
    for a fixed base). All may differ per world (a leading world axis); so may the model's
    stiffness, damping, step masses and ``mb6`` (:func:`tdacm.batch.plant.model_of_world`).
    """

    loads: np.ndarray
    params: np.ndarray
    coord: np.ndarray
    damping: np.ndarray
    gains: np.ndarray
    g4_lu: np.ndarray
    g4_piv: np.ndarray


#: the model arrays :func:`tendon_matrix` reads (B_s(q)): the controller computes the tendon
#: matrix on its model, which must have the true system's tendon geometry
_TENDON_FIELDS = ("bg", "xi0g", "wq", "g_col", "g_nc", "tendon_d", "tendon_dd", "tendon_on")


def controller_arrays(low_level, dt: float) -> tuple[ControllerArrays, ModelArrays]:
    """``(arrays, model)`` of the scenario's low-level block ``low_level``
    (``loop.controller``, an :class:`~tdacm.loop.lowlevel.AdaptiveLowLevel`) for the control
    period ``dt``: the :class:`ControllerArrays` and the model arrays of the controller's
    private gravity-only model (:class:`tdacm.control.EstimatedModel`).

    Refused (``ValueError`` naming the scenario key): a user controller or the PD law
    (``controller.class``) and the truth ablation (``estimation.controller_truth``)."""
    if isinstance(low_level, TruthAblation):
        raise ValueError(
            "estimation.controller_truth: the batched controller reads the estimate only "
            "(the truth ablation is a block-loop diagnostic)"
        )
    if type(low_level) is not AdaptiveLowLevel:
        raise ValueError(
            f"controller.class: the batched engine runs the adaptive controller only, got "
            f"{type(low_level).__module__}.{type(low_level).__qualname__}"
        )
    c = low_level.controller
    if type(c) is not TDACMController or type(c.law) is not AdaptiveController:
        raise ValueError(
            "controller.class: the batched engine runs the adaptive controller only "
            f"(law {type(c.law).__qualname__})"
        )
    if type(c.model) is not EstimatedModel:
        raise ValueError(f"controller.class: an unknown model {type(c.model).__qualname__}")
    dt = float(dt)
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt!r}")
    sysm, model, g = c.system, c.model, c.gains
    n = sysm.n
    p = np.zeros(N_PARAMS)
    p[P_PRETENSION] = c.pretension
    p[P_MAX_TILT] = c.max_tilt
    p[P_FILTER_GAIN] = min(1.0, dt / max(c.attitude_filter, 1e-9))
    p[P_TILT_STEP] = c.max_tilt_rate * dt
    p[P_MIN_LIFT_FORCE] = c.min_lift * c._weight
    p[P_EXACT_ATTITUDE] = float(c.exact_attitude)
    p[P_GRAVITY_FF] = float(model.gravity_feedforward)
    p[P_DT] = dt
    if sysm.floating:
        p[P_MAX_THRUST] = sysm.base.max_thrust
    if sysm.n_rods != 1:  # TDACMController.step reads system.tendons, a single-rod property
        raise ValueError(
            f"robot: the adaptive controller allocates the tendons of one rod, got {sysm.n_rods}"
        )
    p[P_MAX_TENSION] = sysm.tendons.max_tension
    if model.nominal_rotor_drag is not None:
        p[P_ROTOR_DRAG] = 1.0
        p[P_ROTOR_DRAG_K : P_ROTOR_DRAG_K + 3] = model.rotor_drag
    coord = np.empty((N_COORD, n))
    coord[C_MASS_SCALE] = model.mass_scale
    coord[C_DAMPING_SCALE] = model.damping_scale
    coord[C_STIFFNESS_SCALE] = 1.0 + model.d_k
    coord[C_GRAVITY_SCALE] = 1.0 + model.d_g
    coord[C_BETA] = g.beta
    mp = model.system.model_arrays
    ms = sysm.model_arrays
    if mp.floating != ms.floating or any(
        not np.array_equal(getattr(mp, f), getattr(ms, f)) for f in _TENDON_FIELDS
    ):
        raise ValueError("robot: the controller's model has another tendon geometry")
    sd = model.damping_scale
    damping = sd[:, None] * mp.damping * sd[None, :]  # as EstimatedModel.terms
    gains = np.ascontiguousarray(np.stack([g.A_d, g.A_p, g.A_a]), dtype=float)
    if sysm.floating:
        g4 = np.ascontiguousarray(np.asarray(sysm.base.gamma, float)[[0, 1, 2, 5]])
        lu, piv, ok = lu_factor(g4)
        if not ok:
            raise ValueError("robot.drone: the motor layout's Gamma rows [0, 1, 2, 5] are singular")
    else:
        lu, piv = np.eye(4), np.arange(4, dtype=np.int64)
    arrays = ControllerArrays(
        model.system.loads.packed().copy(),
        p,
        coord,
        np.ascontiguousarray(damping),
        gains,
        lu,
        piv,
    )
    return arrays, mp


def controller_state(n: int):
    """The controller state after a reset: ``(delta_hat (n,), att (2,), att_rate (2,),
    att_set (1,) bool)`` (``att`` is taken from ``q`` on the first period)."""
    return np.zeros(n), np.zeros(2), np.zeros(2), np.zeros(1, np.bool_)


def controller_work(n: int) -> np.ndarray:
    """The scratch array of :func:`controller_period` (:data:`N_WORK`, n)."""
    return np.zeros((N_WORK, n))


@njit(cache=True)
def attitude_from_force_nb(f0, f1, f2, psi_d, exact):
    """:func:`tdacm.control.hierarchical.attitude_from_force` on scalars: ``(F, phi_d,
    theta_d)``."""
    big_f = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if big_f < 1e-9:
        return 0.0, 0.0, 0.0
    c, s = np.cos(psi_d), np.sin(psi_d)
    a = f0 * c + f1 * s
    b = f0 * s - f1 * c
    if exact:
        return big_f, np.arcsin(min(max(b / big_f, -1.0), 1.0)), np.arctan2(a, f2)
    return big_f, np.arctan(b / big_f), np.arctan(a / big_f)


@njit(cache=True)
def _law_into(mh, cd, kh, q, qd, q_d, work, beta, a_d, a_p, delta_hat, tau):
    """The adaptive law (paper eqs. S2-S10) of :func:`tdacm.control.adaptive._law_kernel`,
    with ``cd = C_hat + D_hat``, in place: ``tau`` and the rows ``e, edot, s, qd_r, qdd_r``
    of ``work``; returns ``V`` without the ``Delta_tilde`` term."""
    n = q.shape[0]
    qd_d = work[_W_QD_REF]
    qdd_d = work[_W_QDD_REF]
    e = work[_W_E]
    edot = work[_W_EDOT]
    qd_r = work[_W_QD_R]
    qdd_r = work[_W_QDD_R]
    s = work[_W_S]
    for i in range(n):
        e[i] = q[i] - q_d[i]
        edot[i] = qd[i] - qd_d[i]
    return law_into(
        mh, cd, kh, e, edot, qd_d, qdd_d, beta, a_d, a_p, delta_hat, qd_r, qdd_r, s, tau
    )


@njit(cache=True)
def controller_period(
    ca, m, delta_hat, att, att_rate, att_set, q, qd, q_d, qd_d, qdd_d, dt, u, tau, q_ref, work
):
    """One period of the low-level controller of one world (module docstring):
    :meth:`tdacm.control.TDACMController.step` on the arrays ``ca`` (a
    :class:`ControllerArrays`) and the model arrays ``m`` of the controller's model (the
    estimated terms and the tendon matrix ``B_s(q)``; :func:`controller_arrays`).

    State (updated in place): ``delta_hat`` (n,), ``att`` (2,) and ``att_rate`` (2,) (the
    filtered roll/pitch command and its rate), ``att_set`` (1,) bool (``att`` holds a command;
    false after a reset). Inputs: the estimate ``q, qd`` and the reference ``q_d, qd_d,
    qdd_d`` (n,), the period ``dt`` (the one :func:`controller_arrays` was given). Outputs
    (written): ``u`` (n_u,) ``[thrusts (4), tensions]`` or the tensions, ``tau`` (n,) the
    law's ``tau_a`` and ``q_ref`` (n,) the reference it tracked; ``work`` is scratch
    (:func:`controller_work`). Returns ``(V, thrust_saturated, tension_saturated,
    thrust_total, tension_residual)``.

    Estimated terms (:class:`tdacm.control.EstimatedModel`): ``M_hat = S_m M S_m``,
    ``C_hat = S_m C S_m``, ``D_hat = S_d D S_d`` (plus ``R diag(k_r_hat) R^T`` on the drone's
    position rows when the model knows the rotor drag), ``K_hat = (1 + d_k) K`` minus
    ``(1 + d_g) tau_ext`` with the gravity feed-forward, of the model at ``(q, qd)`` (paper
    eq. (9)); the law ``tau_a = M_hat qdd_r + (C_hat + D_hat) qd_r + K_hat - A_d edot - A_p e
    + Delta_hat`` (eqs. S2-S10)."""
    p = ca.params
    n = q.shape[0]
    floating = m.floating
    off = 6 if floating else 0
    sm = ca.coord[C_MASS_SCALE]
    beta = ca.coord[C_BETA]
    a_d = ca.gains[G_AD]
    a_p = ca.gains[G_AP]
    a_a = ca.gains[G_AA]
    # the estimated terms, in the arrays the model kernel returned
    mh, cd, _, tau_ext, _, _, _ = coupled_terms(q, qd, m, ca.loads, bool(1))
    for i in range(n):
        for j in range(n):
            mh[i, j] = sm[i] * mh[i, j] * sm[j]
            cd[i, j] = sm[i] * cd[i, j] * sm[j]
    rotor = p[P_ROTOR_DRAG] != 0.0
    for i in range(n):
        for j in range(n):
            if not (rotor and 3 <= i < 6 and 3 <= j < 6):
                cd[i, j] = cd[i, j] + ca.damping[i, j]
    if rotor:  # C_hat + (D_hat + R diag(k_r_hat) R^T) on the drone's position rows
        rd = _rotor_damping(q, p)
        for i in range(3):
            for j in range(3):
                cd[3 + i, 3 + j] = cd[3 + i, 3 + j] + (ca.damping[3 + i, 3 + j] + rd[i, j])
    kh = work[_W_K]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += m.stiffness[i, j] * q[j]
        kh[i] = ca.coord[C_STIFFNESS_SCALE, i] * acc
        if p[P_GRAVITY_FF] != 0.0:
            kh[i] = kh[i] - ca.coord[C_GRAVITY_SCALE, i] * tau_ext[i]
    qd_ref = work[_W_QD_REF]
    qdd_ref = work[_W_QDD_REF]
    for i in range(n):
        q_ref[i] = q_d[i]
        qd_ref[i] = qd_d[i]
        qdd_ref[i] = qdd_d[i]
    thrust_total = 0.0
    thrust_sat = False
    if floating:
        if not att_set[0]:
            att[0] = q[0]
            att[1] = q[1]
            att_set[0] = True
        # outer pass: the attitude taken as tracked
        q_ref[0] = q[0]
        q_ref[1] = q[1]
        qd_ref[0] = qd[0]
        qd_ref[1] = qd[1]
        qdd_ref[0] = 0.0
        qdd_ref[1] = 0.0
        _law_into(mh, cd, kh, q, qd, q_ref, work, beta, a_d, a_p, delta_hat, tau)
        f2 = max(tau[5], p[P_MIN_LIFT_FORCE])
        _, phi_d, theta_d = attitude_from_force_nb(
            tau[3], tau[4], f2, q_ref[2], p[P_EXACT_ATTITUDE] != 0.0
        )
        mt = p[P_MAX_TILT]
        a = p[P_FILTER_GAIN]
        lim = p[P_TILT_STEP]
        raw0 = min(max(phi_d, -mt), mt)
        raw1 = min(max(theta_d, -mt), mt)
        st0 = min(max(a * (raw0 - att[0]), -lim), lim)
        st1 = min(max(a * (raw1 - att[1]), -lim), lim)
        att[0] = att[0] + st0
        att[1] = att[1] + st1
        att_rate[0] = st0 / dt
        att_rate[1] = st1 / dt
        # inner pass: the filtered roll/pitch command
        q_ref[0] = att[0]
        q_ref[1] = att[1]
        qd_ref[0] = att_rate[0]
        qd_ref[1] = att_rate[1]
        v = _law_into(mh, cd, kh, q, qd, q_ref, work, beta, a_d, a_p, delta_hat, tau)
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
        e4 = work[_W_E, :4]  # free again after the law
        e4[0] = t0
        e4[1] = tb1
        e4[2] = tb2
        e4[3] = thrust_total
        req = work[_W_EDOT, :4]
        lu_solve_into(ca.g4_lu, ca.g4_piv, e4, req)
        mx = p[P_MAX_THRUST]
        for k in range(4):
            f = min(max(req[k], 0.0), mx)
            if abs(f - req[k]) > 1e-9:
                thrust_sat = True
            u[k] = f
    else:
        v = _law_into(mh, cd, kh, q, qd, q_ref, work, beta, a_d, a_p, delta_hat, tau)
    # tendons: B_s(q) T = tau_s with 0 <= T <= T_max and the pretension
    b_s = tendon_matrix(q[off:], m)
    tau_s = tau[off:]
    tens, resid, at_max, at_zero = _allocate_tensions_kernel(
        b_s, tau_s, p[P_MAX_TENSION], p[P_PRETENSION], 1e-3
    )
    nrm = 0.0
    for i in range(tau_s.shape[0]):
        nrm += tau_s[i] * tau_s[i]
    scale = max(1.0, np.sqrt(nrm))
    tension_sat = (at_max or at_zero) and resid > 1e-6 * scale + 1e-9
    uo = 4 if floating else 0
    for k in range(tens.shape[0]):
        u[uo + k] = tens[k]
    # adaptation Delta_hat <- Delta_hat - A_a s dt (explicit Euler)
    s = work[_W_S]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += a_a[i, j] * s[j]
        delta_hat[i] = delta_hat[i] - acc * dt
    return v, thrust_sat, tension_sat, thrust_total, resid


@njit(cache=True)
def _rotor_damping(q, p):
    """``R diag(k_r_hat) R^T`` (3 x 3), the model's rotor drag on the drone's position rows
    (``R = Rz Ry Rx`` at the attitude of ``q``; :meth:`EstimatedModel.rotor_damping`)."""
    r = rot_zyx(q[0], q[1], q[2])
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for c in range(3):
                acc += r[i, c] * p[P_ROTOR_DRAG_K + c] * r[j, c]
            out[i, j] = acc
    return out
