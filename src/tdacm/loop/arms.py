"""The closed loop's blocks for a robot with several arms under one drone (``[[robot.arms]]``).

Each arm carries its own tip camera C_L^k looking at its own marker. The blocks wrap the
single-arm ones, one per arm, and keep the single-arm interfaces of
:class:`~.closed_loop.ClosedLoop` (arm 0's data sits in the single-arm fields, so the loop,
the safety monitor and the outputs run unchanged):

* :class:`ArmsSensors`: one C_L sensor per arm (arm k's noise from its own stream), C_G and
  the other sensors as :class:`~.sensors.Sensors`; the reading's ``local`` is an
  :class:`ArmsMeasurement`;
* :class:`ArmsPerception`: one :class:`~.perception.Perception` per arm -> :class:`ArmsView`;
* :class:`ArmsServo`: the paper's virtual-camera IBVS applied per arm (each arm's own C_V^k,
  features, interaction matrix and twist ``v_k``), and **one** joint-rate mapping over all
  commanded coordinates: the arms' task Jacobians stacked (docs/control.md, "Two arms")::

      [J_1(q_v)[:, c]]            [Ad(g_{C_L1}^{L1}) v_1]
      [J_2(q_v)[:, c]] qdot_c  =  [Ad(g_{C_L2}^{L2}) v_2]      (least squares, pseudo-inverse)

  The drone's coordinates (yaw, position) are columns of both blocks: moving the drone for
  one arm moves the other arm's view, and the least-squares solution trades the two. The
  command shaping, feed-forward and leak are the single-arm servo's, on the stacked rates;
* :class:`ArmsLog`: the run log with the per-arm series :data:`ARM_SERIES`; ``rmse`` and
  ``rmse_true`` are the largest over the arms (the safety monitor watches the worst arm).

The recovery with the global camera runs per arm (:meth:`ArmsServo.recover`): while an
arm's target is out of its C_L view, the drone holds its reference and that arm's rod follows
the paper's plan from one C_G snapshot of its own marker (C_G detects each arm's marker,
:class:`ArmsGlobal`); the other rods hold. Once every arm sees its target again the stacked
IBVS resumes from that reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import numpy as np
from numba import njit

from .._linalg import SVD_PINV, svd_solve
from .._records import stack, take
from ..control import Mode
from ..vision.mounts import tip_jacobian_into
from ..vision.tip import rates_from_jacobian
from ..vision.virtual import BehindVirtualCamera
from .data import CameraMeasurement, DeferredMeasurement, LocalView, ServoCommand, ServoEvent
from .logger import RunLog
from .sensors import Sensors
from .servo import (
    EVENT_NAMES,
    FAILURE_REASONS,
    IBVS,
    IBVS_ENGAGED,
    NO_EVENT,
    NO_FAILURE,
    RECOVERY,
    RECOVERY_PLANNED,
    TARGET_LOST,
    RobustServo,
    ServoOut,
    VisualServo,
    _recovery,
    follow,
    normalized_rmse,
)

#: :func:`arms_command`'s arguments for the stacked mapping of the arms' twists (no feature
#: rows: :func:`feature_joint_rates` is the squeeze's)
NO_WEIGHTS = np.zeros((0, 6, 6))
NO_PRESSING = np.zeros(0, np.bool_)


def twist_arguments(twist, k: int) -> np.ndarray:
    """The external twists argument of :func:`arms_command` (6 ``k``; NaN: the IBVS twists)."""
    if twist is None:
        return np.full(6 * k, np.nan)
    return np.ascontiguousarray(twist, dtype=float).reshape(6 * k)


#: Per-arm series of :class:`ArmsLog` (one column per arm).
ARM_SERIES = (
    "rmse_arms", "rmse_true_arms", "detected_arms", "points_arms", "points_local_arms",
    "twist_arms",
)  # fmt: skip


def _arm0(name: str) -> property:
    """A read-only attribute that reads arm 0's ``name``."""
    return property(lambda self: getattr(self[0], name), doc=f"arm 0's ``{name}``")


class ArmsMeasurement(tuple):
    """One :class:`~.data.CameraMeasurement` per arm's C_L; reads as arm 0's (``detection``,
    ``found``, ``image``, ``t_capture``) where a single C_L is expected."""

    t_capture = _arm0("t_capture")
    detection = _arm0("detection")
    found = _arm0("found")
    image = _arm0("image")


class ArmsGlobal(DeferredMeasurement):
    """One C_G measurement per arm (``arms``, each detecting its arm's marker and taken only
    when read, :class:`~.data.DeferredMeasurement`); reads as arm 0's where one C_G frame is
    expected (the log, the outputs)."""

    __slots__ = ("arms",)

    def __init__(self, arms):
        self.arms = tuple(arms)
        super().__init__(self.arms[0].t_capture, None)

    @property
    def taken(self) -> bool:
        return self.arms[0].taken

    def value(self):
        return self.arms[0].value()


@dataclass(frozen=True)
class ArmsView(LocalView):
    """Arm 0's :class:`~.data.LocalView` (its fields) and every arm's view (``arms``)."""

    arms: tuple = ()


@dataclass(frozen=True)
class ArmServoState:
    """What the servo computed for one arm in a period (logged)."""

    points: np.ndarray | None
    rmse: float
    rmse_measured: float
    twist: np.ndarray
    seen: bool


class ArmsSensors(Sensors):
    """:class:`~.sensors.Sensors` with one C_L per arm (``locals_``, arm 0 first; ``local``
    is arm 0's). Arm 0's C_L is read first and C_G, the other sensors after it, as for one
    arm; the other arms' C_L after them."""

    def __init__(self, locals_, *args, globals_=(), **kwargs):
        super().__init__(locals_[0], *args, **kwargs)
        self.locals_ = list(locals_)
        self.globals_ = list(globals_)  # C_G detecting arm k's marker, k >= 1

    def reset(self) -> None:
        super().reset()
        for s in self.locals_[1:] + self.globals_:
            s.reset()

    def first_look(self, t: float, q) -> ArmsMeasurement:
        out = []
        for s in self.locals_:
            det, _ = s.ideal(q)
            s.reset()
            out.append(CameraMeasurement(t, det))
        return ArmsMeasurement(out)

    def read(self, state, request_global: bool = False):
        r = super().read(state, request_global)
        local = ArmsMeasurement([r.local] + [s.measure(state) for s in self.locals_[1:]])
        glob = r.global_
        if glob is not None and self.globals_:
            glob = ArmsGlobal(
                [glob] + [DeferredMeasurement(state.t, partial(g.measure, state))
                          for g in self.globals_]
            )  # fmt: skip
        return type(r)(r.t, local, glob, r.other, r.global_output)

    def close(self) -> None:
        super().close()
        for s in self.locals_[1:] + self.globals_:
            s.close()


class ArmsPerception:
    """One :class:`~.perception.Perception` per arm (its controller camera and marker); the
    global camera's perception is arm 0's (C_G is shared)."""

    def __init__(self, perceptions):
        self.arms = list(perceptions)
        lead = self.arms[0]
        self.local_camera = lead.local_camera
        self.global_camera = lead.global_camera
        self.target = lead.target

    def reset(self) -> None:
        for p in self.arms:
            p.reset()

    def local(self, m: ArmsMeasurement) -> ArmsView:
        views = tuple(p.local(mk) for p, mk in zip(self.arms, m, strict=True))
        v0 = views[0]
        return ArmsView(v0.t_capture, v0.found, v0.pixels, v0.points, v0.depths, views)

    def global_(self, m):
        """Arm 0's :class:`~.data.GlobalView`, or with one C_G measurement per arm
        (:class:`ArmsGlobal`) a tuple of every arm's."""
        if isinstance(m, ArmsGlobal):
            return tuple(p.global_(mk) for p, mk in zip(self.arms, m.arms, strict=True))
        return self.arms[0].global_(m)


#: What the servo of several arms takes from arm 0's servo (the joint reference's owner).
_FROM_LEAD = (
    "system", "n", "config", "shaping", "recovery", "ibvs", "local_camera", "global_camera",
    "target", "tip_mount", "desired_points", "desired_depths",
)  # fmt: skip


class ArmsServo:
    """The servo of a robot with several arms (module docstring): ``arms`` are single-arm
    servos (:class:`~.servo.VisualServo` or :class:`~.servo.RobustServo`), one per arm, built
    on the same system with their arm's ``rod``, camera, mount and reference snapshot. Arm
    0's servo holds the joint reference (``q_d``, ``qd_d``) and its shaping; the others give
    their twists and Jacobians. Implements the servo protocol of
    :mod:`tdacm.loop.protocols`."""

    def __init__(self, arms):
        self.arms = list(arms)
        if len(self.arms) < 2:
            raise ValueError("ArmsServo needs two or more arm servos")
        for name in _FROM_LEAD:
            setattr(self, name, getattr(self.arms[0], name))
        # the compiled step (arms_command) runs the arms' servos of tdacm.loop.servo; the
        # squeeze (a subclass) runs the methods below
        self._compiled = type(self) is ArmsServo and all(
            type(a) in (VisualServo, RobustServo) for a in self.arms
        )
        #: the arms' records stacked (a leading arm axis); each arm's servo holds its views
        self.params = stack([a.params for a in self.arms])
        self.state = stack([a.state for a in self.arms])
        for k, a in enumerate(self.arms):
            a.state = take(self.state, k)
        n, ns = self.n, self.arms[0]._n_s
        self._outs = stack([ServoOut.empty(n, ns) for _ in self.arms])
        for k, a in enumerate(self.arms):
            a._out = take(self._outs, k)
        self._robot = ServoOut.empty(n, ns)
        self.memo = ArmsMemo.initial()

    @property
    def mode(self) -> str:
        return Mode.RECOVERY if any(a.mode == Mode.RECOVERY for a in self.arms) else Mode.IBVS

    @property
    def q_d(self) -> np.ndarray:
        return self.arms[0].q_d

    @property
    def qd_d(self) -> np.ndarray:
        return self.arms[0].qd_d

    def reset(self, q0, first_view: ArmsView | None = None) -> None:
        views = first_view.arms if isinstance(first_view, ArmsView) else [None] * len(self.arms)
        for a, v in zip(self.arms, views, strict=True):
            a.reset(q0, v)
        self._lost = self.mode == Mode.RECOVERY
        self.memo.lost[0] = self._lost

    def joint_rates(self, q, twists) -> np.ndarray:
        """``qdot_d[c] = [J_k(q_v)[:, c]]_k^+ [Ad(g_{C_Lk}^{Lk}) v_k]_k`` over the commanded
        coordinates ``c`` (docs/control.md, "Two arms")."""
        jac = np.vstack([a.task_jacobian(q) for a in self.arms])
        rhs = np.concatenate([a._ad_mount @ v for a, v in zip(self.arms, twists, strict=True)])
        return rates_from_jacobian(jac, rhs, self.arms[0]._cmd)

    def step(self, t: float, dt: float, view: ArmsView, gview, est, twist=None) -> ServoCommand:
        """One period. ``twist`` (optional): the arms' twists stacked (``6 k`` values)
        replacing the IBVS twists."""
        if self._compiled:
            return self.compiled_step(t, dt, view, gview, est, twist)
        q = est.q
        per = [a.perceive(t, dt, v, est) for a, v in zip(self.arms, view.arms, strict=True)]
        modes, event = self._robot_event(per)
        states, twists = [], []
        external = None if twist is None else np.asarray(twist, float).reshape(len(per), 6)
        seen_all = all(p[2] for p in per)
        for k, (mode, _, seen, ibvs_twist, points, _, _, rmse, extra) in enumerate(per):
            v = np.zeros(6)
            if mode == Mode.IBVS and seen_all:
                v = np.asarray(ibvs_twist() if external is None else external[k], float)
            twists.append(v)
            states.append(ArmServoState(points, rmse, extra.get("rmse_measured", math.nan), v,
                                        bool(seen)))  # fmt: skip
        qdd_d, request, failure, plan, event = self._joint_command(
            t, dt, q, gview, modes, seen_all, twists, event
        )
        return self._command(per, states, twists, qdd_d, event, failure, request, plan)

    def compiled_step(self, t, dt, view, gview, est, twist=None) -> ServoCommand:
        """One period of the compiled step: each arm's :func:`~.servo.servo_perceive`, then
        :func:`arms_command` with each arm's C_G snapshot read when its recovery needs one."""
        q = self.perceive_arms(t, dt, view, est)
        offered, g_found, corners, seen = self.global_arguments(gview)
        tw = twist_arguments(twist, len(self.arms))
        arms_command(self.params, self.state, self.arms[0]._m, float(t), float(dt), q, offered,
                     tw, g_found, corners, seen, self._outs, self.memo, self._robot, NO_WEIGHTS,
                     NO_PRESSING, 0.0)  # fmt: skip
        return self.command_of_outputs()

    def perceive_arms(self, t, dt, view, est) -> np.ndarray:
        """The first part of the period of every arm (:meth:`~.servo.VisualServo.perceive_period`
        into its row of the stacked outputs); returns the estimate's ``q``."""
        for arm, v in zip(self.arms, view.arms, strict=True):
            arm.perceive_period(t, dt, v, est)  # into its row of outs
            arm._memo = None
        return np.ascontiguousarray(est.q, dtype=float)

    def global_arguments(self, gview) -> tuple:
        """``(offered, found (k,), corners (k, M, 4, 2), seen (k, M))`` of
        :func:`arms_command`: each arm's C_G snapshot, read when its recovery needs one."""
        k = len(self.arms)
        outs = self._outs
        offered = gview is not None
        views = gview if isinstance(gview, tuple) else (gview,) * k
        m_count = self.params.marker_centres.shape[1]
        g_found = np.zeros(k, np.bool_)
        corners = np.zeros((k, m_count, 4, 2))
        seen = np.zeros((k, m_count), np.bool_)
        if offered:
            for a, arm in enumerate(self.arms):
                if outs.mode[a, 0] == RECOVERY and arm.state.traj_on[0] == 0.0:
                    g_found[a], corners[a], seen[a] = arm._global_corners(views[a])
        return offered, g_found, corners, seen

    def arm_state(self, a: int, out: ServoOut) -> ArmServoState:
        """Arm ``a``'s :class:`ArmServoState` of its outputs ``out`` this period."""
        seen = bool(out.seen[0])
        meas = float(out.rmse_measured[0]) if self.arms[a].params.robust else math.nan
        return ArmServoState(out.points.copy() if seen else None,
                             float(out.rmse[0]) if seen else math.nan, meas, out.twist.copy(),
                             seen)  # fmt: skip

    def command_of_outputs(self, **extra) -> ServoCommand:
        """The period's :class:`ServoCommand` of the compiled step's outputs (``extra``:
        further fields); raises :class:`~tdacm.vision.virtual.BehindVirtualCamera` when a
        point lies behind an arm's virtual camera (the loop ends the run)."""
        outs, robot, memo = self._outs, self._robot, self.memo
        self._lost = bool(memo.lost[0])
        failure = None
        if robot.failure[0] != NO_FAILURE:
            a = int(memo.failed_arm[0])
            if robot.failure[0] == 1:  # BEHIND: eq. (18) undefined, the loop ends the run
                raise BehindVirtualCamera("a point lies behind the virtual camera")
            failure = f"arm {a}: {FAILURE_REASONS[int(robot.failure[0])]}"
        plan = None
        if robot.planned[0]:
            a = int(memo.planned_arm[0])
            o, st = take(outs, a), self.arms[a].state
            plan = {
                "t": float(st.traj_t0[0]), "q_s_d": o.plan_qs.tolist(),
                "point_local": o.plan_point.tolist(), "cost": float(o.plan_cost[0]),
                "success": bool(o.plan_success[0]), "duration": float(o.plan_duration[0]),
                "arm": a,
            }  # fmt: skip
        states = tuple(self.arm_state(a, take(outs, a)) for a in range(len(self.arms)))
        o0, lead = take(outs, 0), self.arms[0]
        seen0 = bool(o0.seen[0])
        if lead.params.robust:
            extra["target_pose"] = lead.state.target_pose.copy() if lead.state.tp_set[0] else None
        event = extra.pop("event", None) or EVENT_NAMES.get(int(robot.event[0]))
        return ServoCommand(
            self.mode, lead.state.q_d.copy(), lead.state.qd_d.copy(), robot.qdd_d.copy(),
            robot.twist.copy(), o0.features.copy() if seen0 else None,
            o0.error.copy() if seen0 else None, o0.points.copy() if seen0 else None,
            float(robot.rmse[0]), event=event, failure=failure,
            rmse_measured=float(robot.rmse_measured[0]), arms=states,
            request_global=bool(robot.request[0]), plan=plan, **extra,
        )  # fmt: skip

    def _command(self, per, states, twists, qdd_d, event, failure, request, plan):
        """The period's :class:`ServoCommand` from the arms' perceptions ``per`` and states:
        arm 0's twist and points, the largest of the arms' RMSEs (NaN if one is), the lead's
        joint reference."""
        lead = self.arms[0]
        rmses = [s.rmse for s in states]
        rmse = max(rmses) if all(map(math.isfinite, rmses)) else math.nan
        meas = [s.rmse_measured for s in states]
        p0, e0 = per[0], per[0][8]
        return ServoCommand(
            self.mode, lead.q_d.copy(), lead.qd_d.copy(), qdd_d, twists[0], p0[5], p0[6], p0[4],
            rmse, event=event, failure=failure,
            rmse_measured=max(meas) if all(map(math.isfinite, meas)) else math.nan,
            target_pose=e0.get("target_pose"), arms=tuple(states), request_global=request,
            plan=plan,
        )  # fmt: skip

    def _robot_event(self, per):
        """The arms' modes and the robot's event of the period from the arms' perceptions
        ``per``: an arm losing its target; IBVS engaged when the last lost arm sees its
        target again (the loop arms the safety monitor then, as for one arm)."""
        modes = [p[0] for p in per]
        was_lost = self._lost
        self._lost = any(m == Mode.RECOVERY for m in modes)
        event = next((p[1] for p in per if p[1] == ServoEvent.TARGET_LOST), None)
        if event is None and was_lost and not self._lost:
            event = ServoEvent.IBVS_ENGAGED
        if event is None and per[0][1] != ServoEvent.IBVS_ENGAGED:
            event = per[0][1]
        return modes, event

    def _joint_command(self, t, dt, q, gview, modes, seen_all, twists, event):
        """The period's joint command: the recovery of the arms that lost their target
        (:meth:`recover`), else the joint rates of the arms' ``twists`` when every arm sees
        its target, else a hold. Returns ``(qdd_d, request_global, failure, plan, event)``."""
        lead, n = self.arms[0], self.n
        qdd_d = np.zeros(n)
        failure = plan = None
        request = False
        lost = [k for k, m in enumerate(modes) if m == Mode.RECOVERY]
        if lost:
            qdd_d, request, failure, plan = self.recover(t, q, gview, lost)
            if plan is not None and event is None:
                event = "recovery planned"
        elif seen_all:
            qdd_d = lead.follow_rates(q, self.joint_rates(q, twists), t, dt)
        else:  # an arm's target not seen this period (nothing fused yet): hold
            lead.qd_d = np.zeros(n)
        return qdd_d, request, failure, plan, event

    def recover(self, t: float, q, gview, lost: list[int]):
        """The recovery of the arms ``lost`` (module docstring): the drone holds its
        reference, each lost arm's rod follows the cubic trajectory of its own plan (one C_G
        snapshot of its marker, :meth:`~.servo.VisualServo.recover` on its strains), the other
        rods hold theirs. Returns ``(qdd_d, request_global, failure, plan_info)`` and sets the
        lead servo's ``q_d``, ``qd_d``."""
        lead, n = self.arms[0], self.n
        q_d, qd_d, qdd_d = lead.q_d.copy(), np.zeros(n), np.zeros(n)
        views = gview if isinstance(gview, tuple) else (gview,) * len(self.arms)
        request, failure, plan = False, None, None
        for k in lost:
            arm, acc = self.arms[k], np.zeros(n)
            status, info = arm.recover(t, q, views[k], acc)
            if status == "hold":
                request = True
                if info is not None and failure is None:
                    failure = f"arm {k}: {info}"
                continue
            if status == "failed":
                failure = failure or f"arm {k}: {info}"
                continue
            if info is not None and plan is None:
                plan = dict(info, arm=k)
            c = arm._strains
            q_d[c], qd_d[c], qdd_d[c] = arm.q_d[c], arm.qd_d[c], acc[c]
        lead.q_d, lead.qd_d = q_d, qd_d
        return qdd_d, request, failure, plan


class ArmsLog(RunLog):
    """The run log of a robot with several arms: the single-arm series of arm 0, with
    ``rmse_true`` the largest over the arms, and :data:`ARM_SERIES`. ``truths``: one
    ``q -> (true points in arm k's servo camera, target pose)`` per arm; ``desired``: the arms'
    reference points."""

    def __init__(self, desired, frame_composer=None, truths=None):
        super().__init__(desired[0], frame_composer, None)
        self.desired = [np.asarray(d, float) for d in desired]
        self.truths = list(truths or [])

    def record(self, plant, readings, view, estimate, cmd, act, force=None) -> None:
        super().record(plant, readings, view, estimate, cmd, act, force)
        r = self.rows
        k = len(self.desired)
        rt = np.full(k, np.nan)
        for i, (truth, d) in enumerate(zip(self.truths, self.desired, strict=False)):
            rt[i] = normalized_rmse(truth(plant.q)[0], d)
        r["rmse_true"][-1] = float(np.max(rt)) if self.truths else np.nan
        arms = cmd.arms or ()
        r.setdefault("rmse_arms", []).append(
            np.array([a.rmse for a in arms]) if len(arms) == k else np.full(k, np.nan)
        )
        r.setdefault("rmse_true_arms", []).append(rt)
        nan_pts = np.full((4, 2), np.nan)
        r.setdefault("points_arms", []).append(
            np.array([nan_pts if a.points is None else np.asarray(a.points, float).reshape(4, 2)
                      for a in arms]) if len(arms) == k else np.full((k, 4, 2), np.nan)
        )  # fmt: skip
        r.setdefault("twist_arms", []).append(
            np.array([np.asarray(a.twist, float) for a in arms]) if len(arms) == k
            else np.full((k, 6), np.nan)
        )  # fmt: skip
        views = getattr(view, "arms", ())
        r.setdefault("detected_arms", []).append(
            np.array([bool(v.found) for v in views]) if len(views) == k else np.zeros(k, bool)
        )
        r.setdefault("points_local_arms", []).append(
            np.array([np.asarray(v.points, float).reshape(4, 2) if v.found else nan_pts
                      for v in views]) if len(views) == k else np.full((k, 4, 2), np.nan)
        )  # fmt: skip


# ============================================================================ compiled step
# The servo of several arms as one compiled step over the arms' stacked servo records (a
# leading arm axis, :func:`tdacm._records.take`): every arm's :func:`~.servo.servo_perceive`,
# then :func:`arms_command`. :class:`ArmsServo` calls it for the block loop, the batched
# engine for every world.


@njit(cache=True)
def _level(q, m):
    """``q_v``: ``q`` with the drone's roll and pitch zero on a floating base (the virtual
    camera's chain, docs/control.md), a copy."""
    qv = q.copy()
    if m.floating:
        qv[0] = 0.0
        qv[1] = 0.0
    return qv


@njit(cache=True)
def stacked_joint_rates(ps, m, q, twists, out):
    """``qdot_d[c] = [J_k(q_v)[:, c]]_k^+ [Ad(g_{C_Lk}^{Lk}) v_k]_k`` over the commanded
    coordinates ``c`` of the arms' records ``ps`` (stacked) for their twists ``twists`` (k, 6),
    ``q_v`` ``q`` with roll and pitch zero (docs/control.md, "Two arms")."""
    k = twists.shape[0]
    n = q.shape[0]
    qv = _level(q, m)
    lead = take(ps, 0)
    cmd = lead.commanded
    jc = np.empty((6 * k, cmd.shape[0]))
    rhs = np.empty(6 * k)
    jac = np.empty((6, n))
    for a in range(k):
        p = take(ps, a)
        tip_jacobian_into(qv, m, p.rod, jac)
        for i in range(6):
            acc = 0.0
            for c in range(6):
                acc += p.ad_mount[i, c] * twists[a, c]
            rhs[6 * a + i] = acc
            for c in range(cmd.shape[0]):
                jc[6 * a + i, c] = jac[i, cmd[c]]
    x = svd_solve(jc, rhs, SVD_PINV, 1e-8)
    for i in range(n):
        out[i] = 0.0
    for c in range(cmd.shape[0]):
        out[cmd[c]] = x[c]


@njit(cache=True)
def feature_joint_rates(ps, m, q, twists, weights, pressing, axial_weight, separate, out):
    """The stacked mapping in feature space (the squeeze's, :mod:`tdacm.loop.touch_arms`) into
    ``out`` (n,): arm ``a``'s rows ``W_a Ad(g_{C_La}^{La})^-1 J_a(q_v)[:, c]`` against
    ``W_a v_a`` (``weights`` (k, 6, 6): each arm's interaction matrix this period, ``twists``
    (k, 6)), least squares over the commanded coordinates ``c`` (pseudo-inverse); for an arm
    in ``pressing`` (k,) its distance row (the sixth) is replaced by its camera's axial
    velocity weighted by ``axial_weight``: one row for the sum of the pressing arms' axial
    velocities, or with ``separate`` one row per pressing arm."""
    k = twists.shape[0]
    n = q.shape[0]
    qv = _level(q, m)
    cmd = take(ps, 0).commanded
    nc = cmd.shape[0]
    n_pressing = 0
    for a in range(k):
        if pressing[a]:
            n_pressing += 1
    rows = 6 * k - n_pressing
    if separate:
        rows += n_pressing
    elif n_pressing > 0:
        rows += 1
    lhs = np.zeros((rows, nc))
    rhs = np.zeros(rows)
    axial = np.zeros(nc)
    speed = 0.0
    jac = np.empty((6, n))
    jc = np.empty((6, nc))
    r = 0
    for a in range(k):
        p = take(ps, a)
        tip_jacobian_into(qv, m, p.rod, jac)
        for i in range(6):
            for c in range(nc):
                acc = 0.0
                for j in range(6):
                    acc += p.ad_mount_inv[i, j] * jac[j, cmd[c]]
                jc[i, c] = acc
        w = weights[a]
        last = 5 if pressing[a] else 6
        for i in range(last):
            acc = 0.0
            for j in range(6):
                acc += w[i, j] * twists[a, j]
                for c in range(nc):
                    lhs[r, c] += w[i, j] * jc[j, c]
            rhs[r] = acc
            r += 1
        if pressing[a]:
            if separate:
                for c in range(nc):
                    lhs[r, c] = axial_weight * jc[5, c]
                rhs[r] = axial_weight * twists[a, 5]
                r += 1
            for c in range(nc):
                axial[c] += jc[5, c]
            speed += twists[a, 5]
    if n_pressing > 0 and not separate:
        for c in range(nc):
            lhs[r, c] = axial_weight * axial[c]
        rhs[r] = axial_weight * speed
    x = svd_solve(lhs, rhs, SVD_PINV, 1e-8)
    for i in range(n):
        out[i] = 0.0
    for c in range(nc):
        out[cmd[c]] = x[c]


class ArmsMemo(NamedTuple):
    """The servo of several arms' own state and outputs besides its arms': whether an arm
    was in recovery last period (``lost`` (1,) bool), the arm whose failure ends the run
    (``failed_arm``) and the arm whose plan was made this period (``planned_arm``), -1: none
    (one-element arrays)."""

    lost: np.ndarray
    failed_arm: np.ndarray
    planned_arm: np.ndarray

    @classmethod
    def initial(cls) -> ArmsMemo:
        return cls(np.zeros(1, np.bool_), np.full(1, -1, np.int64), np.full(1, -1, np.int64))


@njit(cache=True)
def arms_command(ps, ss, m, t, dt, q, offered, twist_in, g_found, corners, marker_seen, outs,
                 memo, robot, weights, pressing, axial_weight):  # fmt: skip
    """The end of a period of the servo of several arms (after each arm's
    :func:`~.servo.servo_perceive` into its outputs ``outs``; module docstring) on the arms'
    records ``ps``, ``ss`` (stacked): the robot's event (an arm losing its target; IBVS
    engaged when the last lost arm sees it again), then the recovery of the arms that lost
    their target (each on its own strains from its own C_G snapshot: ``g_found`` (k,),
    ``corners`` (k, M, 4, 2), ``marker_seen`` (k, M); the drone and the other rods hold),
    else, when every arm sees its target, the stacked joint rates (:func:`stacked_joint_rates`)
    of the arms' twists (IBVS, or ``twist_in`` (6 k) when finite) followed by arm 0's servo
    (its ``q_d``, ``qd_d`` are the robot's reference), else a hold; with ``weights`` (k, 6, 6; none: (0, 6, 6)) the rates are the stacked mapping
    in feature space (:func:`feature_joint_rates` with ``pressing`` and ``axial_weight``: the
    squeeze's). ``robot`` (a
    :class:`~.servo.ServoOut`) receives the robot's mode (recovery if an arm recovers),
    event, failure, request, the worst arm's RMSEs (NaN if an arm has none), arm 0's twist
    and ``qdd_d``; ``memo`` (:class:`ArmsMemo`) the arms that failed or planned."""
    k = outs.mode.shape[0]
    n = q.shape[0]
    lead = take(ss, 0)
    robot.failure[0] = NO_FAILURE
    robot.request[0] = False
    robot.planned[0] = False
    memo.failed_arm[0] = -1
    memo.planned_arm[0] = -1
    for i in range(n):
        robot.qdd_d[i] = 0.0
    for i in range(6):
        robot.twist[i] = 0.0
    any_lost = False
    all_seen = True
    event = NO_EVENT
    for a in range(k):
        any_lost = any_lost or outs.mode[a, 0] == RECOVERY
        all_seen = all_seen and outs.seen[a, 0]
        if event == NO_EVENT and outs.event[a, 0] == TARGET_LOST:
            event = TARGET_LOST
    was_lost = memo.lost[0]
    memo.lost[0] = any_lost
    if event == NO_EVENT and was_lost and not any_lost:
        event = IBVS_ENGAGED
    robot.mode[0] = RECOVERY if any_lost else IBVS
    robot.seen[0] = all_seen
    robot.event[0] = event
    for a in range(k):  # a point behind an arm's C_V ends the run (servo_perceive's failure)
        if outs.failure[a, 0] != NO_FAILURE:
            robot.failure[0] = outs.failure[a, 0]
            memo.failed_arm[0] = a
            return
    external = np.isfinite(twist_in[0])
    twists = np.zeros((k, 6))
    for a in range(k):
        if outs.mode[a, 0] == IBVS and all_seen:
            for i in range(6):
                twists[a, i] = twist_in[6 * a + i] if external else outs.ibvs_twist[a, i]
        for i in range(6):
            outs.twist[a, i] = twists[a, i]
    if any_lost:
        q_d = lead.q_d.copy()
        qd_d = np.zeros(n)
        for a in range(k):
            if outs.mode[a, 0] != RECOVERY:
                continue
            p = take(ps, a)
            s = take(ss, a)
            out = take(outs, a)
            for i in range(n):
                out.qdd_d[i] = 0.0
            _recovery(p, s, m, t, q, offered, g_found[a], corners[a], marker_seen[a], out)
            if out.request[0]:  # holding for a snapshot
                robot.request[0] = True
                continue
            if out.failure[0] != NO_FAILURE:
                if memo.failed_arm[0] < 0:
                    robot.failure[0] = out.failure[0]
                    memo.failed_arm[0] = a
                continue
            if out.planned[0] and memo.planned_arm[0] < 0:
                memo.planned_arm[0] = a
                robot.planned[0] = True
            for j in range(p.strains[0], p.strains[1]):
                q_d[j] = s.q_d[j]
                qd_d[j] = s.qd_d[j]
                robot.qdd_d[j] = out.qdd_d[j]
        for i in range(n):
            lead.q_d[i] = q_d[i]
            lead.qd_d[i] = qd_d[i]
        if robot.planned[0] and event == NO_EVENT:
            robot.event[0] = RECOVERY_PLANNED
    elif all_seen:
        rates = np.empty(n)
        if weights.shape[0] > 0:
            feature_joint_rates(ps, m, q, twists, weights, pressing, axial_weight, False, rates)
        else:
            stacked_joint_rates(ps, m, q, twists, rates)
        follow(take(ps, 0), lead, m, q, rates, t, dt, robot.qdd_d)
    else:  # an arm's target not seen this period (nothing fused yet): hold
        for i in range(n):
            lead.qd_d[i] = 0.0
    for i in range(6):
        robot.twist[i] = twists[0, i]
    robot.rmse[0] = _worst(outs.rmse)
    robot.rmse_measured[0] = _worst(outs.rmse_measured)


@njit(cache=True)
def _worst(values):
    """The largest of the arms' ``values`` (k, 1), NaN if one is."""
    worst = -np.inf
    for a in range(values.shape[0]):
        if not np.isfinite(values[a, 0]):
            return np.nan
        worst = max(worst, values[a, 0])
    return worst
