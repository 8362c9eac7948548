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
from typing import NamedTuple

import numpy as np
from numba import njit

from .._linalg import SVD_PINV, svd_solve
from .._linalg import solve as _solve
from ..control import (
    CubicTrajectory,
    Mode,
    ModeSwitch,
    estimate_target_pose,
    plan_rod_configuration,
)
from ..control.planner import (
    IPPE_ORDER,
    PLAN_BOUND,
    plan_kernel,
    rod_columns,
    square_corners,
    square_pose,
)
from ..lie.se3 import adjoint_pair, expmap, so3_log
from ..vision.camera import CameraParams, all_in_image
from ..vision.features import advanced_features, min_edge2, min_edge2_of
from ..vision.ibvs import MODES, IBVSController, ibvs_law
from ..vision.ippe import canonical_frame
from ..vision.mounts import (
    base_pose_into,
    inv4,
    mul4,
    rod_steps,
    tip_camera_pose,
    tip_camera_pose_into,
    tip_jacobian_into,
)
from ..vision.target_filter import (
    TargetFilter,
    TargetFilterParams,
    TargetFilterState,
    filter_reset,
    points_in_kernel,
)
from ..vision.target_filter import filter_update as _filter_update
from ..vision.targets import ArucoMarker
from ..vision.tip import rates_from_jacobian
from ..vision.virtual import (
    EXACT,
    METHODS,
    BehindVirtualCamera,
    virtual_points,
    virtual_points_into,
    virtual_transform,
    virtual_transform_into,
)
from .config import IbvsConfig, RecoveryConfig
from .data import GlobalView, LocalView, ServoCommand, ServoEvent, StateEstimate
from .perception import perceive

MODE_CODES = {Mode.IBVS: 0, Mode.RECOVERY: 1}
#: the C_L poses the robust servo keeps (a frame is fused with its capture period's: the
#: largest latency it compensates is one less)
FILTER_HISTORY = 64
_NO_UV = np.zeros((4, 2))
_NO_Z = np.ones(4)
_NO_TWIST = np.full(6, np.nan)


def normalized_rmse(points, desired) -> float:
    """``sqrt(mean_k |p_k - p_k^d|^2)`` over the four points (normalized coordinates)."""
    if points is None:
        return float("nan")
    d = np.asarray(points) - np.asarray(desired)
    s = np.sum(d * d, axis=1)
    # np.mean is this sum over the count; the plain form skips its overhead (4 calls a period)
    return math.sqrt(s.sum() / s.shape[0]) if s.shape[0] else float("nan")


def frame_arguments(view: LocalView, est: StateEstimate, dt: float, robust: bool) -> tuple:
    """The period's arguments of :func:`servo_perceive` from the perceived C_L ``view`` and
    the estimate ``est``: ``(q, p_qq, found, uv, xy, z, capture)`` (``p_qq`` the estimate's
    covariance of ``q`` for the robust servo, zeros on the true state; a frame not found as
    placeholders)."""
    c = np.ascontiguousarray
    q = c(est.q, dtype=float)
    n = q.shape[0]
    found = bool(view.found)
    if found:
        uv, xy = c(view.pixels, dtype=float), c(view.points, dtype=float)
        z = c(view.depths, dtype=float)
        capture = int(round(view.t_capture / dt))
    else:
        uv, xy, z, capture = _NO_UV, _NO_UV, _NO_Z, -1
    est_p = getattr(est, "P", None)
    p_qq = np.zeros((n, n)) if est_p is None or not robust else c(np.asarray(est_p)[:n, :n])
    return q, p_qq, found, uv, xy, z, capture


def twist_argument(twist) -> np.ndarray:
    """The external twist argument of :func:`servo_command`: ``twist`` (6,), or NaNs for the
    servo's own."""
    return _NO_TWIST if twist is None else np.ascontiguousarray(twist, dtype=float)


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
        self._setup()
        # the compiled step (:func:`servo_perceive`, :func:`servo_command`) runs the servos of
        # this module; the servos built on their parts (touch, several arms) run the methods
        # below
        self._compiled = type(self) in (VisualServo, RobustServo)
        self._m = s.model_arrays
        self.params = self.servo_params()
        self._n_s = int(self.params.strains[1] - self.params.strains[0])
        window = int(self.target_filter.window) if isinstance(self, RobustServo) else 0
        self.state = servo_state(self.params, n, self._n_s, window)
        self._out = ServoOut.empty(n, self._n_s)
        self._memo = None
        self._frame = None  # perceive_period's frame arguments (frame_arguments) this period
        self.reset(np.zeros(n))

    def _setup(self) -> None:
        """What a servo builds before its records (the robust servo's target filter)."""

    def servo_params(self) -> ServoParams:
        """The record of the compiled step (:class:`ServoParams`) of this servo."""
        s, cfg, rc = self.system, self.config, self.recovery
        target = self.target
        ids = tuple(getattr(target, "ids", ())) if not isinstance(target, ArucoMarker) else ()
        marker_ids = ids or (target.marker_id,)
        corners = [target.corner_points(i) for i in marker_ids]
        side = float(np.linalg.norm(corners[0][1] - corners[0][0]))
        object_2d = canonical_frame(target.feature_points)[0]
        robust = isinstance(self, RobustServo)
        if robust:
            fp = filter_record(self.target_filter, object_2d, FILTER_HISTORY)
        else:
            unused = TargetFilter(self.local_camera, target.feature_points, level_prior=0.0,
                                  window=1)  # fmt: skip
            fp = FilterParams(unused.params, object_2d, 1)
        ib = self.ibvs
        base = s.n - s.n_s
        cols = slice(0, s.n_s) if s.n_rods == 1 else rod_columns(s, self.rod)
        c = np.ascontiguousarray
        return ServoParams(
            gain=float(ib.gain), interaction=MODES.index(ib.mode), floor=float(ib.floor),
            damped=ib.solver == "damped", compensation=METHODS.index(self.compensation),
            desired_points=c(self.desired_points), desired_depths=np.array(np.broadcast_to(  # writable: the engine's type
                np.asarray(self.desired_depths, float), (4,))),
            desired_features=c(ib.desired), desired_interaction=c(ib.interaction_desired),
            camera=self.local_camera.params(), mount=c(self.tip_mount),
            ad_mount=c(self._ad_mount), mount_inv=c(np.linalg.inv(self.tip_mount)),
            ad_mount_inv=c(self._ad_mount_inv), rod=rod_steps(s, self.rod),
            strains=np.array([base + cols.start, base + cols.stop], np.int64),
            commanded=c(self._cmd, np.int64), limits=c(self._lim),
            soft_start=float(cfg.soft_start), rate_filter=float(cfg.rate_filter),
            margin_px=float(rc.margin_px), confirm=int(rc.confirm), lose=int(rc.lose),
            global_camera=self.global_camera.params(), drone_mount=c(self.drone_mount),
            square=square_corners(side), marker_centres=c([k.mean(axis=0) for k in corners]),
            largest_tag=bool(ids), max_speed=float(rc.max_speed),
            z_min=float(self.local_camera.near), bound=float(PLAN_BOUND), robust=robust,
            filter=fp, smoothing=float(cfg.filter_smoothing) if robust else 0.0,
            lost_timeout=float(rc.lost_timeout), accel_ff=bool(cfg.accel_feedforward),
            leak=float(cfg.reference_leak),
        )  # fmt: skip

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
        if getattr(self, "state", None) is not None:
            self._memo = None
            uv = first_view.pixels if seen else np.zeros((4, 2))
            servo_reset(self.params, self.state, self._m, np.ascontiguousarray(q0, dtype=float),
                        bool(seen), np.ascontiguousarray(uv, dtype=float))  # fmt: skip

    @property
    def mode(self) -> str:
        if self._compiled:
            return Mode.IBVS if self.state.mode[0] == IBVS else Mode.RECOVERY
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
        if self._compiled:
            return self.compiled_step(t, dt, view, gview, est, twist)
        return self.command(t, dt, est.q, gview, twist, *self.perceive(t, dt, view, est))

    def perceive_period(self, t, dt, view, est) -> ServoOut:
        """The first part of the period (:func:`servo_perceive`) on the view ``view`` and the
        estimate ``est``, once: asked again with the same ``view`` and ``est`` (an env's
        observation, then the period's step), it returns the same outputs."""
        memo = self._memo
        if memo is not None and memo[0] is view and memo[1] is est:
            return self._out
        p, st, out = self.params, self.state, self._out
        self._frame = frame_arguments(view, est, dt, p.robust)
        q, p_qq, found, uv, xy, z, capture = self._frame
        k = int(round(t / dt))
        servo_perceive(p, st, self._m, float(t), float(dt), k, q, p_qq, found, uv, xy, z, capture,
                       out)  # fmt: skip
        self._memo = (view, est)
        return out

    def period_view(self, t, dt, view, est, force=None) -> ServoOut:
        """The view this servo works on this period (what an env observes): its first part,
        once (:meth:`perceive_period`; the touch servo adds its law's, ``force`` its force
        reading)."""
        return self.perceive_period(t, dt, view, est)

    def compiled_step(self, t, dt, view, gview, est, twist=None) -> ServoCommand:
        """One period of the compiled step (:meth:`perceive_period`, then
        :func:`servo_command` with C_G's snapshot read when :func:`needs_global`)."""
        p, st = self.params, self.state
        c = np.ascontiguousarray
        q = c(est.q, dtype=float)
        out = self.perceive_period(t, dt, view, est)
        self._memo = None
        if out.failure[0] == BEHIND:  # eq. (18) undefined: the loop ends the run, as an outcome
            raise BehindVirtualCamera(FAILURE_REASONS[BEHIND].removeprefix("servo: "))
        offered, g_found, corners, seen = self.global_arguments(gview, out)
        tw = twist_argument(twist)
        servo_command(p, st, self._m, float(t), float(dt), q, offered, tw, g_found, corners, seen,
                      out)  # fmt: skip
        return self._command_of(out)

    def global_arguments(self, gview, out: ServoOut) -> tuple:
        """The C_G arguments of :func:`servo_command` after this period's first part ``out``:
        ``(offered, found, corners (M, 4, 2), seen (M,))``, C_G's snapshot read only when the
        step needs it (:func:`needs_global`)."""
        offered = gview is not None
        m_count = self.params.marker_centres.shape[0]
        g_found, corners, seen = False, np.zeros((m_count, 4, 2)), np.zeros(m_count, np.bool_)
        if needs_global(self.state, out, offered):
            g_found, corners, seen = self._global_corners(gview)
        return offered, g_found, corners, seen

    def _global_corners(self, gview):
        """``(found, corners (M, 4, 2), seen (M,))`` of C_G's view for :func:`servo_command`:
        each marker's detected corners (OpenCV order) in the target's marker order."""
        target = self.target
        ids = tuple(getattr(target, "ids", ())) if not isinstance(target, ArucoMarker) else ()
        ids = ids or (target.marker_id,)
        corners = np.zeros((len(ids), 4, 2))
        seen = np.zeros(len(ids), np.bool_)
        if not gview.found:
            return False, corners, seen
        det = gview.detection.corners or {}
        for i, mid in enumerate(ids):
            if mid in det:
                corners[i] = np.asarray(det[mid], float)
                seen[i] = True
        return True, corners, seen

    def _command_of(self, out: ServoOut) -> ServoCommand:
        """The :class:`~.data.ServoCommand` of the compiled step's outputs."""
        st = self.state
        mode = Mode.IBVS if out.mode[0] == IBVS else Mode.RECOVERY
        seen = bool(out.seen[0])
        event = EVENT_NAMES.get(int(out.event[0]))
        plan = None
        if out.planned[0]:
            event = "recovery planned"
            plan = {
                "t": None, "q_s_d": out.plan_qs.tolist(), "point_local": out.plan_point.tolist(),
                "cost": float(out.plan_cost[0]), "success": bool(out.plan_success[0]),
                "duration": float(out.plan_duration[0]),
            }  # fmt: skip
            plan["t"] = float(st.traj_t0[0])
        failure = FAILURE_REASONS.get(int(out.failure[0]))
        extra = {}
        if self.params.robust:
            extra = {
                "rmse_measured": float(out.rmse_measured[0]),
                "target_pose": st.target_pose.copy() if st.tp_set[0] else None,
            }
        return ServoCommand(
            mode, st.q_d.copy(), st.qd_d.copy(), out.qdd_d.copy(), out.twist.copy(),
            out.features.copy() if seen else None, out.error.copy() if seen else None,
            out.points.copy() if seen else None, float(out.rmse[0]) if seen else math.nan,
            request_global=bool(out.request[0]), event=event, plan=plan, failure=failure,
            **extra,
        )  # fmt: skip

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

    def _setup(self) -> None:
        """The target filter and the prediction's constants (before the records are built)."""
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
        if np.any(z <= 0) or min_edge2_of(xy) < 1e-24:
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


# ----------------------------------------------------------------------------- target filter
class FilterParams(NamedTuple):
    """The target filter's constants for the servo's step: ``record`` the filter's
    (:class:`~tdacm.vision.target_filter.TargetFilterParams`), ``object_2d`` (4, 2) the
    target's points in their canonical frame (the perception's), ``history`` the C_L poses
    kept (latency + 1)."""

    record: TargetFilterParams
    object_2d: np.ndarray
    history: int


def filter_record(tf, object_2d, history: int) -> FilterParams:
    """The :class:`FilterParams` of a :class:`~tdacm.vision.TargetFilter` ``tf``."""
    return FilterParams(tf.params, np.ascontiguousarray(object_2d, float), int(history))


def filter_state(window: int) -> TargetFilterState:
    return TargetFilterState.initial(window)


def filter_estimate(fs) -> tuple | None:
    """``(pose (4, 4), covariance (6, 6), rejected frames)`` of a target filter's state
    ``fs`` (copies), ``None`` before its first estimate."""
    if not fs.initialized[0]:
        return None
    return fs.pose.copy(), fs.cov.copy(), int(fs.rejected[0])


def target_estimate(servo) -> tuple | None:
    """The robust servo's estimate of the target (:func:`filter_estimate`; arm 0's with
    several arms), ``None`` for a servo without one or before its first estimate."""
    servo = getattr(servo, "arms", [servo])[0]
    if getattr(servo, "_compiled", False):
        return filter_estimate(servo.state.filter) if servo.params.robust else None
    filt = getattr(servo, "target_filter", None)
    if filt is None or not filt.initialized:
        return None
    return filt.pose.copy(), filt.P.copy(), int(filt.rejected)


@njit(cache=True)
def filter_initialized(fs):
    return fs.initialized[0]


@njit(cache=True)
def filter_update(fp, fs, uv, g_c, cov):
    return _filter_update(fp.record, fs, uv, g_c, cov)


# ============================================================================ compiled step
# The servo's per-world step over its records (the module docstring's periods), called by
# :class:`VisualServo` / :class:`RobustServo` for the block loop and by the batched engine
# (:mod:`tdacm.batch`) for every world: :func:`servo_reset`, then every period
# :func:`servo_perceive` (the view, the target filter and the mode switch) and
# :func:`servo_command` (IBVS or the recovery; C_G's snapshot is an input, read only when
# :func:`needs_global` says so).

#: the servo's mode codes (:class:`tdacm.control.Mode`)
IBVS, RECOVERY = 0, 1
#: events of a period (:class:`~.data.ServoEvent`; a recovery planned)
NO_EVENT, IBVS_ENGAGED, TARGET_LOST, RECOVERY_PLANNED = 0, 1, 2, 3
#: failures of a period: none, a point behind C_V (``Termination.BEHIND_CAMERA``), C_G does
#: not see the target, no pose from C_G's corners (``Termination.RECOVERY_FAILED``)
NO_FAILURE, BEHIND, NOT_SEEN_BY_GLOBAL, NO_POSE = 0, 1, 2, 3
#: the failures in words (the summary's ``termination_reason``, the block loop's and the
#: engine's alike)
FAILURE_REASONS = {
    BEHIND: "servo: a point lies behind the virtual camera",
    NOT_SEEN_BY_GLOBAL: "recovery: target not seen by C_G",
    NO_POSE: "recovery planning failed: the marker's corners admit no pose",
}
EVENT_NAMES = {
    IBVS_ENGAGED: ServoEvent.IBVS_ENGAGED,
    TARGET_LOST: ServoEvent.TARGET_LOST,
    RECOVERY_PLANNED: "recovery planned",
}
#: the interaction matrix of ``ibvs.mode`` (:data:`tdacm.vision.ibvs.MODES`)
CURRENT, DESIRED, MEAN = 0, 1, 2


class ServoParams(NamedTuple):
    """The servo's parameters (the record of the compiled step), for one arm's camera.

    The IBVS (``[ibvs]``): ``gain``, ``interaction`` (:data:`CURRENT`, ...), ``floor`` and
    ``damped`` (the solve), ``compensation`` (the virtual camera's form,
    :data:`tdacm.vision.virtual.EXACT`, ...), the reference snapshot in C_V
    ``desired_points`` (4, 2), ``desired_depths`` (4,), ``desired_features`` (6,),
    ``desired_interaction`` (6, 6). The camera: ``camera`` the controller's model of C_L (a
    :class:`~tdacm.vision.camera.CameraParams`), ``mount`` ``g_{C_L}^L`` (4, 4) and its adjoint
    ``ad_mount`` (6, 6), ``mount_inv``, ``ad_mount_inv``, ``rod`` the Magnus steps of its rod
    (2,) and ``strains`` the rod's strain coordinates ``[start, stop)`` in ``q``. The joint
    rates and their shaping: ``commanded`` (k,) the commanded coordinates, ``limits`` (n,)
    their rate limits, ``soft_start``, ``rate_filter`` (s). The mode switch (``[recovery]``):
    ``margin_px``, ``confirm``, ``lose``. The recovery: ``global_camera`` (C_G's model),
    ``drone_mount`` ``g_{C_G}^b``, ``square`` (4, 2) a marker's corners in its plane,
    ``marker_centres`` (M, 3) each marker's centre in the target frame, ``largest_tag`` (plan
    on the largest tag seen of a pattern), ``max_speed`` (rad/s), ``z_min`` (m, C_L's near
    plane) and ``bound`` (the plan's strain bound). The robust servo (``robust``): the target
    filter's record ``filter``, ``smoothing`` (s), ``lost_timeout`` (s), ``accel_ff``,
    ``leak`` (1/s) and ``history`` the C_L poses kept (latency + 1)."""

    gain: float
    interaction: int
    floor: float
    damped: bool
    compensation: int
    desired_points: np.ndarray
    desired_depths: np.ndarray
    desired_features: np.ndarray
    desired_interaction: np.ndarray
    camera: CameraParams
    mount: np.ndarray
    ad_mount: np.ndarray
    mount_inv: np.ndarray
    ad_mount_inv: np.ndarray
    rod: np.ndarray
    strains: np.ndarray
    commanded: np.ndarray
    limits: np.ndarray
    soft_start: float
    rate_filter: float
    margin_px: float
    confirm: int
    lose: int
    global_camera: CameraParams
    drone_mount: np.ndarray
    square: np.ndarray
    marker_centres: np.ndarray
    largest_tag: bool
    max_speed: float
    z_min: float
    bound: float
    robust: bool
    filter: FilterParams
    smoothing: float
    lost_timeout: float
    accel_ff: bool
    leak: float


class ServoState(NamedTuple):
    """The servo's state (one-element arrays for its scalars): the mode and the switch's
    counters (``good``: frames inside the margin while recovering, ``bad``: frames missed
    while servoing), when IBVS engaged (``ibvs_start``), the reference ``q_d``, ``qd_d``
    (n,), the recovery's cubic trajectory (``traj_on``, ``traj_t0``, ``traj_tf``, from
    ``traj_q0`` by ``traj_dq``, the rod's strains). The robust servo: the target filter's
    state ``filter``, the smoothed target pose ``target_pose`` (``tp_set``), the capture
    period of the last frame fused (``last_fused``, -1: none), the time of the last frame
    the filter accepted (``last_seen``, NaN: none), when C_G first missed the target in a
    recovery (``cg_missed``, NaN: none) and the C_L poses and their covariances of the last
    periods (``cam_hist`` (H, 4, 4), ``cov_hist`` (H, 6, 6)): a frame is fused with its
    capture period's."""

    mode: np.ndarray
    good: np.ndarray
    bad: np.ndarray
    ibvs_start: np.ndarray
    q_d: np.ndarray
    qd_d: np.ndarray
    traj_on: np.ndarray
    traj_t0: np.ndarray
    traj_tf: np.ndarray
    traj_q0: np.ndarray
    traj_dq: np.ndarray
    filter: TargetFilterState
    target_pose: np.ndarray
    tp_set: np.ndarray
    last_fused: np.ndarray
    last_seen: np.ndarray
    cg_missed: np.ndarray
    cam_hist: np.ndarray
    cov_hist: np.ndarray


class ServoOut(NamedTuple):
    """What the servo's step produced in a period (written by the step; one-element arrays
    for the scalars): the ``mode``, its ``event`` and a ``failure`` (:data:`NO_FAILURE`, ...),
    whether it asks C_G for the next period (``request``); whether a view is servoed on
    (``seen``: measured and perceived, or predicted by the robust servo), its points
    ``points`` (4, 2) and depths ``depths`` (4,) in the servo camera (C_V; C_L for a held
    base), their ``features``, ``error`` (angles wrapped) and IBVS ``ibvs_twist`` (6,), the
    normalized ``rmse`` to the reference and ``rmse_measured`` (the measured view's, robust
    servo), the twist applied ``twist`` (zeros when not servoing), the robust servo's
    predicted C_L pixels ``pixels`` (4, 2) (``pixels_ok``: in front of C_L) and the
    reference's acceleration ``qdd_d`` (n,); a recovery plan made this period (``planned``):
    the rod's strains ``plan_qs`` (ns,), the target in C_L ``plan_point`` (3,), its
    ``plan_cost``, ``plan_success`` and the trajectory's ``plan_duration``."""

    mode: np.ndarray
    event: np.ndarray
    failure: np.ndarray
    request: np.ndarray
    seen: np.ndarray
    points: np.ndarray
    depths: np.ndarray
    features: np.ndarray
    error: np.ndarray
    ibvs_twist: np.ndarray
    rmse: np.ndarray
    rmse_measured: np.ndarray
    twist: np.ndarray
    pixels: np.ndarray
    pixels_ok: np.ndarray
    qdd_d: np.ndarray
    planned: np.ndarray
    plan_qs: np.ndarray
    plan_point: np.ndarray
    plan_cost: np.ndarray
    plan_success: np.ndarray
    plan_duration: np.ndarray

    @classmethod
    def empty(cls, n: int, ns: int) -> ServoOut:
        z1 = lambda: np.zeros(1)  # noqa: E731
        i1 = lambda: np.zeros(1, np.int64)  # noqa: E731
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        return cls(i1(), i1(), i1(), b1(), b1(), np.zeros((4, 2)), np.zeros(4), np.zeros(6),
                   np.zeros(6), np.zeros(6), z1(), z1(), np.zeros(6), np.zeros((4, 2)), b1(),
                   np.zeros(n), b1(), np.zeros(ns), np.zeros(3), z1(), b1(), z1())  # fmt: skip


def servo_state(p: ServoParams, n: int, ns: int, window: int) -> ServoState:
    """A servo state for ``n`` coordinates, a rod of ``ns`` strains and a target filter of
    ``window`` frames (zeros: :func:`servo_reset` starts it)."""
    h = int(p.filter.history) if p.robust else 1
    z1 = lambda: np.zeros(1)  # noqa: E731
    return ServoState(
        z1(), z1(), z1(), z1(), np.zeros(n), np.zeros(n), z1(), z1(), z1(), np.zeros(ns),
        np.zeros(ns), filter_state(window if p.robust else 0), np.eye(4), z1(), z1(), z1(),
        z1(), np.zeros((h, 4, 4)), np.zeros((h, 6, 6)),
    )  # fmt: skip


@njit(cache=True)
def rmse_to(pv, dp):
    """``sqrt(mean_k |p_k - p_k^d|^2)`` over the four points (:func:`normalized_rmse`)."""
    acc = 0.0
    for k in range(4):
        dx = pv[k, 0] - dp[k, 0]
        dy = pv[k, 1] - dp[k, 1]
        acc += dx * dx + dy * dy
    return np.sqrt(acc / 4.0)


@njit(cache=True)
def switch_update(mode, counters, seen_inside, found, confirm, lose):
    """The mode switch's hysteresis (:class:`tdacm.control.ModeSwitch`): ``counters`` =
    (frames inside the margin while recovering, frames missed while servoing), updated in
    place; returns the new mode."""
    if mode == RECOVERY:
        counters[0] = counters[0] + 1 if seen_inside else 0
        if counters[0] >= confirm:
            counters[1] = 0
            return IBVS
        return RECOVERY
    counters[1] = 0 if found else counters[1] + 1
    if counters[1] >= lose:
        counters[0] = 0
        return RECOVERY
    return IBVS


@njit(cache=True)
def servo_reset(p, s, m, q0, found, uv):
    """Start from ``q0`` (the estimate): the reference at ``q0`` with a level drone, the
    initial mode IBVS when the first (ideal) C_L frame ``found`` has its pixels ``uv`` inside
    the switch's margin and its corners explicable (:func:`~.perception.perceive`), recovery
    otherwise; the target filter and the robust servo's memory cleared."""
    n = q0.shape[0]
    for i in range(n):
        s.q_d[i] = q0[i]
        s.qd_d[i] = 0.0
    if m.floating:
        s.q_d[0] = 0.0
        s.q_d[1] = 0.0
    xy = np.empty((4, 2))
    z = np.empty(4)
    seen = found and perceive(p.camera, p.filter.object_2d, uv, xy, z)
    s.mode[0] = IBVS if seen and all_in_image(p.camera, uv, p.margin_px) else RECOVERY
    s.good[0] = 0.0
    s.bad[0] = 0.0
    s.ibvs_start[0] = 0.0
    s.traj_on[0] = 0.0
    filter_reset(s.filter)
    s.tp_set[0] = 0.0
    s.last_fused[0] = -1.0
    s.last_seen[0] = np.nan
    s.cg_missed[0] = np.nan


@njit(cache=True)
def _servo_camera_pose(p, m, q, g_c, out):
    """The servo camera's world pose: C_V (eq. (18)) for a floating base, C_L for a held one."""
    if not m.floating:
        out[:, :] = g_c
        return
    g_b = np.empty((4, 4))
    base_pose_into(q, m, g_b)
    gv = np.empty((4, 4))
    virtual_transform_into(g_b, g_c, gv)  # g_{C_L}^{C_V}; C_V = C_L (g_{C_L}^{C_V})^-1
    iv = np.empty((4, 4))
    inv4(gv, iv)
    mul4(g_c, iv, out)


@njit(cache=True)
def to_virtual(p, m, q, g_c, xy, z, pv, zv):
    """Points ``xy`` (4, 2) with depths ``z`` of C_L in the servo camera (C_V, eq. (18), for a
    floating base) into ``pv``, ``zv``; False when a point maps behind C_V."""
    if not m.floating:
        pv[:, :] = xy
        zv[:] = z
        return True
    g_b = np.empty((4, 4))
    base_pose_into(q, m, g_b)
    gv = np.empty((4, 4))
    virtual_transform_into(g_b, g_c, gv)
    if not virtual_points_into(xy, z, gv, p.compensation, pv, zv):
        return False
    if p.compensation != EXACT:  # the other forms give the ratio z^{C_V} / z^{C_L}
        for k in range(4):
            zv[k] = zv[k] * z[k]
    return True


@njit(cache=True)
def _smooth_target(p, s, a):
    """The smoothed target pose toward the filter's estimate by the fraction ``a`` of one
    period: a first-order filter of time constant ``smoothing`` on SE(3)
    (:meth:`RobustServo.predict_target`)."""
    if not filter_initialized(s.filter):  # nothing fused yet, or the filter restarted
        return
    pose = s.filter.pose
    if s.tp_set[0] == 0.0 or a >= 1.0:
        s.target_pose[:, :] = pose
        s.tp_set[0] = 1.0
        return
    d = np.empty((4, 4))
    inv4(s.target_pose, d)
    d2 = np.empty((4, 4))
    mul4(d, pose, d2)
    w = a * so3_log(np.ascontiguousarray(d2[:3, :3]))
    step = expmap(np.array([w[0], w[1], w[2], 0.0, 0.0, 0.0]))
    for i in range(3):
        step[i, 3] = a * d2[i, 3]
    out = np.empty((4, 4))
    mul4(s.target_pose, step, out)
    s.target_pose[:, :] = out


@njit(cache=True)
def _camera_covariance(p, m, q, p_qq, out):
    """``J_C P_qq J_C^T`` (6 x 6, ``[w; v]`` in C_L, symmetrized) with ``J_C = Ad(g_{C_L}^L)^-1
    J_L^L(q)`` (eq. (10)): the C_L pose's covariance from an estimate's ``P_qq``."""
    n = q.shape[0]
    jl = np.empty((6, n))
    tip_jacobian_into(q, m, p.rod, jl)
    j = p.ad_mount_inv @ jl
    c = j @ p_qq @ j.T
    for a in range(6):
        for b in range(6):
            out[a, b] = 0.5 * (c[a, b] + c[b, a])


@njit(cache=True)
def servo_perceive(p, s, m, t, dt, k, q, p_qq, found, uv, xy, z, capture, out):
    """The first part of a period at time ``t`` (period ``k``) on the estimate ``q`` (with
    ``P_qq`` (n, n), zeros for the true state): the view the servo works on, the target
    filter and the mode switch, into ``out`` (a :class:`ServoOut`; ``twist``, ``qdd_d`` and the
    plan are :func:`servo_command`'s).

    The measured servo: the delivered frame (``found``, its pixels ``uv`` and their
    normalized points ``xy`` and IPPE depths ``z`` from the perception block) in C_V (eq.
    (18)). The robust servo: the frame (captured at period ``capture``) fused into the target
    filter with the C_L pose (and its covariance) of its capture period, the smoothed target
    estimate, the points predicted in the servo camera and in C_L; the switch watches the
    predicted C_L pixels while servoing. Then the features, the error and the IBVS twist
    (eqs. (19)-(21), (39)) of the view."""
    n = q.shape[0]
    out.failure[0] = NO_FAILURE
    out.event[0] = NO_EVENT
    out.request[0] = False
    out.planned[0] = False
    out.rmse[0] = np.nan
    out.rmse_measured[0] = np.nan
    out.pixels_ok[0] = False
    for i in range(6):
        out.twist[i] = 0.0
        out.features[i] = 0.0
        out.error[i] = 0.0
        out.ibvs_twist[i] = 0.0
    for i in range(n):
        out.qdd_d[i] = 0.0
    pv, zv = out.points, out.depths
    g_c = np.empty((4, 4))
    tip_camera_pose_into(q, m, p.rod, p.mount, g_c)
    prev = int(s.mode[0])
    counters = np.array([int(s.good[0]), int(s.bad[0])])
    if p.robust:
        hist = s.cam_hist.shape[0]
        s.cam_hist[k % hist] = g_c
        _camera_covariance(p, m, q, p_qq, s.cov_hist[k % hist])
        cap = max(0, capture)
        if found and cap > s.last_fused[0]:
            s.last_fused[0] = cap
            if filter_update(p.filter, s.filter, uv, s.cam_hist[cap % hist],
                             s.cov_hist[cap % hist]):  # fmt: skip
                s.last_seen[0] = cap * dt
        a = min(1.0, dt / p.smoothing) if p.smoothing > 0.0 else 1.0
        _smooth_target(p, s, a)
        valid = False
        if s.tp_set[0] != 0.0:
            g_s = np.empty((4, 4))
            _servo_camera_pose(p, m, q, g_c, g_s)
            points_in_kernel(p.filter.record.object_points, g_s, s.target_pose, pv, zv)
            valid = min_edge2(pv) >= 1e-24
            for i in range(4):
                if not zv[i] > 0.0:
                    valid = False
            if valid:
                xl = np.empty((4, 2))
                zl = np.empty(4)
                points_in_kernel(p.filter.record.object_points, g_c, s.target_pose, xl, zl)
                ok = True
                for i in range(4):
                    if not zl[i] > 0.0:
                        ok = False
                    out.pixels[i, 0] = p.camera.fx * xl[i, 0] + p.camera.cx
                    out.pixels[i, 1] = p.camera.fy * xl[i, 1] + p.camera.cy
                out.pixels_ok[0] = ok
        if found:  # what was measured, in C_V (logged)
            mv = np.empty((4, 2))
            mz = np.empty(4)
            if to_virtual(p, m, q, g_c, xy, z, mv, mz):
                out.rmse_measured[0] = rmse_to(mv, p.desired_points)
        if prev == IBVS:
            seen = (
                valid
                and out.pixels_ok[0]
                and np.isfinite(s.last_seen[0])
                and t - s.last_seen[0] <= p.lost_timeout
                and all_in_image(p.camera, out.pixels, 0.0)
            )
            ins = seen and all_in_image(p.camera, out.pixels, p.margin_px)
        else:
            seen = found
            ins = seen and all_in_image(p.camera, uv, p.margin_px)
        out.seen[0] = valid
    else:
        view = found
        if view and not to_virtual(p, m, q, g_c, xy, z, pv, zv):
            out.failure[0] = BEHIND
            view = False
        seen = found
        ins = found and all_in_image(p.camera, uv, p.margin_px)
        out.seen[0] = view
        if view and min_edge2(pv) < 1e-24:  # coincident corners: nothing to servo on
            out.failure[0] = BEHIND
            out.seen[0] = False
    mode = switch_update(prev, counters, ins, seen, p.confirm, p.lose)
    s.mode[0], s.good[0], s.bad[0] = mode, counters[0], counters[1]
    out.mode[0] = mode
    if prev == RECOVERY and mode == IBVS:  # IBVS engages: its ramp restarts
        s.ibvs_start[0] = t
        s.traj_on[0] = 0.0
        out.event[0] = IBVS_ENGAGED
    elif prev == IBVS and mode == RECOVERY:
        out.event[0] = TARGET_LOST
    if out.seen[0]:
        out.rmse[0] = rmse_to(pv, p.desired_points)
        f, e, v = ibvs_law(pv, zv, p.desired_features, p.desired_interaction,
                                p.interaction, p.gain, p.floor, p.damped)  # fmt: skip
        for i in range(6):
            out.features[i] = f[i]
            out.error[i] = e[i]
            out.ibvs_twist[i] = v[i]


@njit(cache=True)
def needs_global(s, out, offered):
    """Whether this period's :func:`servo_command` reads C_G's snapshot: a recovery without a
    trajectory yet, C_G offered this period."""
    return offered and out.mode[0] == RECOVERY and s.traj_on[0] == 0.0 and out.failure[0] == 0


@njit(cache=True)
def joint_rates(p, m, q, twist, out):
    """``qdot_d[cmd] = (J_L^L(q_v)[:, cmd])^+ Ad(g_{C_L}^L) v`` with roll and pitch of ``q_v``
    zero (the virtual-camera chain's Jacobian, :meth:`VisualServo.joint_rates`) into ``out``."""
    n = q.shape[0]
    qv = q.copy()
    if m.floating:
        qv[0] = 0.0
        qv[1] = 0.0
    jac = np.empty((6, n))
    tip_jacobian_into(qv, m, p.rod, jac)
    tip = np.zeros(6)
    for i in range(6):
        acc = 0.0
        for c in range(6):
            acc += p.ad_mount[i, c] * twist[c]
        tip[i] = acc
    cmd = p.commanded
    jc = np.empty((6, cmd.shape[0]))
    for i in range(6):
        for c in range(cmd.shape[0]):
            jc[i, c] = jac[i, cmd[c]]
    x = svd_solve(jc, tip, SVD_PINV, 1e-8)
    for i in range(n):
        out[i] = 0.0
    for c in range(cmd.shape[0]):
        out[cmd[c]] = x[c]


@njit(cache=True)
def shape(p, s, rates, t, dt):
    """Limit, ramp and filter the joint rates into ``qd_d``; integrate ``q_d`` (command
    shaping, docs/control.md): the rates scaled to their limits, a ramp of time constant
    ``soft_start`` after IBVS engages, a first-order filter of ``rate_filter`` (it starts from
    the recovery's last rates: a smooth hand-over, and keeps the IBVS from exciting the
    coupled roll/strain mode, ~2 Hz)."""
    cmd = p.commanded
    t_ib = t - s.ibvs_start[0]
    ramp = 1.0 - np.exp(-t_ib / p.soft_start) if p.soft_start > 0.0 else 1.0
    scale = 1.0
    for c in range(cmd.shape[0]):
        scale = max(scale, abs(rates[cmd[c]]) / p.limits[cmd[c]])
    a_f = min(1.0, dt / p.rate_filter) if p.rate_filter > 0.0 else 1.0
    n = s.q_d.shape[0]
    new = np.zeros(n)
    for c in range(cmd.shape[0]):
        new[cmd[c]] = rates[cmd[c]] / scale
    for i in range(n):
        s.qd_d[i] = s.qd_d[i] + a_f * (ramp * new[i] - s.qd_d[i])
        s.q_d[i] = s.q_d[i] + s.qd_d[i] * dt


@njit(cache=True)
def _plan(p, s, m, t, q, corners, marker_seen, out):
    """The recovery plan from one C_G snapshot (:meth:`VisualServo.plan`): the target's pose
    in C_G from one square marker (the largest tag seen of a pattern; ``corners`` (M, 4, 2)
    OpenCV order, ``marker_seen`` (M,)), its centre in the body frame, the rod's strains that
    put it on C_L's optical axis (:func:`~tdacm.control.planner.plan_kernel`) and the cubic
    trajectory there (:class:`~tdacm.control.CubicTrajectory`, duration from ``max_speed``).
    False when no marker is seen or its corners admit no pose."""
    cam = p.global_camera
    mk = -1
    if p.largest_tag:
        best = -1.0
        for i in range(corners.shape[0]):
            if not marker_seen[i]:
                continue
            ext = 0.0
            for a in range(2):
                lo_, hi_ = np.inf, -np.inf
                for c in range(4):
                    lo_ = min(lo_, corners[i, c, a])
                    hi_ = max(hi_, corners[i, c, a])
                ext += hi_ - lo_
            if ext > best:
                best, mk = ext, i
    elif marker_seen[0]:
        mk = 0
    if mk < 0:
        return False
    xy = np.empty((4, 2))
    for c in range(4):
        src = IPPE_ORDER[c]
        xy[c, 0] = (corners[mk, src, 0] - cam.cx) / cam.fx
        xy[c, 1] = (corners[mk, src, 1] - cam.cy) / cam.fy
    g = np.empty((4, 4))
    if not square_pose(p.square, xy, p.marker_centres[mk], g):
        return False
    p_body = np.empty(3)
    dm = p.drone_mount
    for i in range(3):
        p_body[i] = dm[i, 0] * g[0, 3] + dm[i, 1] * g[1, 3] + dm[i, 2] * g[2, 3] + dm[i, 3]
    a0, a1 = p.strains[0], p.strains[1]
    ns = a1 - a0
    qs_now = q[a0:a1].copy()
    x, point, cost, feasible = plan_kernel(qs_now, m, p.rod[0], p.rod[1], p.mount_inv, p_body,
                                           p.z_min, p.bound, True)  # fmt: skip
    big = 0.0
    for i in range(ns):
        big = max(big, abs(x[i] - qs_now[i]))
    s.traj_on[0] = 1.0
    s.traj_t0[0] = t
    s.traj_tf[0] = t + max(0.5, 1.5 * big / p.max_speed)
    for i in range(ns):
        s.traj_q0[i] = qs_now[i]
        s.traj_dq[i] = x[i] - qs_now[i]
        out.plan_qs[i] = x[i]
    for i in range(3):
        out.plan_point[i] = point[i]
    out.planned[0] = True
    out.plan_cost[0] = cost
    out.plan_success[0] = feasible and cost < 1e-3
    out.plan_duration[0] = s.traj_tf[0] - t
    return True


@njit(cache=True)
def _follow(p, s, t, qdd_d):
    """The cubic trajectory at ``t`` into the rod's strains of ``q_d``, ``qd_d``, ``qdd_d``
    (:class:`~tdacm.control.CubicTrajectory`; the other coordinates held)."""
    n = s.q_d.shape[0]
    a0 = p.strains[0]
    ns = s.traj_q0.shape[0]
    t0, tf = s.traj_t0[0], s.traj_tf[0]
    h = tf - t0
    tt = min(max(t - t0, 0.0), h)
    moving = not (t >= tf or t < t0)
    for i in range(n):
        s.qd_d[i] = 0.0
    for i in range(ns):
        d = s.traj_dq[i]
        a2 = 3 * d / h**2
        a3 = -2 * d / h**3
        j = a0 + i
        s.q_d[j] = s.traj_q0[i] + a2 * tt**2 + a3 * tt**3
        if moving:
            s.qd_d[j] = 2 * a2 * tt + 3 * a3 * tt**2
            qdd_d[j] = 2 * a2 + 6 * a3 * tt


@njit(cache=True)
def _recovery(p, s, m, t, q, offered, g_found, corners, marker_seen, out):
    """The recovery mode for one period: before a trajectory exists, hold and ask C_G for a
    snapshot (not ``offered``), detect the target in it, plan and start from the current pose
    with a level drone; then follow the trajectory. When C_G misses the target the robust
    servo holds and asks again for ``lost_timeout`` s after the first miss; otherwise (and
    when no plan exists) the period fails."""
    n = q.shape[0]
    if s.traj_on[0] == 0.0:
        if not offered:  # hold and ask C_G for the next period
            for i in range(n):
                s.qd_d[i] = 0.0
            out.request[0] = True
            return
        if not g_found:
            for i in range(n):
                s.qd_d[i] = 0.0
            if not p.robust:
                out.failure[0] = NOT_SEEN_BY_GLOBAL
                return
            if not np.isfinite(s.cg_missed[0]):
                s.cg_missed[0] = t
            if t - s.cg_missed[0] >= p.lost_timeout:
                out.failure[0] = NOT_SEEN_BY_GLOBAL
            else:
                out.request[0] = True
            return
        s.cg_missed[0] = np.nan
        if not _plan(p, s, m, t, q, corners, marker_seen, out):
            for i in range(n):
                s.qd_d[i] = 0.0
            out.failure[0] = NO_POSE
            return
        for i in range(n):
            s.q_d[i] = q[i]
        if m.floating:
            s.q_d[0] = 0.0
            s.q_d[1] = 0.0
    _follow(p, s, t, out.qdd_d)


@njit(cache=True)
def follow(p, s, m, q, rates, t, dt, qdd_d):
    """IBVS mode on joint rates already mapped: shaped into ``qd_d`` and integrated into
    ``q_d`` (:func:`shape`); the robust servo on a flying base adds the acceleration
    feed-forward of the filtered rate into ``qdd_d`` (the low-level loop follows the
    deceleration instead of lagging into an overshoot; the paper has ``qdd_d = 0``) and the
    leak of ``q_d`` toward the estimate ``q`` (``q_d`` is only an integrated rate while the
    vision loop closes on the actual pose: no wind-up while the plant lags)."""
    n = q.shape[0]
    qd_prev = s.qd_d.copy()
    shape(p, s, rates, t, dt)
    if p.robust and m.floating:
        if p.accel_ff:
            for i in range(n):
                qdd_d[i] = (s.qd_d[i] - qd_prev[i]) / dt
        if p.leak > 0.0:
            cmd = p.commanded
            for c in range(cmd.shape[0]):
                j = cmd[c]
                s.q_d[j] += p.leak * dt * (q[j] - s.q_d[j])


@njit(cache=True)
def servo_command(p, s, m, t, dt, q, offered, twist_in, g_found, corners, marker_seen, out):
    """The end of a period (after :func:`servo_perceive`): in IBVS mode with a view (or an
    external ``twist_in``, finite: a learning agent's action) the twist's joint rates
    (:func:`joint_rates`) shaped into ``qd_d`` and integrated into ``q_d`` (the robust servo
    adds the acceleration feed-forward of the filtered rate and the leak of ``q_d`` toward the
    estimate on a flying base); in recovery the plan from C_G's snapshot (``g_found``, its
    markers' ``corners`` and ``marker_seen``, read when :func:`needs_global`) and its cubic
    trajectory; otherwise a hold."""
    n = q.shape[0]
    if out.failure[0] != NO_FAILURE:
        return
    mode = out.mode[0]
    external = np.isfinite(twist_in[0])
    if mode == IBVS and (out.seen[0] or external):
        for i in range(6):
            out.twist[i] = twist_in[i] if external else out.ibvs_twist[i]
        rates = np.empty(n)
        joint_rates(p, m, q, out.twist, rates)
        follow(p, s, m, q, rates, t, dt, out.qdd_d)
    elif mode == RECOVERY:
        _recovery(p, s, m, t, q, offered, g_found, corners, marker_seen, out)
    else:  # IBVS mode but the target is not seen (or nothing fused yet): hold
        for i in range(n):
            s.qd_d[i] = 0.0
