"""Extended Kalman filter of the TD-ACM state from drone pose, IMU and tendon encoders.

State (floating base, ``n`` coordinates)::

    x = [q (n), qd (n), a_d (n), b_g (3), b_a (3)]

``q, qd`` as in the model (``q = [phi, theta, psi, x, y, z, q_s]``), ``a_d`` a disturbance
acceleration on every coordinate (random walk: the controller's model is 10 % off and the
disturbances are unknown), ``b_g, b_a`` the gyro and accelerometer biases (random walks). A fixed
base has ``x = [q, qd, a_d]`` and only the encoders.

Process model (continuous, input ``u`` held over the period; the controller's perturbed model,
:mod:`tdacm.estimation.kernels`)::

    q' = qd,  qd' = f_hat(q, qd, u) + a_d + w_a,  a_d' = w_d,  b' = w_b

with white ``w_a`` (``accel_noise_*``), ``w_d`` (``disturbance_walk_*``), ``w_b`` (the IMU's
bias walks). The mean is propagated with RK4 (``rk4_steps`` per period); the covariance with
``Phi = expm(A dt)`` (3rd-order series) of the Jacobian ``A`` (``df_hat/d[q, qd]`` by forward
differences of the numba model) and Van Loan's discretization of the noise.

Measurements (``docs/estimation.md`` has the Jacobians):

* pose: ``p = q[3:6]``; attitude residual ``log(R_hat^T R_meas)`` (body frame) with
  ``H = T(phi, theta)`` on the Euler angles (``R(e + de) ~ R(e) exp([T de]x)``);
* IMU: ``gyro = T(phi, theta) Phi_dot + b_g``, ``accel = R^T (f_hat + a_d - g)[3:6] + b_a``
  evaluated with the input applied over the period ending at the sample;
* encoders: ``dl = l(q_s) - l(q_ref)``, ``H = dl/dq_s = -B_s^T``;
* with a :class:`~tdacm.estimation.camera.TargetCamera`: the tip camera's view of the static
  target, six more states ``[p_T, theta]`` (the target pose) at the end of ``x``
  (:mod:`tdacm.estimation.camera` has the model and the Jacobians).

Latency: the filter keeps its last ``max_delay`` seconds of ticks (input, transition, noise,
measurements). A late measurement is attached to the tick of its capture time and the filter
re-runs from there (updates at each tick, mean re-propagated with RK4, covariance with the
stored ``Phi`` and ``Q``: the linearization is not redone, an O(correction) approximation).
Missing measurements (dropouts, slower sensors) simply mean predict-only ticks.

The filter's one period is the compiled :func:`~tdacm.estimation.ekf_step.ekf_step` over the
records :class:`~tdacm.estimation.ekf_step.EkfParams` (built here once, :func:`ekf_params`)
and :class:`~tdacm.estimation.ekf_step.EkfState`; :class:`ExtendedKalmanFilter` is the Python
block around it (validation, measurement objects, the divergence as an exception, timings).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..control.model import EstimatedModel
from ..lie.euler import euler_from_rotation
from ..lie.se3 import adjoint_pair
from ..vision.ippe import canonical_frame
from . import ekf_step as ES
from .camera import TargetCamera, TargetViewMeasurement
from .config import EstimatorConfig
from .estimate import StateEstimate
from .inversion import strains_from_tendon_lengths
from .kernels import tendon_lengths_and_jacobian
from .proprioception import (
    EncoderMeasurement,
    ImuMeasurement,
    PoseMeasurement,
    SensorSuiteConfig,
)

__all__ = [
    "EstimatorConfig",
    "EstimatorDiverged",
    "ExtendedKalmanFilter",
    "FilterTick",
    "StateEstimate",
    "ekf_params",
    "euler_from_rotation",
]


class EstimatorDiverged(FloatingPointError):
    """The filter cannot go on: its model's mass matrix lost positive definiteness at the
    estimated state, the innovation covariance became singular, or the state became
    non-finite. :class:`~.block.FilterBlock` turns it into :attr:`StateEstimate.failure`
    (the closed loop ends the run)."""


class FilterTick(NamedTuple):
    """One kept tick of the filter's history: its time, posterior state and covariance."""

    t: float
    x: np.ndarray
    P: np.ndarray


#: measurement objects -> kinds of :mod:`~tdacm.estimation.ekf_step`
_KINDS = {
    EncoderMeasurement: ES.ENCODERS,
    PoseMeasurement: ES.POSE,
    ImuMeasurement: ES.IMU,
    TargetViewMeasurement: ES.VIEW,
}


def ekf_params(
    model: EstimatedModel,
    sensors: SensorSuiteConfig,
    config: EstimatorConfig,
    q_ref,
    camera: TargetCamera | None,
) -> ES.EkfParams:
    """The :class:`~tdacm.estimation.ekf_step.EkfParams` of a filter on the controller's
    ``model`` assuming ``sensors``, tuned by ``config``, with encoders zeroed at the strains
    ``q_ref`` and the tip ``camera`` (or ``None``): the noise of the process model, the
    default initial covariance and the measurement noises (module docstring)."""
    sysm = model.system  # private, gravity-only copy (no disturbances)
    m = sysm.model_arrays
    n, n_s, n_a = sysm.n, sysm.n_s, sysm.n_a
    floating = sysm.floating
    i_target = 3 * n + (6 if floating else 0)
    nx = i_target + (6 if camera is not None else 0)
    c, imu, enc, pose = config, sensors.imu, sensors.encoders, sensors.pose

    def blocks(a, b, d, e=None, f=None, target=None):
        """A vector over the state from per-block values (q, qd, a_d[, b_g, b_a][, target])."""
        parts = [a, b, d] + ([e, f] if floating else [])
        if camera is not None:
            parts.append(np.zeros(6) if target is None else target)
        return np.concatenate(parts)

    def per_coord(ang, lin, strain):
        if floating:
            return np.array([ang] * 3 + [lin] * 3 + [strain] * n_s, float)
        return np.full(n_s, float(strain))

    wa = per_coord(c.accel_noise_angular, c.accel_noise_linear, c.accel_noise_strain)
    wd = per_coord(c.disturbance_walk_angular, c.disturbance_walk_linear, c.disturbance_walk_strain)
    # a small floor keeps Q_c positive on the bias states (numerical conditioning)
    qc = np.diag(
        blocks(np.zeros(n), wa**2, wd**2, np.full(3, max(imu.gyro_bias_walk, 1e-5)) ** 2,
               np.full(3, max(imu.accel_bias_walk, 1e-4)) ** 2)
    )  # fmt: skip
    q_std = per_coord(c.initial_attitude_std, c.initial_position_std, c.initial_strain_std)
    ad_std = per_coord(
        c.initial_disturbance_angular_std,
        c.initial_disturbance_linear_std,
        c.initial_disturbance_strain_std,
    )
    target_std = None
    if camera is not None:
        target_std = np.array(
            [camera.target_initial_position_std] * 3 + [camera.target_initial_attitude_std] * 3
        )
    p0 = np.diag(
        blocks(q_std, np.full(n, c.initial_velocity_std), ad_std,
               np.full(3, max(imu.gyro_bias, 1e-4)), np.full(3, max(imu.accel_bias, 1e-3)),
               target_std) ** 2
    )  # fmt: skip
    skip = np.zeros(n, dtype=np.bool_)
    if floating:
        skip[3:6] = True  # the dynamics do not depend on the drone's position
    rr = [imu.gyro_noise**2] * 3 + [imu.accel_noise**2 + c.accel_model_error**2] * 3
    if camera is not None:
        obj = camera.object_points
        k = obj.shape[0]
        obj2d, canon = canonical_frame(obj)
        cam = dict(
            tip_mount=camera.tip_mount.copy(),
            ad_mount_inv=adjoint_pair(camera.tip_mount)[1],
            object_points=obj.copy(),
            canonical_points=np.ascontiguousarray(obj2d),
            canonical_inv=np.ascontiguousarray(np.linalg.inv(canon)),
            r_view=np.diag(np.tile(camera.sigma**2, k)),
            gate=camera.gate,
            reinit_after=float(camera.reinit_after),
            level_normal=camera.level_normal.copy(),
            p_target=np.diag(target_std**2),
        )
    else:
        cam = dict(
            tip_mount=np.eye(4), ad_mount_inv=np.eye(6), object_points=np.zeros((0, 3)),
            canonical_points=np.zeros((0, 2)), canonical_inv=np.eye(4),
            r_view=np.zeros((0, 0)), gate=0.0, reinit_after=0.0, level_normal=np.zeros(3),
            p_target=np.zeros((6, 6)),
        )  # fmt: skip
    ca = np.ascontiguousarray
    return ES.EkfParams(
        n=int(n), n_s=int(n_s), n_a=int(n_a), n_u=int(sysm.n_u), nx=int(nx),
        floating=bool(floating), camera=camera is not None, i_target=int(i_target),
        rk4_steps=int(c.rk4_steps), loads=sysm.loads.packed().copy(),
        gravity=sysm.loads.gravity.copy(), mass_scale=ca(model.mass_scale, float),
        damping_scale=ca(model.damping_scale, float), stiffness_scale=ca(model.stiffness_scale),
        gravity_scale=ca(model.gravity_scale), rotor_drag=ca(model.rotor_drag, float), skip=skip,
        qc=qc, model_error_fraction=float(c.model_error_fraction), p0=p0,
        l_ref=tendon_lengths_and_jacobian(q_ref, m)[0],
        r_encoders=np.eye(n_a) * max(enc.variance + enc.bias**2, 1e-16),
        r_pose=np.diag([pose.position_noise**2] * 3 + [pose.attitude_noise**2] * 3)
        + np.eye(6) * 1e-14,
        r_imu=np.diag(rr) + np.eye(6) * 1e-14, r_gyro=np.diag(rr[:3]) + np.eye(3) * 1e-14,
        max_delay=float(c.max_delay), **cam,
    )  # fmt: skip


class ExtendedKalmanFilter:
    """EKF on the controller's perturbed model (see module docstring).

    Parameters
    ----------
    model:
        The controller's :class:`~tdacm.control.model.EstimatedModel` (its private
        gravity-only copy and its perturbation draws are used; the plant is never touched).
    sensors:
        The sensor specifications the filter assumes (noise levels for ``R``; datasheet values).
    config:
        :class:`EstimatorConfig`.
    q_ref:
        Strains at which the encoders were zeroed (default straight).
    camera:
        A :class:`~tdacm.estimation.camera.TargetCamera` to fuse the tip camera's view of the
        static target (six more states: the target pose); ``None`` (default): proprioceptive
        sensors only.
    period:
        The period (s) the filter will be stepped at, to size its window of ticks at once
        (:func:`~tdacm.estimation.ekf_step.window_ticks`); ``None``: the window grows to what
        ``max_delay`` needs as the filter runs.

    The filter's parameters are :attr:`params`, its state :attr:`state` (records of
    :mod:`~tdacm.estimation.ekf_step`).
    """

    #: measurements a tick holds at first (the slots and the window grow when a run needs more)
    SLOTS = 8

    def __init__(
        self,
        model: EstimatedModel,
        sensors: SensorSuiteConfig | None = None,
        config: EstimatorConfig | None = None,
        q_ref=None,
        camera: TargetCamera | None = None,
        period: float | None = None,
    ):
        if not isinstance(model, EstimatedModel):
            raise ValueError(f"model must be an EstimatedModel, got {model!r}")
        if camera is not None and not isinstance(camera, TargetCamera):
            raise ValueError(f"camera must be a TargetCamera or None, got {camera!r}")
        self.model = model
        self.sensors = SensorSuiteConfig() if sensors is None else sensors
        self.config = EstimatorConfig() if config is None else config
        sysm = model.system  # private, gravity-only copy (no disturbances)
        self.system = sysm
        #: the model arrays of the controller's private model, which the filter propagates
        self.model_arrays = sysm.model_arrays
        self.n, self.n_s, self.n_a = sysm.n, sysm.n_s, sysm.n_a
        self.floating = sysm.floating
        self.camera = camera
        self.q_ref = np.zeros(self.n_s) if q_ref is None else np.asarray(q_ref, float)
        if self.q_ref.shape != (self.n_s,):
            raise ValueError(f"q_ref must hold the {self.n_s} strains, got {self.q_ref.shape}")
        self.params = ekf_params(model, self.sensors, self.config, self.q_ref, camera)
        self._revision = model.revision
        self.nx = self.params.nx
        self.i_target = self.params.i_target  # index of [p_T, theta] (with a camera)
        if period is None:
            window = 4
        else:
            if not period > 0:
                raise ValueError(f"period must be positive, got {period!r}")
            window = ES.window_ticks(self.config.max_delay, float(period))
        self.state = ES.EkfState.empty(self.params, window, self.SLOTS)
        self.timings: list[float] = []  # wall time of each step (s)

    # ------------------------------------------------------------------ set-up
    def renew(self) -> None:
        """Take the model's current parameter errors (after ``model.reseed``) into the
        filter's record."""
        if self._revision != self.model.revision:
            self.params = ekf_params(self.model, self.sensors, self.config, self.q_ref, self.camera)
            self._revision = self.model.revision

    def default_covariance(self) -> np.ndarray:
        """``P0`` from the config's initial standard deviations and the IMU's bias specs."""
        return self.params.p0.copy()

    def initial_guess(self, measurements, fallback_q=None) -> np.ndarray:
        """``q`` from one set of measurements: drone pose from the pose sensor, strains from
        the encoders by least squares (:func:`strains_from_tendon_lengths`); coordinates
        without a measurement come from ``fallback_q`` (default zeros)."""
        q = np.zeros(self.n) if fallback_q is None else np.asarray(fallback_q, float).copy()
        for m in measurements:
            if isinstance(m, PoseMeasurement) and self.floating:
                q[:3] = euler_from_rotation(m.rotation)
                q[3:6] = m.position
            elif isinstance(m, EncoderMeasurement):
                res = strains_from_tendon_lengths(self.system, m.delta_length, self.q_ref)
                q[self.n - self.n_s :] = res.q_s
        return q

    def reset(self, q0, P0=None, t0: float = 0.0, qd0=None) -> StateEstimate:
        """Start at ``(q0, qd0)`` (``qd0`` default zeros, disturbances and biases zero) with
        covariance ``P0`` (full ``nx x nx``, or ``2n x 2n`` for ``[q, qd]`` only; default
        :meth:`default_covariance`)."""
        self.renew()
        n = self.n
        q0 = np.asarray(q0, float)
        qd0 = np.zeros(n) if qd0 is None else np.asarray(qd0, float)
        if q0.shape != (n,) or qd0.shape != (n,):
            raise ValueError(f"q0 and qd0 must have {n} entries, got {q0.shape}, {qd0.shape}")
        p = self.default_covariance()
        if P0 is not None:
            P0 = np.asarray(P0, float)
            if P0.shape == (2 * n, 2 * n):
                p[: 2 * n, : 2 * n] = P0
            elif P0.shape == (self.nx, self.nx):
                p = P0.copy()
            else:
                raise ValueError(f"P0 must be {2 * n}x{2 * n} or {self.nx}x{self.nx}")
        x = np.zeros(self.nx)
        x[:n], x[n : 2 * n] = q0, qd0
        ES.ekf_reset(self.params, self.state, float(t0), x, np.ascontiguousarray(p))
        self.timings = []
        return self.estimate

    def warm_up(self) -> None:
        """Run the compiled step once (numba compiles or loads it), leaving no state behind."""
        n = self.n
        q = np.zeros(n)
        if self.floating:
            q[5] = 1.0
        kept, timings = self.state, self.timings
        self.state = ES.EkfState.empty(self.params, 4, self.SLOTS)
        try:
            self.reset(q)
            u = np.zeros(self.system.n_u)
            meas = [EncoderMeasurement(0.0, np.zeros(self.n_a))]
            if self.floating:
                meas += [PoseMeasurement(0.0, q[3:6], np.eye(3)),
                         ImuMeasurement(0.02, np.zeros(3), np.array([0.0, 0.0, 9.81]))]  # fmt: skip
            if self.camera is not None:  # a target 1 m in front of C_L
                obj = self.camera.object_points
                z = obj[:, :2] / (obj[:, 2:] + 1.0)
                meas.append(TargetViewMeasurement(0.02, z))
            self.step(0.0, None, meas[:2])
            self.step(0.02, u, meas[2:])
        finally:
            self.state, self.timings = kept, timings

    # ------------------------------------------------------------------ outputs
    def _latest(self) -> int:
        if self.state.kept[0] == 0:
            raise RuntimeError("call reset() before using the filter")
        return int(ES.ekf_latest(self.state))

    @property
    def estimate(self) -> StateEstimate:
        s, n, st = self._latest(), self.n, self.state
        return StateEstimate(
            float(st.t[s]),
            st.x[s, :n].copy(),
            st.x[s, n : 2 * n].copy(),
            st.p[s, : 2 * n, : 2 * n].copy(),
        )

    @property
    def x(self) -> np.ndarray:
        """The full filter state ``[q, qd, a_d(, b_g, b_a)(, p_T, theta)]``."""
        return self.state.x[self._latest()].copy()

    @property
    def P_full(self) -> np.ndarray:
        return self.state.p[self._latest()].copy()

    def history(self) -> list[FilterTick]:
        """The kept ticks, oldest first (copies)."""
        st = self.state
        out = []
        for i in range(int(st.kept[0])):
            s = (int(st.head[0]) + i) % st.window
            out.append(FilterTick(float(st.t[s]), st.x[s].copy(), st.p[s].copy()))
        return out

    @property
    def dropped_late(self) -> int:
        """Measurements older than the kept history (not fused)."""
        return int(self.state.dropped_late[0])

    @property
    def views_fused(self) -> int:
        """Target views fused (re-runs of late ticks count again)."""
        return int(self.state.views_fused[0])

    @property
    def views_rejected(self) -> int:
        """Target views gated out or with a point behind C_L."""
        return int(self.state.views_rejected[0])

    @property
    def target_restarts(self) -> int:
        """Times the target states were started again after ``reinit_after`` s of rejects."""
        return int(self.state.target_restarts[0])

    # ------------------------------------------------------------------ process model
    def _qdd(self, x, u) -> np.ndarray:
        """The process model's ``f_hat(q, qd, u) + a_d`` at the state ``x``."""
        a, ok = ES.model_acceleration(
            self.params,
            self.model_arrays,
            np.ascontiguousarray(x, float),
            np.ascontiguousarray(u, float),
        )
        if not ok:
            raise EstimatorDiverged(ES.DIVERGENCE[ES.MASS_NOT_PD])
        return a

    # ------------------------------------------------------------------ the tip camera
    def _need_camera(self) -> None:
        if self.camera is None:
            raise ValueError("the filter has no camera (ExtendedKalmanFilter(..., camera=...))")

    def camera_pose(self, q) -> np.ndarray:
        """World pose of C_L at ``q`` in the filter's model: ``g_L(q) g_{C_L}^L``."""
        self._need_camera()
        return ES.camera_pose(self.params, self.model_arrays, np.ascontiguousarray(q, float))[0]

    def target_pose(self, x=None) -> np.ndarray | None:
        """The filter's target pose (4x4, world) from state ``x`` (default: the latest);
        ``None`` before the target was first seen."""
        if not self.state.has_anchor[0]:
            return None
        x = self.x if x is None else np.ascontiguousarray(x, float)
        i = self.i_target
        g = np.eye(4)
        g[:3, :3] = ES.target_rotation(self.params, self.state, x)[0]
        g[:3, 3] = x[i : i + 3]
        return g

    def view_prediction(self, x):
        """Predicted normalized points (2k,) of the target at state ``x`` and the Jacobian
        (2k x nx) of :mod:`~tdacm.estimation.camera`; ``None`` if a point is behind C_L."""
        self._need_camera()
        z, h, ok = ES.view_prediction(
            self.params, self.state, self.model_arrays, np.ascontiguousarray(x, float)
        )
        return (z, h) if ok else None

    def start_target(self, g_t) -> None:
        """(Re)start the target states at the pose ``g_t`` (4x4, world) with the wide prior,
        in the latest estimate and every kept tick (what the first view does from its planar
        PnP pose)."""
        self._need_camera()
        s = self._latest()
        st = self.state
        x, p = st.x[s].copy(), st.p[s].copy()
        ES.set_target(self.params, st, np.ascontiguousarray(g_t, float), x, p)

    # ------------------------------------------------------------------ step
    def pack(self, measurements) -> ES.EkfMeasurements:
        """The measurement objects as the rows of :class:`~.ekf_step.EkfMeasurements`."""
        meas = ES.EkfMeasurements.empty(self.params, len(measurements))
        k = self.params.object_points.shape[0]
        shapes = {ES.ENCODERS: (self.n_a,), ES.IMU: (3,), ES.POSE: (3,), ES.VIEW: (k, 2)}
        for i, m in enumerate(measurements):
            kind = _KINDS.get(type(m))
            if kind is None:
                raise ValueError(f"unknown measurement {m!r}")
            if kind == ES.VIEW and self.camera is None:
                raise ValueError(
                    "a TargetViewMeasurement needs an ExtendedKalmanFilter built with a camera"
                )
            if kind == ES.ENCODERS:
                parts = [m.delta_length]
            elif kind == ES.POSE:
                parts = [m.position, m.rotation]
            elif kind == ES.IMU:
                parts = [m.gyro, m.accel]
            else:
                parts = [m.points]
            parts = [np.asarray(a, float) for a in parts]
            if parts[0].shape != shapes[kind] or (kind == ES.POSE and parts[1].shape != (3, 3)):
                raise ValueError(f"measurement {m!r}: wrong shape")
            row = np.concatenate([a.ravel() for a in parts])
            meas.kind[i] = kind
            meas.t[i] = float(m.t)
            meas.data[i, : row.size] = row
        meas.rows[0] = len(measurements)
        return meas

    def fit_slots(self, rows: int) -> None:
        """Room for ``rows`` measurements in one tick (a compiled caller that cannot grow the
        state, :func:`~tdacm.estimation.block.filter_start`)."""
        slots = self.state.slots
        while slots < rows:
            slots *= 2
        if slots != self.state.slots:
            self._grow(self.state.window, slots)

    def _grow(self, window: int, slots: int) -> None:
        """A larger window (or more slots a tick) holding the same history."""
        old = self.state
        new = ES.EkfState.empty(self.params, window, slots)
        cnt, w = int(old.kept[0]), old.window
        order = (int(old.head[0]) + np.arange(cnt)) % w
        for name in ("t", "x", "p", "u", "has_u", "phi", "qn", "jac", "m_count"):
            getattr(new, name)[:cnt] = getattr(old, name)[order]
        for name in ("m_kind", "m_t", "m_data"):
            getattr(new, name)[:cnt, : old.slots] = getattr(old, name)[order]
        for name in ("anchor", "has_anchor", "view_ok_t", "last_view", "dropped_late",
                     "views_fused", "views_rejected", "target_restarts"):  # fmt: skip
            getattr(new, name)[...] = getattr(old, name)
        new.kept[0] = cnt
        self.state = new

    def step(self, t: float, u_applied, measurements=()) -> StateEstimate:
        """Advance to time ``t`` with the input ``u_applied`` held since the previous step
        (``None`` at the reset time: update only) and fuse ``measurements`` (any mix of pose,
        IMU, encoder and target-view measurements, possibly captured earlier than ``t``)."""
        w0 = time.perf_counter()
        if self.state.kept[0] == 0:
            raise RuntimeError("call reset() before step()")
        self.renew()
        t = float(t)
        if u_applied is None:
            u = np.zeros(self.system.n_u)
        else:
            u = np.ascontiguousarray(u_applied, dtype=float)
            if u.shape != (self.system.n_u,):
                raise ValueError(f"u_applied must have {self.system.n_u} entries, got {u.shape}")
        meas = self.pack(list(measurements))
        while True:
            status = ES.ekf_step(self.params, self.state, self.model_arrays, t, u, u_applied is not None,
                                 meas)  # fmt: skip
            if status == ES.WINDOW_FULL:
                self._grow(2 * self.state.window, self.state.slots)
            elif status == ES.TICK_FULL:
                self._grow(self.state.window, 2 * self.state.slots)
            else:
                break
        if status == ES.TIME_BACKWARDS:
            raise ValueError(f"time went backwards: {t} < {self.estimate.t}")
        if status == ES.NO_INPUT:
            raise ValueError(f"u_applied is needed to advance to t = {t} (> {self.estimate.t})")
        if status != ES.OK:
            raise EstimatorDiverged(ES.DIVERGENCE[status])
        self.timings.append(time.perf_counter() - w0)
        return self.estimate
