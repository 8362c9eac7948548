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

Latency: the filter keeps its last ``max_delay`` seconds of ticks (prior, input, transition,
measurements). A late measurement is attached to the tick of its capture time and the filter
re-runs from there (updates at each tick, mean re-propagated with RK4, covariance with the
stored ``Phi`` and ``Q``: the linearization is not redone, an O(correction) approximation).
Missing measurements (dropouts, slower sensors) simply mean predict-only ticks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..control.model import EstimatedModel
from ..lie.euler import euler_from_rotation, euler_rate_matrix, rot_zyx
from ..lie.se3 import adjoint_pair, so3_exp_and_left_jacobian, so3_log
from ..vision.mounts import tip_camera_pose
from . import kernels as EK
from .camera import TargetCamera, TargetViewMeasurement, target_pose_from_view, view_model
from .config import EstimatorConfig
from .estimate import StateEstimate
from .inversion import strains_from_tendon_lengths
from .proprioception import (
    EncoderMeasurement,
    ImuMeasurement,
    PoseMeasurement,
    SensorSuiteConfig,
)


class EstimatorDiverged(FloatingPointError):
    """The filter cannot go on: its model's mass matrix lost positive definiteness at the
    estimated state, or the state became non-finite. :class:`~.block.FilterBlock` turns it
    into :attr:`StateEstimate.failure` (the closed loop ends the run)."""


def _kalman_update(x, p, r, h, rr):
    """:func:`~.kernels.kalman_update`; a singular innovation covariance ``H P H^T + R`` (only
    a broken ``P`` makes it so: ``R`` is positive definite) is the filter's divergence."""
    try:
        return EK.kalman_update(x, p, r, h, rr)
    except np.linalg.LinAlgError as exc:
        raise EstimatorDiverged(
            f"estimator diverged (singular innovation covariance: {exc})"
        ) from exc


@dataclass(slots=True, eq=False)
class _Tick:
    """One filter period in the history: its input, prior, transition ``phi``, process noise
    ``qn`` and Jacobian, the measurements fused at it and its posterior (the prior until
    one is)."""

    t: float
    u: object
    x_prior: np.ndarray
    p_prior: np.ndarray
    phi: object
    qn: object
    jac: object
    meas: list = field(default_factory=list)
    x_post: np.ndarray = None
    p_post: np.ndarray = None

    def __post_init__(self):
        self.x_post = self.x_prior
        self.p_post = self.p_prior


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
    """

    def __init__(
        self,
        model: EstimatedModel,
        sensors: SensorSuiteConfig | None = None,
        config: EstimatorConfig | None = None,
        q_ref=None,
        camera: TargetCamera | None = None,
    ):
        if not isinstance(model, EstimatedModel):
            raise ValueError(f"model must be an EstimatedModel, got {model!r}")
        self.model = model
        self.sensors = SensorSuiteConfig() if sensors is None else sensors
        self.config = EstimatorConfig() if config is None else config
        sysm = model.system  # private, gravity-only copy (no disturbances)
        self.system = sysm
        self._m = sysm.model_arrays
        self._loads = sysm.loads.packed().copy()
        self._gravity = sysm.loads.gravity.copy()
        self._s_m = np.ascontiguousarray(model.mass_scale)
        self._s_d = np.ascontiguousarray(model.damping_scale)
        self._k_scale = 1.0 + model.d_k
        self._g_scale = 1.0 + model.d_g
        self._drag = np.ascontiguousarray(model.rotor_drag, dtype=float)
        n = sysm.n
        self.n, self.n_s, self.n_a = n, sysm.n_s, sysm.n_a
        self.floating = sysm.floating
        self.nx = 3 * n + (6 if self.floating else 0)
        if camera is not None and not isinstance(camera, TargetCamera):
            raise ValueError(f"camera must be a TargetCamera or None, got {camera!r}")
        self.camera = camera
        self.i_target = self.nx  # index of [p_T, theta] in the state (with a camera)
        if camera is not None:
            self.nx += 6
            self._ad_mount_inv = adjoint_pair(camera.tip_mount)[1]
            self._r_view = np.diag(np.tile(camera.sigma**2, camera.object_points.shape[0]))
        self._anchor = None  # R_A of the target (set at its first detection)
        self._view_ok_t = -np.inf  # capture time of the last fused view
        self.views_fused = 0  # target views fused / gated out (re-runs of late ticks count)
        self.views_rejected = 0
        self.target_restarts = 0
        self._skip = np.zeros(n, dtype=np.bool_)
        if self.floating:
            self._skip[3:6] = True  # the dynamics do not depend on the drone's position
        self.q_ref = np.zeros(self.n_s) if q_ref is None else np.asarray(q_ref, float)
        self._l_ref = EK.tendon_lengths_and_jacobian(self.q_ref, self._m)[0]
        self._qc = self._continuous_noise()
        self._hist: list[_Tick] = []
        self.dropped_late = 0  # measurements older than the kept history
        self.timings: list[float] = []  # wall time of each step (s)

    # ------------------------------------------------------------------ set-up
    def _blocks(self, a, b, c, d=None, e=None, target=None):
        """A vector over the state from per-block values (q, qd, a_d[, b_g, b_a][, target])."""
        parts = [a, b, c] + ([d, e] if self.floating else [])
        if self.camera is not None:
            parts.append(np.zeros(6) if target is None else target)
        return np.concatenate(parts)

    def _per_coord(self, ang, lin, strain):
        if self.floating:
            return np.array([ang] * 3 + [lin] * 3 + [strain] * self.n_s, float)
        return np.full(self.n_s, float(strain))

    def _continuous_noise(self):
        c, n = self.config, self.n
        wa = self._per_coord(c.accel_noise_angular, c.accel_noise_linear, c.accel_noise_strain)
        wd = self._per_coord(
            c.disturbance_walk_angular, c.disturbance_walk_linear, c.disturbance_walk_strain
        )
        imu = self.sensors.imu
        # a small floor keeps Q_c positive on the bias states (numerical conditioning)
        bg = np.full(3, max(imu.gyro_bias_walk, 1e-5))
        ba = np.full(3, max(imu.accel_bias_walk, 1e-4))
        return np.diag(self._blocks(np.zeros(n), wa**2, wd**2, bg**2, ba**2))

    def default_covariance(self) -> np.ndarray:
        """``P0`` from the config's initial standard deviations and the IMU's bias specs."""
        c = self.config
        q_std = self._per_coord(
            c.initial_attitude_std, c.initial_position_std, c.initial_strain_std
        )
        qd_std = np.full(self.n, c.initial_velocity_std)
        ad_std = self._per_coord(
            c.initial_disturbance_angular_std,
            c.initial_disturbance_linear_std,
            c.initial_disturbance_strain_std,
        )
        imu = self.sensors.imu
        bg = np.full(3, max(imu.gyro_bias, 1e-4))
        ba = np.full(3, max(imu.accel_bias, 1e-3))
        return np.diag(self._blocks(q_std, qd_std, ad_std, bg, ba, self._target_std()) ** 2)

    def _target_std(self):
        cam = self.camera
        if cam is None:
            return None
        return np.array(
            [cam.target_initial_position_std] * 3 + [cam.target_initial_attitude_std] * 3
        )

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
        self._hist = [_Tick(float(t0), None, x, p, None, None, None)]
        self.dropped_late = 0
        self.timings = []
        self._anchor = None
        self._view_ok_t = -np.inf
        self.views_fused = self.views_rejected = self.target_restarts = 0
        return self.estimate

    def warm_up(self) -> None:
        """Run every kernel once (numba compiles or loads them), leaving no state behind."""
        n = self.n
        q = np.zeros(n)
        if self.floating:
            q[5] = 1.0
        kept = (self._hist, self.dropped_late, self.timings, self._anchor, self._view_ok_t,
                self.views_fused, self.views_rejected, self.target_restarts)  # fmt: skip
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
        (self._hist, self.dropped_late, self.timings, self._anchor, self._view_ok_t,
         self.views_fused, self.views_rejected, self.target_restarts) = kept  # fmt: skip

    # ------------------------------------------------------------------ outputs
    @property
    def estimate(self) -> StateEstimate:
        tk = self._hist[-1]
        n = self.n
        return StateEstimate(
            tk.t,
            tk.x_post[:n].copy(),
            tk.x_post[n : 2 * n].copy(),
            tk.p_post[: 2 * n, : 2 * n].copy(),
        )

    @property
    def x(self) -> np.ndarray:
        """The full filter state ``[q, qd, a_d(, b_g, b_a)]``."""
        return self._hist[-1].x_post.copy()

    @property
    def P_full(self) -> np.ndarray:
        return self._hist[-1].p_post.copy()

    # ------------------------------------------------------------------ process model
    def _qdd(self, x, u):
        n = self.n
        a, ok = EK.model_qdd(
            x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], self._m, self._loads,
            self._s_m, self._s_d, self._k_scale, self._g_scale, self._drag,
        )  # fmt: skip
        if not ok:
            raise EstimatorDiverged("estimator: the model's mass matrix is not positive definite")
        return a

    def _predict(self, prev: _Tick, t: float, u) -> _Tick:
        n, nx = self.n, self.nx
        dt = t - prev.t
        x = prev.x_post
        q, qd, ad = x[:n], x[n : 2 * n], x[2 * n : 3 * n]
        args = (
            self._m, self._loads, self._s_m, self._s_d, self._k_scale, self._g_scale, self._drag
        )  # fmt: skip
        a0, jac, ok = EK.linearize(q, qd, u, ad, *args, self._skip)
        q1, qd1, ok2 = EK.propagate_mean(q, qd, u, ad, dt, self.config.rk4_steps, *args)
        if not (ok and ok2):
            raise EstimatorDiverged("estimator: the model's mass matrix is not positive definite")
        a = np.zeros((nx, nx))
        a[:n, n : 2 * n] = np.eye(n)
        a[n : 2 * n, : 2 * n] = jac
        a[n : 2 * n, 2 * n : 3 * n] = np.eye(n)
        phi = EK.transition(a, dt)
        qn = EK.discrete_noise(a, self._qc, dt)
        # relative model error: the perturbed M, C, D, K are off by up to ~10 %, so the
        # predicted acceleration (f_hat + a_d; a_d holds the slow bias, e.g. the gravity
        # error at hover) is, over this period, off by ~ fraction * |f_hat + a_d|
        # (systematic within the period: a fully correlated position/velocity increment)
        rel = self.config.model_error_fraction * np.abs(a0)
        g = np.concatenate([0.5 * dt * dt * rel, dt * rel])
        idx = np.arange(2 * n)
        sub = np.zeros((2 * n, 2 * n))
        sub[idx[:n], idx[:n]] = g[:n] ** 2
        sub[idx[n:], idx[n:]] = g[n:] ** 2
        sub[:n, n:] = sub[n:, :n] = np.diag(g[:n] * g[n:])
        qn[: 2 * n, : 2 * n] += sub
        xp = x.copy()
        xp[:n], xp[n : 2 * n] = q1, qd1
        pp = phi @ prev.p_post @ phi.T + qn
        return _Tick(t, u, xp, 0.5 * (pp + pp.T), phi, qn, jac)

    def _repropagate(self, prev: _Tick, tk: _Tick) -> None:
        """Prior of ``tk`` from the (changed) posterior of ``prev`` with the stored Phi, Q."""
        n = self.n
        x = prev.x_post
        args = (
            self._m, self._loads, self._s_m, self._s_d, self._k_scale, self._g_scale, self._drag
        )  # fmt: skip
        q1, qd1, ok = EK.propagate_mean(
            x[:n], x[n : 2 * n], tk.u, x[2 * n : 3 * n], tk.t - prev.t, self.config.rk4_steps, *args
        )
        if not ok:
            raise EstimatorDiverged("estimator: the model's mass matrix is not positive definite")
        xp = x.copy()
        xp[:n], xp[n : 2 * n] = q1, qd1
        pp = tk.phi @ prev.p_post @ tk.phi.T + tk.qn
        tk.x_prior, tk.p_prior = xp, 0.5 * (pp + pp.T)

    # ------------------------------------------------------------------ updates
    def _update_tick(self, tk: _Tick, late=None) -> None:
        """Fuse the tick's measurements into its prior (``late is None``) or only the
        ``late`` ones into its current posterior (the others are in it already)."""
        if late is None:
            x, p, todo = tk.x_prior, tk.p_prior, tk.meas
        else:
            x, p, todo = tk.x_post, tk.p_post, late
        order = {EncoderMeasurement: 0, PoseMeasurement: 1, ImuMeasurement: 2,
                 TargetViewMeasurement: 3}  # fmt: skip
        for meas in sorted(todo, key=lambda m: order[type(m)]):
            if isinstance(meas, TargetViewMeasurement):
                x, p = self._view_update(x, p, meas)
                continue
            res = self._measurement(x, meas, tk)
            if res is not None:
                x, p, _ = _kalman_update(x, p, *res)
        tk.x_post, tk.p_post = x, p

    # ------------------------------------------------------------------ the tip camera
    def camera_pose(self, q) -> np.ndarray:
        """World pose of C_L at ``q`` in the filter's model: ``g_L(q) g_{C_L}^L``."""
        return tip_camera_pose(self.system, q, self.camera.tip_mount)

    def target_pose(self, x=None) -> np.ndarray | None:
        """The filter's target pose (4x4, world) from state ``x`` (default: the latest);
        ``None`` before the target was first seen."""
        if self._anchor is None:
            return None
        x = self._hist[-1].x_post if x is None else x
        i = self.i_target
        g = np.eye(4)
        g[:3, :3] = (
            so3_exp_and_left_jacobian(np.ascontiguousarray(x[i + 3 : i + 6]))[0] @ self._anchor
        )
        g[:3, 3] = x[i : i + 3]
        return g

    def view_prediction(self, x):
        """Predicted normalized points (2k,) of the target at state ``x`` and the Jacobian
        (2k x nx) of :mod:`~tdacm.estimation.camera`; ``None`` if a point is behind C_L."""
        n, i = self.n, self.i_target
        q = x[:n]
        g_c = self.camera_pose(q)
        rot, jl = so3_exp_and_left_jacobian(np.ascontiguousarray(x[i + 3 : i + 6]))
        z, h_cam, h_tgt, ok = view_model(
            np.ascontiguousarray(g_c[:3, :3]), g_c[:3, 3].copy(), rot @ self._anchor,
            np.ascontiguousarray(x[i : i + 3]), jl, self.camera.object_points,
        )  # fmt: skip
        if not ok:
            return None
        h = np.zeros((z.size, self.nx))
        h[:, :n] = h_cam @ (self._ad_mount_inv @ self.system.tip_jacobian(q))
        h[:, i : i + 6] = h_tgt
        return z, h

    def _set_target(self, g_t, x, p):
        """(Re)start the target states at pose ``g_t`` with the wide prior, uncorrelated
        with the rest, in ``x, p`` and in every kept tick (before the first view nothing
        touched these states, so this is exact; a restart forgets the old target)."""
        i = self.i_target
        self._anchor = np.ascontiguousarray(g_t[:3, :3])
        p0 = np.diag(self._target_std() ** 2)

        def put(xx, pp):
            xx = xx.copy()
            xx[i : i + 3], xx[i + 3 : i + 6] = g_t[:3, 3], 0.0
            pp = pp.copy()
            pp[i : i + 6, :] = 0.0
            pp[:, i : i + 6] = 0.0
            pp[i : i + 6, i : i + 6] = p0
            return xx, pp

        for tk in self._hist:
            tk.x_prior, tk.p_prior = put(tk.x_prior, tk.p_prior)
            tk.x_post, tk.p_post = put(tk.x_post, tk.p_post)
        return put(x, p)

    def _view_update(self, x, p, meas: TargetViewMeasurement):
        """Fuse one detection of the target (gated; module :mod:`~tdacm.estimation.camera`)."""
        cam = self.camera
        if cam is None:
            raise ValueError(
                "a TargetViewMeasurement needs an ExtendedKalmanFilter built with a camera"
            )
        pts = np.asarray(meas.points, float)
        if self._anchor is None or meas.t - self._view_ok_t > cam.reinit_after:
            # first view, or every view gated out for a while: (re)start from this one
            g_t = target_pose_from_view(
                pts, cam.object_points, self.camera_pose(x[: self.n]), cam.level_normal
            )
            if g_t is None:
                return x, p
            restart = self._anchor is not None
            x, p = self._set_target(g_t, x, p)
            self._view_ok_t = meas.t
            if restart:
                self.target_restarts += 1
        pred = self.view_prediction(x)
        if pred is None:
            self.views_rejected += 1
            return x, p
        x1, p1, nis = _kalman_update(x, p, pts.ravel() - pred[0], pred[1], self._r_view)
        if nis > cam.gate:
            self.views_rejected += 1
            return x, p
        self.views_fused += 1
        self._view_ok_t = max(self._view_ok_t, meas.t)
        return x1, p1

    def _measurement(self, x, meas, tk: _Tick):
        n, nx = self.n, self.nx
        sc = self.sensors
        if isinstance(meas, EncoderMeasurement):
            qs = x[n - self.n_s : n]
            lengths, dl_dq = EK.tendon_lengths_and_jacobian(qs, self._m)
            h = np.zeros((self.n_a, nx))
            h[:, n - self.n_s : n] = dl_dq
            r = np.asarray(meas.delta_length, float) - (lengths - self._l_ref)
            var = sc.encoders.variance + sc.encoders.bias**2
            return r, h, np.eye(self.n_a) * max(var, 1e-16)
        if not self.floating:
            return None
        if isinstance(meas, PoseMeasurement):
            rot = rot_zyx(x[0], x[1], x[2])
            r = np.concatenate(
                [meas.position - x[3:6], so3_log(np.ascontiguousarray(rot.T @ meas.rotation))]
            )
            h = np.zeros((6, nx))
            h[0:3, 3:6] = np.eye(3)
            h[3:6, 0:3] = euler_rate_matrix(x[0], x[1])
            pc = sc.pose
            rr = np.diag([pc.position_noise**2] * 3 + [pc.attitude_noise**2] * 3)
            return r, h, rr + np.eye(6) * 1e-14
        if isinstance(meas, ImuMeasurement):
            ic = sc.imu
            ib = 3 * n
            q, qd = x[:n], x[n : 2 * n]
            h = np.zeros((6, nx))
            w_hat = EK.body_rate(q, qd) + x[ib : ib + 3]
            h[0:3, n : n + 3] = euler_rate_matrix(q[0], q[1])
            h[0:3, ib : ib + 3] = np.eye(3)
            eps = 1e-7
            for j in range(2):
                qq = q.copy()
                qq[j] += eps
                h[0:3, j] = (EK.body_rate(qq, qd) - EK.body_rate(q, qd)) / eps
            rows = [0, 1, 2]
            r_list = [meas.gyro - w_hat]
            rr = [ic.gyro_noise**2] * 3
            if tk.u is not None and tk.jac is not None:
                qdd = self._qdd(x, tk.u)
                f_hat = EK.specific_force(q, qdd, self._gravity) + x[ib + 3 : ib + 6]
                rot = rot_zyx(q[0], q[1], q[2])
                h[3:6, : 2 * n] = rot.T @ tk.jac[3:6, :]
                h[3:6, 2 * n + 3 : 2 * n + 6] = rot.T
                h[3:6, ib + 3 : ib + 6] = np.eye(3)
                f0 = EK.specific_force(q, qdd, self._gravity)
                for j in range(3):
                    qq = q.copy()
                    qq[j] += eps
                    h[3:6, j] += (EK.specific_force(qq, qdd, self._gravity) - f0) / eps
                rows += [3, 4, 5]
                r_list.append(meas.accel - f_hat)
                rr += [ic.accel_noise**2 + self.config.accel_model_error**2] * 3
            return np.concatenate(r_list), h[rows], np.diag(rr) + np.eye(len(rows)) * 1e-14
        raise ValueError(f"unknown measurement {meas!r}")

    # ------------------------------------------------------------------ step
    def step(self, t: float, u_applied, measurements=()) -> StateEstimate:
        """Advance to time ``t`` with the input ``u_applied`` held since the previous step
        (``None`` at the reset time: update only) and fuse ``measurements`` (any mix of pose,
        IMU and encoder measurements, possibly captured earlier than ``t``)."""
        w0 = time.perf_counter()
        if not self._hist:
            raise RuntimeError("call reset() before step()")
        t = float(t)
        last = self._hist[-1]
        new_tick = t > last.t + 1e-9
        if not new_tick and t < last.t - 1e-9:
            raise ValueError(f"time went backwards: {t} < {last.t}")
        # a measurement belongs to the tick nearest its capture time (half a period either side)
        if new_tick:
            tol = 0.5 * (t - last.t)
        elif len(self._hist) > 1:
            tol = 0.5 * (last.t - self._hist[-2].t)
        else:
            tol = 1e-6
        current, earliest, late = [], len(self._hist), {}
        for m in measurements:
            if new_tick and m.t > last.t + tol:
                current.append(m)
                continue
            j = int(np.argmin([abs(tk.t - m.t) for tk in self._hist]))
            if abs(self._hist[j].t - m.t) > tol + 1e-9:
                self.dropped_late += 1  # older than the kept history
                continue
            self._hist[j].meas.append(m)
            late.setdefault(j, []).append(m)
            earliest = min(earliest, j)
        if earliest < len(self._hist):
            # the late ones on top of the posterior of their tick (sequential updates), then
            # the later ticks re-run from their re-propagated priors with all their updates
            self._update_tick(self._hist[earliest], late[earliest])
            for i in range(earliest + 1, len(self._hist)):
                self._repropagate(self._hist[i - 1], self._hist[i])
                self._update_tick(self._hist[i])
        if new_tick:
            u = np.asarray(u_applied, float)
            if u.shape != (self.system.n_u,):
                raise ValueError(f"u_applied must have {self.system.n_u} entries, got {u.shape}")
            tk = self._predict(last, t, u)
            tk.meas = current
            self._update_tick(tk)
            self._hist.append(tk)
            while len(self._hist) > 1 and self._hist[1].t < t - self.config.max_delay - 1e-9:
                self._hist.pop(0)
        if not np.all(np.isfinite(self._hist[-1].x_post)):
            raise EstimatorDiverged("estimator diverged (non-finite state)")
        self.timings.append(time.perf_counter() - w0)
        return self.estimate
