"""The servo block: dual-camera visual servoing (paper, "Dual-Camera Visual Servoing").

Per period, from the perception of both cameras and the state estimate:

1. **mode switch** (:class:`~tdacm.control.ModeSwitch`): IBVS while the target is in C_L's
   view, recovery when it is lost (margin and hysteresis);
2. **IBVS** (local camera): the normalized points of C_L are mapped to the virtual camera C_V
   (roll/pitch compensation, eq. (18)), the six advanced features and their interaction
   matrix give the twist ``v = -lambda J_img^+ e`` of C_V (eqs. (19)-(21)), and the tip-level
   mapping ``qdot_d = (J_L^L)^+ Ad v`` over the commanded coordinates (roll and pitch are not
   commanded) gives the joint rates; **command shaping** (ours, documented in
   docs/control.md) limits them, ramps them up after IBVS engages and smooths them with a
   first-order filter; ``q_d`` is their integral;
3. **recovery** (global camera): one C_G snapshot gives the target pose (IPPE), the planner
   solves for the rod configuration ``q_s^d`` that brings the target into C_L's view, and a
   cubic trajectory drives the rod there while the drone holds its pose. If no C_G frame is
   available when recovery starts, the servo holds and requests one (``request_global``).

:class:`VisualServo` implements the servo protocol of :mod:`tdacm.loop.protocols`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._linalg import solve as _solve
from ..control import (
    CubicTrajectory,
    Mode,
    ModeSwitch,
    estimate_target_pose,
    plan_rod_configuration,
)
from ..control.planner import rod_columns
from ..lie.se3 import adjoint_pair, expmap, so3_log
from ..vision.features import _min_edge2, advanced_features
from ..vision.ibvs import IBVSController
from ..vision.mounts import tip_camera_pose
from ..vision.target_filter import TargetFilter
from ..vision.tip import rates_from_jacobian
from ..vision.virtual import virtual_points, virtual_transform
from .config import IbvsConfig, RecoveryConfig
from .data import GlobalView, LocalView, ServoCommand, StateEstimate

MODE_CODES = {Mode.IBVS: 0, Mode.RECOVERY: 1}


def normalized_rmse(points, desired) -> float:
    """``sqrt(mean_k |p_k - p_k^d|^2)`` over the four points (normalized coordinates)."""
    if points is None:
        return float("nan")
    d = np.asarray(points) - np.asarray(desired)
    s = np.sum(d * d, axis=1)
    # np.mean is this sum over the count; the plain form skips its overhead (4 calls a period)
    return math.sqrt(s.sum() / s.shape[0]) if s.shape[0] else float("nan")


class VisualServo:
    """The paper's dual-camera servo (module docstring).

    Parameters
    ----------
    system:
        The controller's view of the robot's kinematics (Jacobians, poses).
    local_camera, global_camera:
        The controller's camera models (intrinsics used to interpret pixels).
    target:
        The fiducial target (its geometry is known to the controller).
    tip_mount, drone_mount:
        ``g_{C_L}^L`` and ``g_{C_G}^b``.
    desired_points, desired_depths:
        The reference snapshot in C_V (C_L for a fixed base).
    config:
        The ``[ibvs]`` record (:class:`~.config.IbvsConfig`): gain ``lambda``, interaction
        matrix, virtual-camera form, the ``J_img`` solve (:func:`~tdacm.vision.ibvs.robust_solve`;
        ``floor = 0``: the plain inverse) and the command shaping (``max_joint_rate``, ...).
    recovery:
        The ``[recovery]`` record (:class:`~.config.RecoveryConfig`): the mode switch and the
        recovery planner.
    rod:
        The arm carrying C_L (a robot with several arms, :class:`~.arms.ArmsServo`).
    """

    def __init__(
        self,
        system,
        local_camera,
        global_camera,
        target,
        tip_mount,
        drone_mount,
        desired_points,
        desired_depths,
        config: IbvsConfig | None = None,
        recovery: RecoveryConfig | None = None,
        rod: int = 0,
    ):
        self.system = system
        self.rod = int(rod)
        self.local_camera = local_camera
        self.global_camera = global_camera
        self.target = target
        self.tip_mount = np.asarray(tip_mount, float)
        self.drone_mount = np.asarray(drone_mount, float)
        self.desired_points = np.asarray(desired_points, float)
        self.desired_depths = np.asarray(desired_depths, float)
        self.config = config = config or IbvsConfig()
        self.ibvs = IBVSController(
            self.desired_points, self.desired_depths, gain=config.gain, mode=config.mode,
            floor=config.floor, solver=config.solver,
        )  # fmt: skip
        self.compensation = config.compensation
        self.shaping = config  # the command shaping's limits and time constants
        self.recovery = recovery or RecoveryConfig()
        s = system
        n = s.n
        self.n = n
        self._cmd = np.array([i for i in range(n) if not (s.floating and i < 2)])
        lim = np.full(n, self.shaping.max_joint_rate)
        if s.floating:
            lim[3:5] = self.shaping.max_drone_speed
            lim[5] = self.shaping.max_vertical_speed
        self._lim = lim
        self._ad_mount, self._ad_mount_inv = adjoint_pair(self.tip_mount)
        # the coordinates of this servo's rod's strains in q (all strains for one arm)
        cols = slice(0, s.n_s) if s.n_rods == 1 else rod_columns(s, self.rod)
        base = n - s.n_s
        self._strains = np.arange(base + cols.start, base + cols.stop)
        self.switch = ModeSwitch(
            local_camera, self.recovery.margin_px, self.recovery.confirm, self.recovery.lose
        )
        self.reset(np.zeros(n))

    # ------------------------------------------------------------------ state
    def reset(self, q0, first_view: LocalView | None = None) -> None:
        """Start from configuration ``q0`` (the estimate); the initial mode is IBVS when the
        first C_L view has the target inside the margin, recovery otherwise."""
        s = self.system
        seen = first_view is not None and first_view.found
        start = Mode.IBVS if seen and self.switch.inside(first_view.pixels) else Mode.RECOVERY
        self.switch.reset(start)
        self.q_d = np.array(q0, float)
        if s.floating:
            self.q_d[:2] = 0.0
        self.qd_d = np.zeros(self.n)
        self.ibvs_start = 0.0
        self.traj = None

    @property
    def mode(self) -> str:
        return self.switch.mode

    # ------------------------------------------------------------------ pieces
    def local_camera_pose(self, q) -> np.ndarray:
        """``g_{C_L} = g_L(q) g_{C_L}^L`` (:func:`~tdacm.vision.tip_camera_pose`; the system keeps
        the tip pose of the last configurations, asked for several times a period)."""
        return tip_camera_pose(self.system, q, self.tip_mount, self.rod)

    def to_virtual(self, view: LocalView, q):
        """Points and depths of the view in C_V (eq. (18)); unchanged for a fixed base."""
        if not self.system.floating:
            return view.points, view.depths
        gv = virtual_transform(self.system.base_pose(q), self.local_camera_pose(q))
        xy, zv = virtual_points(view.points, gv, view.depths, self.compensation, True)
        # "exact" returns z^{C_V}; the other forms the ratio z^{C_V} / z^{C_L}
        return xy, (zv if self.compensation == "exact" else zv * view.depths)

    def observe(self, view: LocalView, q):
        """``(points, depths, features, error, rmse)`` of a view in C_V (no state change)."""
        points, depths = self.to_virtual(view, q)
        rmse = normalized_rmse(points, self.desired_points)
        f = advanced_features(points)
        return points, depths, f, self.ibvs.error(points, features=f), rmse

    def joint_rates(self, q, twist) -> np.ndarray:
        """``qdot_d = (J_L^L[:, cmd])^+ Ad(g_{C_L}^L) v`` over the commanded coordinates, with
        the Jacobian of the virtual-camera chain (roll and pitch set to zero) for a floating
        base (:func:`~tdacm.vision.camera_joint_rates` with ``jacobian_at="virtual"``)."""
        return rates_from_jacobian(self.task_jacobian(q), self._ad_mount @ twist, self._cmd)

    def task_jacobian(self, q) -> np.ndarray:
        """``J_L^L`` (6 x n) of this servo's arm at ``q`` with roll and pitch set to zero for a
        floating base (the virtual-camera chain's Jacobian)."""
        qv = q
        if self.system.floating:
            qv = q.copy()
            qv[:2] = 0.0
        s = self.system
        return s.tip_jacobian(qv) if self.rod == 0 else s.tip_jacobian(qv, self.rod)

    def shape(self, rates: np.ndarray, t: float, dt: float) -> None:
        """Limit, ramp and filter the IBVS joint rates into ``qd_d``; integrate ``q_d``."""
        sp = self.shaping
        cmd = self._cmd
        t_ib = t - self.ibvs_start
        ramp = 1.0 - np.exp(-t_ib / sp.soft_start) if sp.soft_start > 0 else 1.0
        scale = max(1.0, float(np.max(np.abs(rates[cmd]) / self._lim[cmd])))
        new_qd = np.zeros(self.n)
        new_qd[cmd] = rates[cmd] / scale
        # the first-order filter starts from the recovery's last joint rates (smooth hand-over)
        # and keeps the IBVS from exciting the coupled roll/strain mode (~2 Hz)
        a_f = min(1.0, dt / sp.rate_filter) if sp.rate_filter > 0 else 1.0
        self.qd_d = self.qd_d + a_f * (ramp * new_qd - self.qd_d)
        self.q_d = self.q_d + self.qd_d * dt

    def plan(self, q, t, gview: GlobalView):
        """Recovery plan from one C_G snapshot."""
        s = self.system
        g_t_cg = estimate_target_pose(gview.detection, self.global_camera, self.target)
        p_body = self.drone_mount @ g_t_cg[:, 3]
        q_s_now = q[self._strains]
        plan = plan_rod_configuration(
            s, p_body[:3], self.tip_mount, q_s_now, z_min=self.local_camera.near, rod=self.rod
        )
        traj = CubicTrajectory.with_speed(q_s_now, plan.q_s, t, self.recovery.max_speed)
        return plan, traj

    def transition(self, prev: str, mode: str, t: float) -> str | None:
        """The event of a mode change: IBVS engaging (its ramp restarts; ``q_d`` continues from
        the recovery reference, a continuous error) or the target lost."""
        if prev == Mode.RECOVERY and mode == Mode.IBVS:
            self.ibvs_start = t
            self.traj = None
            return "ibvs engaged"
        if prev == Mode.IBVS and mode == Mode.RECOVERY:
            return "target lost"
        return None

    def missed_snapshot(self, t: float, gview: GlobalView | None) -> str | None:
        """Recovery needs a C_G snapshot and has none this period: the failure message, or
        ``None`` to hold and ask again (C_G not read this period)."""
        return "recovery: target not seen by C_G" if gview is not None else None

    def recover(self, t: float, q, gview: GlobalView | None, qdd_d) -> tuple[str, object]:
        """The recovery branch (paper, "Dual-Camera Visual Servoing"): plan from one C_G
        snapshot, then follow the cubic trajectory of the rod while the drone holds its pose.
        Returns ``("hold", failure or None)`` when no snapshot is available (``qd_d`` zeroed),
        ``("failed", message)`` when planning fails, else ``("ok", plan_info or None)`` with
        ``q_d``, ``qd_d`` and ``qdd_d`` (in place) set from the trajectory."""
        s, n = self.system, self.n
        plan_info = None
        if self.traj is None:
            if gview is None or not gview.found:
                self.qd_d = np.zeros(n)
                return "hold", self.missed_snapshot(t, gview)
            try:
                plan, self.traj = self.plan(q, t, gview)
            except ValueError as exc:
                return "failed", f"recovery planning failed: {exc}"
            plan_info = {
                "t": t,
                "q_s_d": plan.q_s.tolist(),
                "point_local": plan.point_local.tolist(),
                "cost": plan.cost,
                "success": plan.success,
                "duration": self.traj.duration,
            }
            self.q_d = np.array(q, float)
            if s.floating:
                self.q_d[:2] = 0.0
        qs_d, qsd_d, qsdd_d = self.traj(t)
        cols = self._strains
        self.q_d[cols] = qs_d
        self.qd_d = np.zeros(n)
        self.qd_d[cols] = qsd_d
        qdd_d[cols] = qsdd_d
        return "ok", plan_info

    def recovery_branch(self, t, q, gview, mode, qdd_d, twist, features, error, points, rmse,
                        event, **extra):  # fmt: skip
        """The recovery part of a period, shared by both servos: ``(command, plan, event)``
        with ``command`` the :class:`ServoCommand` that ends the period when the recovery holds
        (C_G requested; ``extra`` fields added) or failed, else ``None``."""
        status, info = self.recover(t, q, gview, qdd_d)
        if status == "hold":
            return ServoCommand(
                mode, self.q_d.copy(), self.qd_d.copy(), qdd_d, twist, features, error,
                points, rmse, request_global=True, event=event, failure=info, **extra,
            ), None, event  # fmt: skip
        if status == "failed":
            return ServoCommand(
                mode, self.q_d.copy(), np.zeros(self.n), qdd_d, twist, features, error,
                points, rmse, failure=info,
            ), None, event  # fmt: skip
        if info is not None:
            return None, info, "recovery planned"
        return None, None, event

    # ------------------------------------------------------------------ the step
    def step(
        self,
        t: float,
        dt: float,
        view: LocalView,
        gview: GlobalView | None,
        est: StateEstimate,
        twist: np.ndarray | None = None,
    ) -> ServoCommand:
        """One servo period. ``twist`` (optional) replaces the IBVS twist (an external
        command, e.g. a learning agent's action); shaping and the mapping still apply."""
        return self.command(t, dt, est.q, gview, twist, *self.perceive(t, dt, view, est))

    def perceive(self, t: float, dt: float, view: LocalView, est: StateEstimate) -> tuple:
        """The first part of a period: the mode switch on the view and the view in C_V.
        Returns ``(mode, event, seen, ibvs_twist, points, features, error, rmse, extra)``
        for :meth:`command` (``ibvs_twist()`` computes the IBVS twist when it is used)."""
        q = est.q
        prev = self.switch.mode
        mode = self.switch.update(view.pixels if view.found else None)
        event = self.transition(prev, mode, t)
        points = depths = features = error = None
        rmse = float("nan")
        if view.found:
            points, depths, features, error, rmse = self.observe(view, q)
        return (
            mode, event, view.found, lambda: self.ibvs.twist(points, depths, error=error),
            points, features, error, rmse, {},
        )  # fmt: skip

    def follow_twist(self, q, twist, t: float, dt: float) -> np.ndarray:
        """IBVS mode: joint rates of ``twist``, shaped into ``qd_d`` and integrated into
        ``q_d``; returns ``qdd_d`` (zero: IBVS gives rates only, ``qdd_r = -beta edot``)."""
        return self.follow_rates(q, self.joint_rates(q, twist), t, dt)

    def follow_rates(self, q, rates, t: float, dt: float) -> np.ndarray:
        """IBVS mode on joint rates already mapped (:meth:`follow_twist`'s second half)."""
        self.shape(rates, t, dt)
        return np.zeros(self.n)

    def command(self, t, dt, q, gview, twist, mode, event, seen, ibvs_twist, points, features,
                error, rmse, extra) -> ServoCommand:  # fmt: skip
        """The end of a period, the same for both servos: IBVS on ``twist`` (if given) or on
        ``ibvs_twist()`` when the target is ``seen``, the recovery branch, or a hold while the
        target is not seen in IBVS mode. ``extra``: fields added to every command."""
        n = self.n
        out_twist = np.zeros(6)
        qdd_d = np.zeros(n)
        plan_info = None
        if mode == Mode.IBVS and (seen or twist is not None):
            out_twist = np.asarray(ibvs_twist() if twist is None else twist, float)
            qdd_d = self.follow_twist(q, out_twist, t, dt)
        elif mode == Mode.RECOVERY:
            ended, plan_info, event = self.recovery_branch(
                t, q, gview, mode, qdd_d, out_twist, features, error, points, rmse, event, **extra
            )
            if ended is not None:
                return ended
        else:  # IBVS mode but the target is not seen (or nothing fused yet): hold
            self.qd_d = np.zeros(n)
        return ServoCommand(
            mode, self.q_d.copy(), self.qd_d.copy(), qdd_d, out_twist, features, error, points,
            rmse, event=event, plan=plan_info, **extra,
        )  # fmt: skip


@dataclass(frozen=True)
class PredictedView:
    """The target's feature points predicted in the servo camera (C_V, or C_L for a held
    base) from the world-frame estimate, with their features, error and twist (``twist`` is
    ``None`` before the first frame); ``pixels_local``: the same points predicted in the real
    camera C_L (pixels), for the field-of-view test of the mode switch."""

    points: np.ndarray | None = None
    depths: np.ndarray | None = None
    features: np.ndarray | None = None
    error: np.ndarray | None = None
    twist: np.ndarray | None = None
    pixels_local: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return self.twist is not None


class RobustServo(VisualServo):
    """Visual servo on features predicted from a world-frame estimate of the static target
    (docs/control.md, "Robust servo"; the servo protocol of :mod:`tdacm.loop.protocols`).

    Per period:

    1. a C_L view (possibly ``k`` periods late) is fused into the
       :class:`~tdacm.vision.TargetFilter` with the C_L pose of its *capture* time, computed
       from the state estimate of that period (latency compensation);
    2. the four feature points are predicted in the virtual camera C_V at the current
       estimated pose from the (smoothed) target estimate - defined through missed frames;
    3. the paper's advanced features and interaction matrix, with the well-conditioned solve
       (:func:`~tdacm.vision.ibvs.robust_solve`, singular values floored at ``floor``), give
       the twist; joint rates and shaping as :class:`VisualServo`, plus the acceleration
       feed-forward of the filtered rate and a leak of ``q_d`` toward ``q_hat``;
    4. the target is lost only if nothing was fused for ``lost_timeout`` s or the predicted
       points leave C_L's image for ``recovery.lose`` periods; a recovery that finds no
       target in C_G holds and retries for ``lost_timeout`` s before giving up.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        c = self.config
        self.target_filter = TargetFilter(
            self.local_camera,
            self.target.feature_points,
            pixel_sigma=c.filter_pixel_sigma,
            window=c.filter_window,
            level_prior=np.radians(c.target_level_prior_deg),
            level_normal=tuple(c.target_level_normal),
        )
        self.smoothing = float(c.filter_smoothing)
        self.target_pose = None  # smoothed estimate used by the prediction
        # feed-forward and leak are for the flying base, whose position lags the reference
        # through the attitude loop (measured on paper-in-fov); a held rod tracks directly
        self._flying = bool(self.system.floating)
        self._leak = self._cmd if self._flying else np.zeros(0, int)

    def reset(self, q0, first_view: LocalView | None = None) -> None:
        super().reset(q0, first_view)
        if hasattr(self, "target_filter"):
            self.target_filter.reset()
        self.target_pose = None
        self._poses = {}  # capture time -> C_L pose (from the estimate of that period)
        self._last_fused = -np.inf
        self._last_seen = None
        self._cg_missed = None

    def missed_snapshot(self, t: float, gview: GlobalView | None) -> str | None:
        """C_G missed the target: hold and retry for ``lost_timeout`` s before giving up."""
        if gview is None:
            return None
        self._cg_missed = t if self._cg_missed is None else self._cg_missed
        if t - self._cg_missed >= self.recovery.lost_timeout:
            return "recovery: target not seen by C_G"
        return None

    def recover(self, t: float, q, gview: GlobalView | None, qdd_d) -> tuple[str, object]:
        if self.traj is None and gview is not None and gview.found:
            self._cg_missed = None
        return super().recover(t, q, gview, qdd_d)

    def servo_camera_pose(self, q) -> np.ndarray:
        """World pose of the servo camera: C_V for a floating base, C_L for a fixed one."""
        g_c = self.local_camera_pose(q)
        if not self.system.floating:
            return g_c
        from ..vision.virtual import virtual_pose

        return virtual_pose(self.system.base_pose(q), g_c)

    def predict_target(self, dt: float) -> None:
        """Advance the smoothed target pose toward the filter's estimate by one period: a
        first-order filter of time constant ``smoothing`` on SE(3). The target is static, so
        this adds no lag to the camera's motion (which enters through the exact camera pose);
        it only spreads the estimate's corrections - large along the weakly observable
        directions while few frames are fused - over time, so that they do not kick the
        TD-ACM."""
        self.target_filter.predict(dt)
        est = self.target_filter.pose
        if est is None:  # not seen yet, or the filter restarted: keep the last estimate
            return
        if self.target_pose is None or self.smoothing == 0:
            self.target_pose = est.copy()
            return
        a = min(1.0, dt / self.smoothing)
        d = _solve(self.target_pose, est)  # g_s^-1 g_T
        w = a * so3_log(np.ascontiguousarray(d[:3, :3]))
        step = expmap(np.array([w[0], w[1], w[2], 0.0, 0.0, 0.0]))  # rotation by a * log(R)
        step[:3, 3] = a * d[:3, 3]
        self.target_pose = self.target_pose @ step

    def predicted_view(self, servo_pose, camera_pose=None) -> PredictedView:
        """Features, error and twist of the servo camera at ``servo_pose`` (4x4 world pose of
        C_V, or of C_L for a held base) predicted from the smoothed target estimate;
        ``camera_pose`` (C_L) adds the predicted C_L pixels."""
        if self.target_pose is None:
            if self.target_filter.pose is None:
                return PredictedView()
            self.target_pose = self.target_filter.pose.copy()
        xy, z = self.target_filter.points_in(servo_pose, self.target_pose)
        # behind the camera, or so far that the corners coincide (an estimate thrown off by
        # large pixel noise): no features, the target counts as not seen this period
        if np.any(z <= 0) or _min_edge2(xy) < 1e-24:
            return PredictedView()
        pix = None
        if camera_pose is not None:
            xl, zl = self.target_filter.points_in(camera_pose, self.target_pose)
            pix = self.local_camera.denormalize_checked(xl) if np.all(zl > 0) else None
        f, e, v = self.ibvs.features_error_twist(xy, z)
        return PredictedView(xy, z, f, e, v, pix)

    def camera_pose_covariance(self, q, P) -> np.ndarray | None:
        """Covariance (6 x 6, ``[w; v]`` in C_L) of the C_L pose computed from an estimate
        with covariance ``P`` (``[q, qd]``): ``J_C P_qq J_C^T`` with ``J_C = Ad(g_{C_L}^L)^-1
        J_L^L(q)`` (eq. (10)); ``None`` for the true state."""
        if P is None:
            return None
        n = self.n
        j = self._ad_mount_inv @ self.system.tip_jacobian(q)
        c = j @ np.asarray(P)[:n, :n] @ j.T
        return 0.5 * (c + c.T)

    def _fuse(self, t: float, view: LocalView, est: StateEstimate) -> None:
        key = round(t, 9)
        q = est.q
        self._poses[key] = (self.local_camera_pose(q), self.camera_pose_covariance(q, est.P))
        if view.found and view.t_capture > self._last_fused:
            tc = round(view.t_capture, 9)
            pose = self._poses.get(tc)
            if pose is None:  # capture before the first period we saw: nearest stored
                pose = self._poses[min(self._poses, key=lambda k: abs(k - tc))]
            self._last_fused = view.t_capture
            if self.target_filter.update_checked(view.pixels, *pose):
                self._last_seen = view.t_capture
            for k in [k for k in self._poses if k < tc]:
                del self._poses[k]
        if len(self._poses) > 64:  # no view for a long time: keep the recent poses only
            for k in sorted(self._poses)[:-64]:
                del self._poses[k]

    def perceive(self, t: float, dt: float, view: LocalView, est: StateEstimate) -> tuple:
        """As :meth:`VisualServo.perceive`, on the features predicted from the target
        estimate (the view is fused first; the mode switch watches the predicted C_L pixels
        while in IBVS)."""
        q = est.q
        self._fuse(t, view, est)
        self.predict_target(dt)
        g_c = self.local_camera_pose(q)
        ps = self.predicted_view(self.servo_camera_pose(q), g_c)
        # what was measured, in C_V (logged only)
        rmse_meas = float("nan")
        if view.found:
            try:
                # the RMSE only: the features and the error of the measured view are not used
                rmse_meas = normalized_rmse(self.to_virtual(view, q)[0], self.desired_points)
            except ValueError:
                pass
        prev = self.switch.mode
        if prev == Mode.IBVS:
            ok = (
                ps.valid
                and self._last_seen is not None
                and t - self._last_seen <= self.recovery.lost_timeout
                and ps.pixels_local is not None
                and bool(np.all(self.local_camera.pixels_in_image_checked(ps.pixels_local, 0.0)))
            )
            mode = self.switch.update(ps.pixels_local if ok else None)
        else:
            mode = self.switch.update(view.pixels if view.found else None)
        event = self.transition(prev, mode, t)
        rmse = normalized_rmse(ps.points, self.desired_points) if ps.valid else float("nan")
        extra = {"rmse_measured": rmse_meas, "target_pose": self.target_pose}
        return (
            mode, event, ps.valid, lambda: ps.twist, ps.points, ps.features, ps.error, rmse, extra,
        )  # fmt: skip

    def follow_rates(self, q, rates, t: float, dt: float) -> np.ndarray:
        """As :meth:`VisualServo.follow_rates`, plus the acceleration feed-forward of the
        filtered rate and the leak of ``q_d`` toward ``q_hat``."""
        r = self.config
        qdd_d = np.zeros(self.n)
        qd_prev = self.qd_d.copy()
        self.shape(rates, t, dt)
        if r.accel_feedforward and self._flying:
            # the low-level loop follows the deceleration instead of lagging into an
            # overshoot (paper: qdd_d = 0)
            qdd_d = (self.qd_d - qd_prev) / dt
        if r.reference_leak > 0:
            # q_d is only an integrated rate; the vision loop closes on the actual pose,
            # so pull q_d toward q_hat (no wind-up while the plant lags)
            c = self._leak
            self.q_d[c] += r.reference_leak * dt * (q[c] - self.q_d[c])
        return qdd_d
