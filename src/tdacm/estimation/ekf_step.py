"""The EKF's compiled step: its records and one period of the filter for one world.

:class:`~tdacm.estimation.ekf.ExtendedKalmanFilter` (the Python block) validates its set-up
once into an :class:`EkfParams` record, keeps an :class:`EkfState` record and calls
:func:`ekf_step` every period; the batched engine holds one state per world and calls the
same function. The filter's model, measurements and latency handling are those of the module
:mod:`tdacm.estimation.ekf` (its docstring has the equations); here they are written once, as
compiled code over records, arrays and scalars.

The history of ticks is a ring of ``window`` fixed slots (:class:`EkfState`): per tick its time,
posterior ``x``, ``P``, the input held over the period before it, the transition ``Phi``, the
process noise ``Q`` and the Jacobian ``d qdd / d[q, qd]`` of its prediction, and up to
``slots`` measurements attached to it (kind, capture time, data). The prior of a tick is not
kept: the filter reads it only while it fuses the tick's measurements (a re-run recomputes it
from the previous posterior with the stored ``Phi`` and ``Q``).

A measurement is a row of an :class:`EkfMeasurements` record: its kind (:data:`ENCODERS`,
:data:`POSE`, :data:`IMU`, :data:`VIEW`, the order in which a tick fuses them), its capture
time and its data (:func:`measurement_size` entries):

* encoders: the tendon-length changes ``dl`` (n_a);
* pose: the position (3) and the rotation matrix row by row (9);
* IMU: the gyro (3) and the specific force (3);
* view: the target's normalized points ``(k, 2)`` row by row (2k).

:func:`ekf_step` returns a status: :data:`OK`, a divergence (:data:`MASS_NOT_PD`,
:data:`SINGULAR`, :data:`NONFINITE_INNOVATION`, :data:`NONFINITE_STATE`: the run's outcome,
:data:`DIVERGENCE` has the words) or a call it refuses before changing anything
(:data:`TIME_BACKWARDS`, :data:`NO_INPUT`, :data:`NO_RESET`, :data:`WINDOW_FULL`,
:data:`TICK_FULL`: the window or a tick's slots are too small; :func:`window_ticks` sizes a
window for a period).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..lie.euler import euler_rate_matrix, euler_zyx, rot_zyx
from ..lie.se3 import so3_exp_and_left_jacobian, so3_log
from ..system.kernels import chain_jacobian
from . import kernels as EK
from .camera import pose_from_view, view_model
from .inversion import strains_gauss_newton

#: measurement kinds, in the order a tick fuses them
ENCODERS, POSE, IMU, VIEW = 0, 1, 2, 3

#: :func:`ekf_step` outcomes
OK = 0
MASS_NOT_PD = 1
SINGULAR = 2
NONFINITE_INNOVATION = 3
NONFINITE_STATE = 4
TIME_BACKWARDS = 5
NO_INPUT = 6
NO_RESET = 7
WINDOW_FULL = 8
TICK_FULL = 9

#: the failure of a diverged filter in words (the run's termination reason)
DIVERGENCE = {
    MASS_NOT_PD: "estimator: the model's mass matrix is not positive definite",
    SINGULAR: "estimator diverged (singular innovation covariance: Matrix is singular to "
    "machine precision.)",
    NONFINITE_INNOVATION: "estimator diverged (singular innovation covariance: Array must "
    "not contain infs or NaNs.)",
    NONFINITE_STATE: "estimator diverged (non-finite state)",
}

#: two times closer than this are the same tick (s)
_T_EPS = 1e-9


class EkfParams(NamedTuple):
    """The filter's parameters (built once by the Python block, :mod:`tdacm.estimation.ekf`).

    Sizes: ``n`` coordinates (``n_s`` strains), ``n_a`` tendons, ``n_u`` inputs, ``nx`` states;
    ``floating`` (a drone: pose and IMU states and measurements), ``camera`` (the target's
    pose states ``[p_T, theta]`` start at ``i_target``). Process model: ``rk4_steps``, the
    packed gravity-only ``loads`` and ``gravity`` of the controller's private model, its
    perturbation ``mass_scale`` ``S_M``, ``damping_scale`` ``S_D``, ``stiffness_scale``
    ``1 + d_K``, ``gravity_scale`` ``1 + d_g`` (n,), ``rotor_drag`` ``k_r_hat`` (3,, zeros:
    none), ``skip`` (n,) the coordinates the dynamics do not depend on (the drone's position),
    ``qc`` the continuous process noise (nx, nx), ``model_error_fraction``. ``p0`` the default
    initial covariance (nx, nx). Measurements: ``l_ref`` the tendon lengths at the encoders'
    zero, the noise covariances ``r_encoders`` (n_a, n_a), ``r_pose`` (6, 6), ``r_imu`` (6, 6)
    and ``r_gyro`` (3, 3, without the accelerometer: the first tick); ``max_delay`` (s) of
    kept history. The tip camera (zero-sized without one): ``tip_mount`` ``g_{C_L}^L``,
    ``ad_mount_inv`` its inverse adjoint, the target's ``object_points`` (k, 3), their
    ``canonical_points`` (k, 2) and ``canonical_inv`` (the target-to-canonical transform of
    :func:`tdacm.vision.ippe.canonical_frame`), ``r_view`` (2k, 2k), ``gate`` (chi-square),
    ``reinit_after`` (s), ``level_normal`` (3,) and ``p_target`` (6, 6) the target's prior."""

    n: int
    n_s: int
    n_a: int
    n_u: int
    nx: int
    floating: bool
    camera: bool
    i_target: int
    rk4_steps: int
    loads: np.ndarray
    gravity: np.ndarray
    mass_scale: np.ndarray
    damping_scale: np.ndarray
    stiffness_scale: np.ndarray
    gravity_scale: np.ndarray
    rotor_drag: np.ndarray
    skip: np.ndarray
    qc: np.ndarray
    model_error_fraction: float
    p0: np.ndarray
    l_ref: np.ndarray
    r_encoders: np.ndarray
    r_pose: np.ndarray
    r_imu: np.ndarray
    r_gyro: np.ndarray
    max_delay: float
    tip_mount: np.ndarray
    ad_mount_inv: np.ndarray
    object_points: np.ndarray
    canonical_points: np.ndarray
    canonical_inv: np.ndarray
    r_view: np.ndarray
    gate: float
    reinit_after: float
    level_normal: np.ndarray
    p_target: np.ndarray


class EkfState(NamedTuple):
    """The filter's state: a ring of ``window`` ticks (module docstring), the oldest kept at
    slot ``head`` and ``kept`` of them (one-element arrays). Per tick: ``t``, the
    posterior ``x`` (nx,) and ``p`` (nx, nx), the input ``u`` (n_u,) held before it and
    ``has_u`` (False at the reset tick), ``phi``, ``qn`` (nx, nx) and ``jac`` (n, 2n) of its
    prediction, and its measurements ``m_kind``, ``m_t`` (slots,), ``m_data`` (slots, size),
    ``m_count``. The target: its ``anchor`` rotation ``R_A`` and ``has_anchor``, ``view_ok_t``
    the capture time of the last fused view, ``last_view`` that of the last view given to the
    filter. Counters: ``dropped_late`` (measurements older than the history), ``views_fused``
    and ``views_rejected`` (re-runs count again), ``target_restarts``."""

    t: np.ndarray
    x: np.ndarray
    p: np.ndarray
    u: np.ndarray
    has_u: np.ndarray
    phi: np.ndarray
    qn: np.ndarray
    jac: np.ndarray
    m_kind: np.ndarray
    m_t: np.ndarray
    m_data: np.ndarray
    m_count: np.ndarray
    head: np.ndarray
    kept: np.ndarray
    anchor: np.ndarray
    has_anchor: np.ndarray
    view_ok_t: np.ndarray
    last_view: np.ndarray
    dropped_late: np.ndarray
    views_fused: np.ndarray
    views_rejected: np.ndarray
    target_restarts: np.ndarray

    @classmethod
    def empty(cls, p: EkfParams, window: int, slots: int) -> EkfState:
        """A state of ``window`` ticks of ``slots`` measurements each, no tick kept (the
        filter starts with :func:`ekf_reset`)."""
        w, s, nx, n = int(window), int(slots), p.nx, p.n
        if w < 2 or s < 1:
            raise ValueError(f"window must be >= 2 and slots >= 1, got {w}, {s}")
        one = lambda dtype=float: np.zeros(1, dtype)  # noqa: E731
        return cls(
            np.zeros(w), np.zeros((w, nx)), np.zeros((w, nx, nx)), np.zeros((w, p.n_u)),
            np.zeros(w, np.bool_), np.zeros((w, nx, nx)), np.zeros((w, nx, nx)),
            np.zeros((w, n, 2 * n)), np.zeros((w, s), np.int64), np.zeros((w, s)),
            np.zeros((w, s, measurement_size(p))), np.zeros(w, np.int64), one(np.int64),
            one(np.int64), np.zeros((3, 3)), one(np.bool_), np.full(1, -np.inf),
            np.full(1, -np.inf), one(np.int64), one(np.int64), one(np.int64), one(np.int64),
        )  # fmt: skip

    @property
    def window(self) -> int:
        return self.t.shape[0]

    @property
    def slots(self) -> int:
        return self.m_kind.shape[1]


class EkfMeasurements(NamedTuple):
    """The measurements given to one :func:`ekf_step`: the first ``rows[0]`` rows of
    ``kind``, ``t`` (capture times) and ``data`` (module docstring)."""

    kind: np.ndarray
    t: np.ndarray
    data: np.ndarray
    rows: np.ndarray

    @classmethod
    def empty(cls, p: EkfParams, capacity: int) -> EkfMeasurements:
        c = int(capacity)
        return cls(
            np.zeros(c, np.int64), np.zeros(c), np.zeros((c, measurement_size(p))),
            np.zeros(1, np.int64),
        )  # fmt: skip


def measurement_size(p: EkfParams) -> int:
    """Entries of a measurement's data row (module docstring)."""
    return max(12, p.n_a, 2 * p.object_points.shape[0])


def window_ticks(max_delay: float, period: float) -> int:
    """Ticks the window needs for a filter stepped every ``period`` s that keeps ``max_delay``
    s of history: the ticks of ``max_delay``, one before them, the new one and one for the
    rounding of the tick times."""
    return int(math.ceil(max_delay / period - 1e-9)) + 3


# ----------------------------------------------------------------------------- helpers
@njit(cache=True)
def _slot(st, i):
    """Ring slot of the ``i``-th kept tick (0: the oldest)."""
    return (st.head[0] + i) % st.t.shape[0]


@njit(cache=True)
def _qdd(p, m, x, u):
    """``f_hat(q, qd, u) + a_d`` at the state ``x`` (:func:`~.kernels.model_qdd`)."""
    n = p.n
    return EK.model_qdd(
        x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], m, p.loads, p.mass_scale, p.damping_scale,
        p.stiffness_scale, p.gravity_scale, p.rotor_drag,
    )  # fmt: skip


@njit(cache=True)
def model_acceleration(p, m, x, u):
    """The filter model's ``qdd`` at the state ``x`` under ``u`` and whether its mass matrix
    is positive definite (the process model of :mod:`tdacm.estimation.ekf`)."""
    return _qdd(p, m, x, u)


@njit(cache=True)
def _propagate(p, m, x, u, dt):
    """The prior mean: ``x`` with ``[q, qd]`` propagated over ``dt`` by RK4 under ``u``."""
    n = p.n
    q1, qd1, ok = EK.propagate_mean(
        x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], dt, p.rk4_steps, m, p.loads, p.mass_scale,
        p.damping_scale, p.stiffness_scale, p.gravity_scale, p.rotor_drag,
    )  # fmt: skip
    xp = x.copy()
    xp[:n] = q1
    xp[n : 2 * n] = qd1
    return xp, ok


@njit(cache=True)
def _predict(p, st, m, prev, s, t, u):
    """Tick ``s`` at ``t`` from the posterior of tick ``prev`` under ``u``: its input, ``Phi``,
    ``Q`` and Jacobian, and its prior in ``x[s]``, ``p[s]``. False: the model's mass matrix
    is not positive definite."""
    n, nx = p.n, p.nx
    dt = t - st.t[prev]
    x = st.x[prev]
    a0, jac, ok = EK.linearize(
        x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], m, p.loads, p.mass_scale, p.damping_scale,
        p.stiffness_scale, p.gravity_scale, p.rotor_drag, p.skip,
    )  # fmt: skip
    xp, ok2 = _propagate(p, m, x, u, dt)
    if not (ok and ok2):
        return False
    a = np.zeros((nx, nx))
    for i in range(n):
        a[i, n + i] = 1.0
        a[n + i, 2 * n + i] = 1.0
        for j in range(2 * n):
            a[n + i, j] = jac[i, j]
    phi = EK.transition(a, dt)
    qn = EK.discrete_noise(a, p.qc, dt)
    # relative model error: the perturbed M, C, D, K are off by up to ~10 %, so the
    # predicted acceleration (f_hat + a_d; a_d holds the slow bias, e.g. the gravity
    # error at hover) is, over this period, off by ~ fraction * |f_hat + a_d|
    # (systematic within the period: a fully correlated position/velocity increment)
    rel = p.model_error_fraction * np.abs(a0)
    for i in range(n):
        gq = 0.5 * dt * dt * rel[i]
        gv = dt * rel[i]
        qn[i, i] += gq * gq
        qn[n + i, n + i] += gv * gv
        qn[i, n + i] += gq * gv
        qn[n + i, i] += gq * gv
    pp = phi @ st.p[prev] @ phi.T + qn
    st.t[s] = t
    st.u[s] = u
    st.has_u[s] = True
    st.phi[s] = phi
    st.qn[s] = qn
    st.jac[s] = jac
    st.x[s] = xp
    st.p[s] = 0.5 * (pp + pp.T)
    return True


@njit(cache=True)
def _repropagate(p, st, m, prev, s):
    """The prior of tick ``s`` from the (changed) posterior of tick ``prev`` with the stored
    ``Phi`` and ``Q`` (module :mod:`tdacm.estimation.ekf`: the linearization is not redone)."""
    xp, ok = _propagate(p, m, st.x[prev], st.u[s], st.t[s] - st.t[prev])
    if not ok:
        return False
    phi = st.phi[s]
    pp = phi @ st.p[prev] @ phi.T + st.qn[s]
    st.x[s] = xp
    st.p[s] = 0.5 * (pp + pp.T)
    return True


@njit(cache=True)
def _fuse(x, p, r, h, rr):
    """:func:`~.kernels.kalman_update` into ``x``, ``p``; the status of :func:`ekf_step`."""
    x1, p1, _, status = EK.kalman_update(x, p, r, h, rr)
    if status == EK.UPDATE_SINGULAR:
        return SINGULAR
    if status == EK.UPDATE_NONFINITE:
        return NONFINITE_INNOVATION
    x[:] = x1
    p[:, :] = p1
    return OK


# ----------------------------------------------------------------------------- measurements
@njit(cache=True)
def _encoders(p, m, x, dl):
    """Residual, Jacobian and noise of the encoders: ``dl = l(q_s) - l(q_ref)``,
    ``H = dl/dq_s = -B_s^T``."""
    n, ns = p.n, p.n_s
    lengths, dl_dq = EK.tendon_lengths_and_jacobian(x[n - ns : n], m)
    h = np.zeros((p.n_a, p.nx))
    h[:, n - ns : n] = dl_dq
    return dl - (lengths - p.l_ref), h


@njit(cache=True)
def _pose(p, x, data):
    """Residual and Jacobian of the pose: ``p = q[3:6]``, attitude ``log(R_hat^T R_meas)``
    with ``H = T(phi, theta)`` on the Euler angles."""
    rot = rot_zyx(x[0], x[1], x[2])
    r_meas = data[3:12].copy().reshape(3, 3)
    r = np.empty(6)
    r[:3] = data[:3] - x[3:6]
    r[3:] = so3_log(np.ascontiguousarray(rot.T @ r_meas))
    h = np.zeros((6, p.nx))
    for i in range(3):
        h[i, 3 + i] = 1.0
    h[3:6, 0:3] = euler_rate_matrix(x[0], x[1])
    return r, h


@njit(cache=True)
def _imu(p, m, x, data, u, has_u, jac):
    """Residual, Jacobian and noise of the IMU (gyro only at the reset tick, which has no
    input); ``ok`` False: the model's mass matrix is not positive definite."""
    n, nx = p.n, p.nx
    ib = 3 * n
    q, qd = x[:n], x[n : 2 * n]
    h = np.zeros((6, nx))
    w_hat = EK.body_rate(q, qd) + x[ib : ib + 3]
    h[0:3, n : n + 3] = euler_rate_matrix(q[0], q[1])
    for i in range(3):
        h[i, ib + i] = 1.0
    eps = 1e-7
    for j in range(2):
        qq = q.copy()
        qq[j] += eps
        h[0:3, j] = (EK.body_rate(qq, qd) - EK.body_rate(q, qd)) / eps
    if not has_u:
        return data[:3] - w_hat, h[:3].copy(), p.r_gyro, True
    qdd, ok = _qdd(p, m, x, u)
    if not ok:
        return data[:3] - w_hat, h[:3].copy(), p.r_gyro, False
    f0 = EK.specific_force(q, qdd, p.gravity)
    f_hat = f0 + x[ib + 3 : ib + 6]
    rot = rot_zyx(q[0], q[1], q[2])
    h[3:6, : 2 * n] = rot.T @ jac[3:6, :]
    h[3:6, 2 * n + 3 : 2 * n + 6] = rot.T
    for i in range(3):
        h[3 + i, ib + 3 + i] = 1.0
    for j in range(3):
        qq = q.copy()
        qq[j] += eps
        h[3:6, j] += (EK.specific_force(qq, qdd, p.gravity) - f0) / eps
    r = np.empty(6)
    r[:3] = data[:3] - w_hat
    r[3:] = data[3:6] - f_hat
    return r, h, p.r_imu, True


# ----------------------------------------------------------------------------- the tip camera
@njit(cache=True)
def camera_pose(p, m, q):
    """World pose of C_L at ``q`` in the filter's model: ``g_L(q) g_{C_L}^L`` (paper eq.
    (10)'s chain) and the tip Jacobian ``J_L^L(q)`` (6 x n)."""
    lo, hi = m.rod_steps[0], m.rod_steps[1]
    g, j, _ = chain_jacobian(
        q, np.zeros(q.shape[0]), m.floating, m.g_fixed, m.g_att[0], m.h[lo:hi], m.xi0s[lo:hi],
        m.bs[lo:hi], m.step_col[lo:hi], m.step_nc[lo:hi],
    )  # fmt: skip
    return g @ p.tip_mount, j


@njit(cache=True)
def target_rotation(p, st, x):
    """``R_T = exp([theta]x) R_A`` of the state ``x`` and the left Jacobian ``J_l(theta)``."""
    i = p.i_target
    rot, jl = so3_exp_and_left_jacobian(np.ascontiguousarray(x[i + 3 : i + 6]))
    return rot @ st.anchor, jl


@njit(cache=True)
def view_prediction(p, st, m, x):
    """Predicted normalized points (2k,) of the target at the state ``x``, their Jacobian
    (2k x nx) of :mod:`~tdacm.estimation.camera` and ``ok`` (False: a point is behind C_L)."""
    n, i = p.n, p.i_target
    g_c, j_tip = camera_pose(p, m, x[:n])
    rt, jl = target_rotation(p, st, x)
    z, h_cam, h_tgt, ok = view_model(
        np.ascontiguousarray(g_c[:3, :3]), g_c[:3, 3].copy(), rt,
        np.ascontiguousarray(x[i : i + 3]), jl, p.object_points,
    )  # fmt: skip
    h = np.zeros((z.shape[0], p.nx))
    if ok:
        h[:, :n] = h_cam @ (p.ad_mount_inv @ j_tip)
        h[:, i : i + 6] = h_tgt
    return z, h, ok


@njit(cache=True)
def _put_target(p, g_t, x, pp):
    """The target states of ``x``, ``pp`` at pose ``g_t`` with the prior ``p_target``,
    uncorrelated with the rest."""
    i = p.i_target
    for j in range(3):
        x[i + j] = g_t[j, 3]
        x[i + 3 + j] = 0.0
    pp[i : i + 6, :] = 0.0
    pp[:, i : i + 6] = 0.0
    pp[i : i + 6, i : i + 6] = p.p_target


@njit(cache=True)
def set_target(p, st, g_t, x, pp):
    """(Re)start the target states at pose ``g_t`` (4x4, world) with the wide prior,
    uncorrelated with the rest, in ``x``, ``pp`` and in every kept tick (before the first
    view nothing touched these states, so this is exact; a restart forgets the old target)."""
    st.anchor[:, :] = g_t[:3, :3]
    st.has_anchor[0] = True
    for k in range(st.kept[0]):
        s = _slot(st, k)
        _put_target(p, g_t, st.x[s], st.p[s])
    _put_target(p, g_t, x, pp)


@njit(cache=True)
def _view_update(p, st, m, x, pp, t_meas, data):
    """Fuse one detection of the target into ``x``, ``pp`` (gated; module
    :mod:`~tdacm.estimation.camera`): the first one, or the first after ``reinit_after`` s of
    gated-out views, (re)starts the target from its planar PnP pose
    (:func:`~.camera.pose_from_view`)."""
    n, k = p.n, p.object_points.shape[0]
    pts = data[: 2 * k].copy()
    if not st.has_anchor[0] or t_meas - st.view_ok_t[0] > p.reinit_after:
        g_c, _ = camera_pose(p, m, x[:n])
        g_t = np.empty((4, 4))
        if not pose_from_view(
            p.object_points, p.canonical_points, p.canonical_inv, pts.reshape(k, 2), g_c,
            p.level_normal, g_t,
        ):  # fmt: skip
            return OK
        restart = st.has_anchor[0]
        set_target(p, st, g_t, x, pp)
        st.view_ok_t[0] = t_meas
        if restart:
            st.target_restarts[0] += 1
    z, h, ok = view_prediction(p, st, m, x)
    if not ok:
        st.views_rejected[0] += 1
        return OK
    x1, p1, nis, status = EK.kalman_update(x, pp, pts - z, h, p.r_view)
    if status == EK.UPDATE_SINGULAR:
        return SINGULAR
    if status == EK.UPDATE_NONFINITE:
        return NONFINITE_INNOVATION
    if nis > p.gate:
        st.views_rejected[0] += 1
        return OK
    st.views_fused[0] += 1
    st.view_ok_t[0] = max(st.view_ok_t[0], t_meas)
    x[:] = x1
    pp[:, :] = p1
    return OK


@njit(cache=True)
def _update_tick(p, st, m, s, first):
    """Fuse the measurements ``first, first + 1, ...`` of tick ``s`` into its ``x``, ``p``
    (its prior, or its posterior when only the late ones are fused), kind by kind in the order
    of :data:`ENCODERS` to :data:`VIEW` and in their order within a kind."""
    x = st.x[s].copy()
    pp = st.p[s].copy()
    status = OK
    for kind in range(4):
        for c in range(first, st.m_count[s]):
            if st.m_kind[s, c] != kind:
                continue
            data = st.m_data[s, c]
            if kind == VIEW:
                status = _view_update(p, st, m, x, pp, st.m_t[s, c], data)
            elif kind == ENCODERS:
                r, h = _encoders(p, m, x, data[: p.n_a])
                status = _fuse(x, pp, r, h, p.r_encoders)
            elif not p.floating:  # no drone: its pose and IMU measure nothing of the state
                continue
            elif kind == POSE:
                r, h = _pose(p, x, data)
                status = _fuse(x, pp, r, h, p.r_pose)
            else:
                r, h, rr, ok = _imu(p, m, x, data, st.u[s], st.has_u[s], st.jac[s])
                status = _fuse(x, pp, r, h, rr) if ok else MASS_NOT_PD
            if status != OK:
                return status
    st.x[s] = x
    st.p[s] = pp
    return OK


# ----------------------------------------------------------------------------- the step
@njit(cache=True)
def initial_estimate(p, m, meas, nominal, q_ref, strain_error, position_error, q_out):
    """The start-up configuration (``initial_guess = "measured"``) into ``q_out`` from one
    reading of the sensors ``meas`` (:class:`EkfMeasurements`): the drone's pose from a pose
    measurement (ZYX angles of its rotation), the strains from the encoders by least squares
    from ``q_ref`` (:func:`~tdacm.estimation.inversion.strains_gauss_newton`), the other
    coordinates ``nominal``; plus the configured errors ``strain_error`` on the strains and
    ``position_error`` on the drone's position (convergence studies)."""
    n, ns = p.n, p.n_s
    for i in range(n):
        q_out[i] = nominal[i]
    for r in range(meas.rows[0]):
        d = meas.data[r]
        if meas.kind[r] == POSE and p.floating:
            rot = np.empty((3, 3))
            for a in range(3):
                for c in range(3):
                    rot[a, c] = d[3 + 3 * a + c]
            q_out[0], q_out[1], q_out[2] = euler_zyx(rot)
            for i in range(3):
                q_out[3 + i] = d[i]
        elif meas.kind[r] == ENCODERS:
            qs, _, _ = strains_gauss_newton(m, p.l_ref, d[: p.n_a].copy(), q_ref.copy(), 1e-12, 30)
            for i in range(ns):
                q_out[n - ns + i] = qs[i]
    for i in range(n - ns, n):
        q_out[i] += strain_error
    if p.floating:
        for i in range(3):
            q_out[3 + i] += position_error


@njit(cache=True)
def ekf_reset(p, st, t0, x0, p0):
    """Start the filter at ``t0`` with the state ``x0`` (nx,) and covariance ``p0`` (nx, nx):
    one tick kept, no input, no target, counters zero."""
    st.head[0] = 0
    st.kept[0] = 1
    st.t[0] = t0
    st.x[0] = x0
    st.p[0] = p0
    st.has_u[0] = False
    st.m_count[0] = 0
    st.anchor[:, :] = 0.0
    st.has_anchor[0] = False
    st.view_ok_t[0] = -np.inf
    st.last_view[0] = -np.inf
    st.dropped_late[0] = 0
    st.views_fused[0] = 0
    st.views_rejected[0] = 0
    st.target_restarts[0] = 0


@njit(cache=True)
def ekf_latest(st):
    """Ring slot of the latest tick (its ``t``, ``x``, ``p`` are the estimate)."""
    return _slot(st, st.kept[0] - 1)


@njit(cache=True)
def measurement_put(meas, kind, t, data):
    """Append a measurement (kind, capture time, data) to ``meas``; False when it is full."""
    c = meas.rows[0]
    if c >= meas.kind.shape[0]:
        return False
    meas.kind[c] = kind
    meas.t[c] = t
    meas.data[c, : data.shape[0]] = data
    meas.rows[0] = c + 1
    return True


@njit(cache=True)
def view_is_new(st, t_capture):
    """Whether a detection captured at ``t_capture`` is new to the filter (captured after the
    last one it was given); if so it becomes the last one."""
    if t_capture > st.last_view[0]:
        st.last_view[0] = t_capture
        return True
    return False


@njit(cache=True)
def ekf_step(p, st, m, t, u, has_u, meas):
    """One period of the filter (module :mod:`tdacm.estimation.ekf`): advance to ``t`` with
    the input ``u`` (n_u,) held since the previous tick (``has_u`` False: no input, only at
    the time of the latest tick) and fuse ``meas`` (:class:`EkfMeasurements`, possibly
    captured earlier). A measurement belongs to the tick nearest its capture time (half a
    period either side; a later one to the new tick); one older than the kept history is
    counted in ``dropped_late``. Late measurements are fused on top of their tick's posterior
    and the later ticks re-run from their re-propagated priors with all their measurements;
    then the new tick is predicted (RK4 mean, ``Phi`` by a series, Van Loan's noise) and
    updated, and the history older than ``max_delay`` is dropped. ``m``: the model arrays of
    the controller's private model. Returns the status (module docstring)."""
    cnt = st.kept[0]
    if cnt == 0:
        return NO_RESET
    t_last = st.t[_slot(st, cnt - 1)]
    new_tick = t > t_last + _T_EPS
    if not new_tick and t < t_last - _T_EPS:
        return TIME_BACKWARDS
    if new_tick and not has_u:
        return NO_INPUT
    if new_tick:
        tol = 0.5 * (t - t_last)
    elif cnt > 1:
        tol = 0.5 * (t_last - st.t[_slot(st, cnt - 2)])
    else:
        tol = 1e-6
    # where each measurement goes (cnt: the new tick, -1: older than the history), checked
    # against the slots before anything changes
    nm = meas.rows[0]
    dest = np.empty(nm, np.int64)
    added = np.zeros(cnt + 1, np.int64)
    for i in range(nm):
        mt = meas.t[i]
        if new_tick and mt > t_last + tol:
            dest[i] = cnt
            added[cnt] += 1
            continue
        j = 0
        best = abs(st.t[_slot(st, 0)] - mt)
        for k in range(1, cnt):
            d = abs(st.t[_slot(st, k)] - mt)
            if d < best:
                best = d
                j = k
        if best > tol + _T_EPS:
            dest[i] = -1
            continue
        dest[i] = j
        added[j] += 1
    slots = st.m_kind.shape[1]
    if added[cnt] > slots:
        return TICK_FULL
    for k in range(cnt):
        if st.m_count[_slot(st, k)] + added[k] > slots:
            return TICK_FULL
    window = st.t.shape[0]
    if new_tick and cnt == window and not (st.t[_slot(st, 1)] < t - p.max_delay - _T_EPS):
        return WINDOW_FULL
    earliest = cnt
    for i in range(nm):
        j = dest[i]
        if j < 0:
            st.dropped_late[0] += 1
            continue
        if j == cnt:
            continue
        s = _slot(st, j)
        c = st.m_count[s]
        st.m_kind[s, c] = meas.kind[i]
        st.m_t[s, c] = meas.t[i]
        st.m_data[s, c] = meas.data[i]
        st.m_count[s] = c + 1
        earliest = min(earliest, j)
    if earliest < cnt:
        # the late ones on top of the posterior of their tick (sequential updates), then the
        # later ticks re-run from their re-propagated priors with all their updates
        s = _slot(st, earliest)
        status = _update_tick(p, st, m, s, st.m_count[s] - added[earliest])
        if status != OK:
            return status
        for i in range(earliest + 1, cnt):
            s = _slot(st, i)
            if not _repropagate(p, st, m, _slot(st, i - 1), s):
                return MASS_NOT_PD
            status = _update_tick(p, st, m, s, np.int64(0))
            if status != OK:
                return status
    if new_tick:
        new = cnt  # the destination of the new tick's measurements
        if cnt == window:  # the oldest tick goes (it is older than max_delay: checked above)
            st.head[0] = (st.head[0] + 1) % window
            cnt -= 1
            st.kept[0] = cnt
        s = _slot(st, cnt)
        if not _predict(p, st, m, _slot(st, cnt - 1), s, t, u):
            return MASS_NOT_PD
        c = 0
        for i in range(nm):
            if dest[i] == new:
                st.m_kind[s, c] = meas.kind[i]
                st.m_t[s, c] = meas.t[i]
                st.m_data[s, c] = meas.data[i]
                c += 1
        st.m_count[s] = c
        status = _update_tick(p, st, m, s, np.int64(0))
        if status != OK:
            return status
        st.kept[0] = cnt + 1
        while st.kept[0] > 1 and st.t[_slot(st, 1)] < t - p.max_delay - _T_EPS:
            st.head[0] = (st.head[0] + 1) % window
            st.kept[0] -= 1
    x = st.x[_slot(st, st.kept[0] - 1)]
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return NONFINITE_STATE
    return OK
