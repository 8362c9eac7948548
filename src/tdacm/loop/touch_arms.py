"""A squeeze with several arms: every probe touches one object and holds a force estimated
from its own arm's tendons (``[touch] enabled`` with ``[[robot.arms]]``, docs/contact.md,
"The squeeze").

* :class:`ArmsForceBlock`: the force block of every arm (its rod's tip, its probe, along its
  camera's optical axis), tared together; the residual of the model's balance (the momentum
  observer's, or with differenced velocities) is one for the whole system, and the drone's
  rows see every arm's force, so the arms' normal forces are solved together by least squares
  (the compiled :func:`~tdacm.estimation.contact_force.force_step`, as
  :func:`~tdacm.estimation.contact_force.normal_forces_of` solves them).
* :class:`ArmsTouchServo`: the servo of several arms (:class:`~.arms.ArmsServo`) over one
  :class:`~.touch.TouchServo` per arm. Each arm has its own phase (approach, contact, hold,
  release), its own twist and its own force estimate; the steps that need every side wait
  for the others: moving in starts once every arm has held its standoff view for ``dwell``
  s (all estimators tared then), every arm moves in until all have touched; ``settle`` s
  after the last arm's first touch every landing is checked on its arm's task view
  (:func:`~.touch.landing_kept`): if all are kept the hold starts for all and ends after
  ``hold_time`` s, then all release; otherwise the force is unloaded on every arm (the mean
  loop's desired force ramped toward zero at ``force / unload_time`` until it is down to
  ``detect_force``) and every arm goes back to its
  approach to land again. The run's phase (``touch_phase``) is the least advanced arm's.
* :class:`ArmsTouchLog`: the log of several arms with the per-arm touch series
  :data:`TOUCH_ARM_SERIES`.

The joint-rate mapping is the stacked one of :mod:`tdacm.loop.arms` in feature space: arm
``k``'s rows ``L_k Ad(g_{C_Lk}^{Lk})^-1 J_k(q_v)[:, c]`` against ``L_k v_k`` (``L_k`` its
interaction matrix), which converges where the twists' least squares stalls with cameras
looking off vertical; while pressing, the arms' distance rows are replaced by one row for
the sum of their cameras' axial velocities (:data:`AXIAL_WEIGHT`), so the drone may move
one camera forward and the other back for the views (docs/contact.md, "The squeeze").

The force loop: from the first arm's touch, ``touch-target``'s PI law of
:mod:`tdacm.loop.touch` on the arms' mean force error ``F_d - mean_k f_k`` (an arm not yet
down counts zero), along ``a``, the joint displacement of that mapping moving every camera one
metre along its axis (:meth:`ArmsTouchServo.squeeze_direction`), started bumplessly from the
offset it finds; the balance loop (below) moves the arms still off in. Waiting for every
arm's own touch left each probe tapping the object for seconds on the EKF's estimates
(docs/contact.md, "The squeeze on estimates").

The balance loop, on the arms' difference (for two arms the drone's x and the same in-plane
bend of both rods, a weakly damped mode of the views' loop): along each balance direction
``b_j`` (:meth:`ArmsTouchServo.balance_directions`, made orthogonal to ``a``), the correction
``balance_gain (mean_i f_i - f_j) - balance_damping s_j`` (``s_j`` the mode's velocity
``b_j . qdot / |b_j|^2`` over the drone's coordinates on a floating base, low-pass filtered
over ``balance_filter`` from rest) added to the reference the views set, replacing the last
period's (docs/contact.md, "The balance loop", "The squeeze on estimates").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control import Mode
from ..system import kernels as K
from ..vision.tip import rates_from_jacobian
from .arms import ArmServoState, ArmsLog, ArmsServo
from .data import PHASES, ForceReading, ServoCommand
from .servo import normalized_rmse
from .touch import (
    _AXIAL,
    TipForceBlock,
    TouchLaw,
    approach_speed,
    is_pinned,
    landing_kept,
    low_pass,
    release_twist,
    task_image_error,
)

APPROACH, CONTACT, HOLD, RELEASE = PHASES

#: The weight of a pressing arm's axial-velocity row against its feature rows (normalized
#: image units per second; a feature row is about 1 / depth, 3 at the contact pose): the axial
#: motion is met almost exactly, the view's other features in the least squares.
AXIAL_WEIGHT = 10.0

#: Per-arm series of :class:`ArmsTouchLog` (one column per arm).
TOUCH_ARM_SERIES = (
    "force_true_arms", "force_hat_arms", "touch_phase_arms", "contact_force_arms",
    "rmse_local_arms", "rmse_local_true_arms",
)  # fmt: skip


@dataclass(frozen=True)
class ArmsForceReading(ForceReading):
    """Arm 0's :class:`~.data.ForceReading` in the single-arm fields, and every arm's
    (``arms``)."""

    arms: tuple = ()


@dataclass(frozen=True)
class ArmTouchState(ArmServoState):
    """:class:`~.arms.ArmServoState` with the arm's touch phase and filtered force."""

    phase: str = APPROACH
    force: float = math.nan


class ArmsForceBlock(TipForceBlock):
    """The estimated normal force on every arm's probe along its tip camera's optical axis
    (module docstring), solved together from one residual. ``model``: the controller's
    :class:`~tdacm.control.EstimatedModel`; ``mounts``: each arm's ``g_{C_L}^L``;
    ``offset``: the contact sphere's centre in the tip frame (the same for every arm: the
    kernels carry one probe); ``kind``, ``gain``: as :class:`~.touch.TipForceBlock`."""

    def __init__(self, model, mounts, offset, input_sigma: float, kind: str, gain: float):
        super().__init__(model, np.asarray(mounts, float), offset, input_sigma, kind, gain)

    def step(self, est, u_applied, dt: float) -> ArmsForceReading:
        if not self.compute(est, u_applied, dt):
            return ArmsForceReading(est.t)
        o = self.out
        arms = tuple(
            ForceReading(est.t, float(o.force[k]), float(o.sigma[k]), o.normals[k].copy(), True)
            for k in range(self.arms)
        )
        a0 = arms[0]
        return ArmsForceReading(est.t, a0.force, a0.sigma, a0.normal, True, arms)


class ArmsTouchServo(ArmsServo):
    """The squeeze of the module docstring over ``arms``, one
    :class:`~.touch.TouchServo` per arm (each with its rod), sharing ``touch``
    (:class:`~.config.TouchConfig`)."""

    def __init__(self, arms, touch):
        super().__init__(arms)
        for a in self.arms:  # each arm's servo runs its Python methods here, not its own step
            a.as_arm()
        self.touch = touch
        self.law = TouchLaw.from_config(touch)
        self._reset_squeeze()

    def _reset_squeeze(self) -> None:
        k = len(self.arms)
        self.phases = [APPROACH] * k
        self._below_since = [None] * k
        self._touch_t = [None] * k
        self._f = [None] * k
        self._integral = 0.0
        self._hold_end = None
        self._weights = None
        self._pressing = set()
        self._engaged = False  # the force loop runs
        self._qd = None
        self._balance = None  # the balance loop's last correction
        self._rate = None  # its filtered rates
        self._pinned = [False] * k  # each arm's servo on its task view (tdacm.loop.touch)
        self._landings = 0  # the squeeze's landings so far (every arm touched once each)
        self._task_err = [None] * k  # each arm's measured task image error, filtered
        self._unload_t = None  # a landing off the marker: when the force began to ramp down

    def reset(self, q0, first_view=None) -> None:
        super().reset(q0, first_view)
        self._reset_squeeze()

    @property
    def phase(self) -> str:
        """The run's phase: the least advanced arm's."""
        return PHASES[min(PHASES.index(p) for p in self.phases)]

    def _filter(self, k: int, reading, dt: float) -> float:
        tc = self.touch
        f_hat = reading.force if reading is not None and reading.valid else math.nan
        if math.isfinite(f_hat):
            self._f[k] = low_pass(self._f[k], f_hat, dt, tc.force_filter)
        return self._f[k] if self._f[k] is not None else 0.0

    def _transitions(self, t: float, pss, forces) -> bool:
        """The phases' changes this period (module docstring); True: tare the estimators."""
        tc = self.touch
        k = len(self.arms)
        if all(p == APPROACH for p in self.phases):
            for i, (arm, ps) in enumerate(zip(self.arms, pss, strict=True)):
                ok = ps is not None and ps.valid
                if ok and normalized_rmse(ps.points, arm.standoff_points) <= tc.start_rmse:
                    self._below_since[i] = self._below_since[i] or t
                else:
                    self._below_since[i] = None
            if all(b is not None and t - b >= tc.dwell for b in self._below_since):
                self.phases = [CONTACT] * k
                self._f = [None] * k
                return True
            return False
        if self._unload_t is not None:  # the force ramped down on every arm, then back off
            # the probes leave once the ramp is down to detect_force (a touch by the law's own
            # measure): ramped further, they slid off the object one after the other, each
            # slide a jump of the views (docs/contact.md, "The squeeze on estimates")
            if self.desired_force(t) <= tc.detect_force + 1e-12:
                self._land_again()
            return False
        for i in range(k):
            if self.phases[i] == CONTACT and self._touch_t[i] is None:
                if forces[i] >= tc.detect_force:
                    self._touch_t[i] = t
                    if all(tt is not None for tt in self._touch_t):
                        self._landings += 1  # every probe down: one landing of the squeeze
        if self._hold_end is None and all(tt is not None for tt in self._touch_t):
            if t - max(self._touch_t) >= tc.settle:
                kept = [landing_kept(e, self._landings, self.law) for e in self._task_err]
                if all(kept):
                    self.phases = [HOLD] * k
                    self._hold_end = t + tc.hold_time
                else:  # unload every probe, then land again from the standoff views
                    self._unload_t = t
        elif self._hold_end is not None and t >= self._hold_end - 1e-9:
            self.phases = [RELEASE] * k
        return False

    def _land_again(self) -> None:
        """After the unloading of a landing off the marker (docs/contact.md, "The squeeze on
        estimates"): every arm goes back to its approach (the standoff view, leaving the
        surface at no more than ``approach_speed``), the force and balance loops disengaged;
        the squeeze moves in again once every arm has held its standoff view for ``dwell`` s
        (the estimators tared again then)."""
        k = len(self.arms)
        self.phases = [APPROACH] * k
        self._below_since = [None] * k
        self._unload_t = None
        self._touch_t = [None] * k
        self._task_err = [None] * k
        self._engaged = False
        self._integral = 0.0
        self._balance = None
        self._rate = None

    def desired_force(self, t: float) -> float:
        """The mean loop's desired force at ``t``: ``touch.force``, ramped linearly toward
        zero at ``force / unload_time`` once a landing off the marker is unloaded (both arms
        together, the balance loop still on: a probe leaving first would push the drone
        sideways), until it is down to ``detect_force`` and the arms go back to their
        approach."""
        tc = self.touch
        if self._unload_t is None:
            return tc.force
        return tc.force * max(0.0, 1.0 - (t - self._unload_t) / tc.unload_time)

    def step(self, t: float, dt: float, view, gview, est, twist=None, force=None) -> ServoCommand:
        q = est.q
        tc = self.touch
        for a in self.arms:
            a._ps = None
        per = [a.perceive(t, dt, v, est) for a, v in zip(self.arms, view.arms, strict=True)]
        pss = [a._ps for a in self.arms]
        readings = getattr(force, "arms", ()) or (None,) * len(self.arms)
        forces = [self._filter(k, r, dt) for k, r in enumerate(readings)]
        prev_phase, prev_arms = self.phase, list(self.phases)
        for k, (arm, v) in enumerate(zip(self.arms, view.arms, strict=True)):
            if self._touch_t[k] is not None and v.found:  # where the landed probe aims
                err = task_image_error(v.points, arm.local_points)
                self._task_err[k] = low_pass(self._task_err[k], err, dt, tc.land_filter)
        tare = self._transitions(t, pss, forces)
        if tare:
            forces = [0.0] * len(self.arms)
        modes, event = self._robot_event(per)
        valid = [ps is not None and ps.valid for ps in pss]
        seen_all = all(p[2] for p in per) and all(valid)
        external = None if twist is None else np.asarray(twist, float).reshape(len(per), 6)
        states, twists, weights = [], [], []
        pinned = [is_pinned(ph, tt is not None, tc.contact_view)
                  for ph, tt in zip(self.phases, self._touch_t, strict=True)]  # fmt: skip
        switched = pinned != self._pinned  # a view changes: the safety monitor re-arms
        self._pinned = pinned
        lvs = [arm.local_view(q) if p else None for arm, p in zip(self.arms, pinned, strict=True)]
        if any(pinned):  # a pinned arm reads its C_L view (the task's)
            valid = [lv.valid if lv is not None else v for lv, v in zip(lvs, valid, strict=True)]
            seen_all = all(p[2] for p in per) and all(valid)
        all_touched = all(tt is not None for tt in self._touch_t)
        for k, (arm, p, ps, lv) in enumerate(zip(self.arms, per, pss, lvs, strict=True)):
            mode, points, rmse, measured = p[0], p[4], p[7], p[8].get("rmse_measured", math.nan)
            v = np.zeros(6)
            phase = self.phases[k]
            view_k, law = ps, arm.standoff_ibvs
            if phase in (CONTACT, HOLD):
                law = arm.ibvs
            if lv is not None:
                view_k, law = lv, arm.local_ibvs
                points = lv.points
                rmse = task_image_error(lv.points, arm.local_points) if lv.valid else math.nan
                pts = view.arms[k].points if view.arms[k].found else None
                measured = task_image_error(pts, arm.local_points)
            if mode == Mode.IBVS and seen_all:
                if external is not None:
                    v = external[k].copy()
                elif lv is not None:
                    v = arm.pinned_twist(lv, ps)
                elif phase in (CONTACT, HOLD):
                    e = ps.error.copy()
                    e[5] = 0.0  # p_z (the distance) is the force loop's
                    v = arm.ibvs.twist(ps.points, ps.depths, error=e)
                    v[5] = 0.0  # after the touch the axis is the admittance's (below)
                else:
                    v = arm.standoff_ibvs.features_error_twist(ps.points, ps.depths)[2]
                    if phase == RELEASE or self._landings:  # leaving the surface
                        v = release_twist(np.asarray(v, float), self.law)
                if phase in (CONTACT, HOLD) and external is None and not all_touched:
                    v[5] = approach_speed(arm._depth, view_k.error[5], view_k.features[5], self.law)
            if phase in (APPROACH, RELEASE) and ps is not None and ps.valid:
                rmse = normalized_rmse(ps.points, arm.standoff_points)
            if view_k is not None and view_k.valid:
                weights.append(law.interaction(view_k.points, view_k.depths))
            twists.append(v)
            states.append(ArmTouchState(points, rmse, measured, v, bool(p[2]), phase,
                                        forces[k]))  # fmt: skip
        self._weights = weights if len(weights) == len(self.arms) else None
        self._pressing = {k for k, p in enumerate(self.phases) if p in (CONTACT, HOLD)}
        qdd_d, request, failure, plan, event, following = self._joint_command(
            t, dt, q, gview, modes, seen_all, twists, event
        )
        if following:
            self._qd = est.qd
            self._admittance(q, forces, dt, self.desired_force(t))
        if prev_phase != self.phase:
            event = f"touch: {self.phase}"
        return self._command(
            per, states, twists, qdd_d, event, failure, request, plan, phase=self.phase,
            tare_force=tare, phase_changed=prev_arms != self.phases or switched,
            landing=self._landings,
        )  # fmt: skip

    def joint_rates(self, q, twists, pressing=None, separate: bool = False) -> np.ndarray:
        """The stacked mapping (:meth:`~.arms.ArmsServo.joint_rates`) in feature space
        (module docstring): arm k's rows ``L_k Ad(g_{C_Lk}^{Lk})^-1 J_k(q_v)[:, c]``, its
        right-hand side ``L_k v_k``, with ``L_k`` its interaction matrix this period; for an
        arm in ``pressing`` (default: those in contact or hold) the distance row of ``L_k``
        is replaced by its camera's axial velocity, weighted by :data:`AXIAL_WEIGHT`: one row
        for the sum of the pressing arms' (``separate``: one row per arm). Without the
        interaction matrices (no view yet) the twists' least squares."""
        if self._weights is None:
            return super().joint_rates(q, twists)
        pressing = self._pressing if pressing is None else pressing
        rows, rhs = [], []
        axial, speed = np.zeros(self.n), 0.0
        for k, (a, v, w) in enumerate(zip(self.arms, twists, self._weights, strict=True)):
            jc = a._ad_mount_inv @ a.task_jacobian(q)
            if k in pressing:
                rows.append(w[:5] @ jc)
                rhs.append(w[:5] @ v)
                if separate:
                    rows.append(AXIAL_WEIGHT * jc[5][None, :])
                    rhs.append([AXIAL_WEIGHT * v[5]])
                axial += jc[5]
                speed += v[5]
            else:
                rows.append(w @ jc)
                rhs.append(w @ v)
        if pressing and not separate:
            rows.append(AXIAL_WEIGHT * axial[None, :])
            rhs.append([AXIAL_WEIGHT * speed])
        return rates_from_jacobian(np.vstack(rows), np.concatenate(rhs), self.arms[0]._cmd)

    def squeeze_direction(self, q) -> np.ndarray:
        """``(n,)``: the joint displacement of the stacked mapping (:meth:`joint_rates`, every
        arm pressing) that moves the arms' cameras one metre along their optical axes (the
        sum of their axial displacements: ``k`` metres), every view's other features as that
        motion leaves them (least squares)."""
        k = len(self.arms)
        return self.joint_rates(q, [_AXIAL] * k, set(range(k)))

    def balance_directions(self, q) -> list:
        """The ``k - 1`` joint displacements of the stacked mapping (:meth:`joint_rates`,
        every arm pressing, one axial row per arm) that move arm ``j``'s camera one metre
        forward along its axis and every camera ``-1 / k`` m (the arms' axial sum unchanged),
        every view's other features as that motion leaves them; for two arms the one
        direction ``b`` moving camera 0 half a metre in and camera 1 half a metre out."""
        k = len(self.arms)
        out = []
        for j in range(k - 1):
            d = [((1.0 if i == j else 0.0) - 1.0 / k) * _AXIAL for i in range(k)]
            out.append(self.joint_rates(q, d, set(range(k)), separate=True))
        return out

    def _admittance(self, q, forces, dt: float, force: float) -> None:
        """The squeeze's force loops (module docstring), from the first arm's touch: the
        mean loop along ``a`` to the desired ``force``, then the balance loop
        (:meth:`_balance_step`)."""
        tc = self.touch
        lead = self.arms[0]
        if not all(p in (CONTACT, HOLD) for p in self.phases):
            return
        # from the first touch: the mean loop pushes on while the other probes are still off
        # (its error counts their zero force) and the balance loop moves them in, instead of
        # each probe tapping the object until its own estimate reaches detect_force
        if not any(tt is not None for tt in self._touch_t):
            return
        a = self.squeeze_direction(q)
        aa = float(a @ a)
        if aa == 0.0:
            return
        err = force - float(np.mean(forces))
        now = float(a @ (lead.q_d - q)) / aa
        if not self._engaged:  # bumpless: the PI starts from the offset it finds
            self._engaged = True
            self._integral = now - tc.force_gain * err
        self._integral += tc.force_integral * err * dt
        offset = tc.force_gain * err + self._integral
        lead.q_d = lead.q_d + a * (offset - now)
        lead.qd_d = lead.qd_d - a * (float(a @ lead.qd_d) / aa)
        if tc.balance_gain or tc.balance_damping:
            self._balance_step(q, a, forces, dt)

    def _balance_step(self, q, a, forces, dt: float) -> None:
        """The balance loop (module docstring): along each balance direction ``b_j``
        (:meth:`balance_directions`, made orthogonal to ``a`` so that the mean loop's offset
        is left as it is), the correction ``g (mean_i f_i - f_j) - c b_j . qdot / |b_j|^2``
        added to the reference the views set (``g``: ``balance_gain``, ``c``:
        ``balance_damping``); each period replaces the last period's correction."""
        tc = self.touch
        lead = self.arms[0]
        aa = float(a @ a)
        dirs = [b - a * (float(a @ b) / aa) for b in self.balance_directions(q)]
        qd = np.zeros(self.n) if self._qd is None else np.asarray(self._qd, float)
        # the mode's velocity read from the drone's coordinates on a floating base (the rods'
        # strain rates are the estimate's noisiest, differenced encoders: docs/contact.md)
        m = slice(0, 6) if lead._flying else slice(None)
        rate = np.array([float(b[m] @ qd[m]) / float(b[m] @ b[m]) for b in dirs])
        if tc.balance_filter <= 0:
            self._rate = rate
        else:  # from rest when the loop engages: one period's rate is mostly noise on estimates
            prev = np.zeros(len(dirs)) if self._rate is None else self._rate
            self._rate = prev + min(1.0, dt / tc.balance_filter) * (rate - prev)
        mean = float(np.mean(forces))
        corr = np.array([tc.balance_gain * (mean - forces[j]) for j in range(len(dirs))])
        corr = corr - tc.balance_damping * self._rate
        # what the reference's leak toward q (RobustServo.follow_rates) left of the last
        # period's correction
        keep = 1.0 - lead.config.reference_leak * dt if lead._flying else 1.0
        prev = np.zeros(len(dirs)) if self._balance is None else keep * self._balance
        lead.q_d = lead.q_d + np.column_stack(dirs) @ (corr - prev)
        self._balance = corr


def _worst(x) -> float:
    """The largest finite entry of ``x`` (NaN if there is none)."""
    x = np.asarray(x, float)
    f = np.isfinite(x)
    return float(x[f].max()) if f.any() else math.nan


def arm_contact_forces(system, contact):
    """``(q, qd) -> (k, 3)``: the obstacles' total force on each arm (its rod's capsules and
    its tip sphere, inertial, N), from the contact kernel's per-node forces."""
    m = system.model_arrays
    rod_of = []
    for rod in range(m.rod_steps.shape[0] - 1):
        rod_of.append(rod)  # the rod base
        for k in range(m.rod_steps[rod], m.rod_steps[rod + 1]):
            if m.step_w[k] != 0.0 and m.step_load[k] != K.LOAD_GRAVITY:
                rod_of.append(rod)
    rod_of = np.asarray(rod_of)
    nrod = m.rod_steps.shape[0] - 1

    def forces(q, qd) -> np.ndarray:
        f = K.contact_nodes(np.asarray(q, float), np.asarray(qd, float), m, contact)[1]
        out = np.zeros((nrod, 3))
        np.add.at(out, rod_of, f)
        return out

    return forces


class ArmsTouchLog(ArmsLog):
    """:class:`~.arms.ArmsLog` with the squeeze's per-arm series :data:`TOUCH_ARM_SERIES`
    (each arm's true contact force along its estimate's normal, its estimate, its phase and
    the norm of the obstacles' total force on it); ``force_true`` is the arms' mean of theirs
    (the summary judges each arm, :func:`tdacm.sim.runner.touch_summary`). ``arm_forces``:
    :func:`arm_contact_forces`."""

    def __init__(self, desired, frame_composer=None, truths=None, arm_forces=None,
                 local_references=None, truths_local=None):  # fmt: skip
        super().__init__(desired, frame_composer, truths)
        self.arm_forces = arm_forces
        #: each arm's reference snapshot in its C_L and ``q -> (true points in its C_L, pose)``
        #: (the task's image errors ``rmse_local_arms``, ``rmse_local_true_arms``)
        self.local_references = None if local_references is None else list(local_references)
        self.truths_local = None if truths_local is None else list(truths_local)

    def record(self, plant, readings, view, estimate, cmd, act, force=None) -> None:
        super().record(plant, readings, view, estimate, cmd, act, force)
        r = self.rows
        k = len(self.desired)
        per = self.arm_forces(plant.q, plant.qd) if self.arm_forces else np.full((k, 3), np.nan)
        arms = getattr(force, "arms", ())
        true = np.full(k, np.nan)
        hat = np.full(k, np.nan)
        for i, fr in enumerate(arms):
            if fr.valid:
                true[i] = float(per[i] @ fr.normal)
                hat[i] = fr.force
        if not arms:
            true = np.linalg.norm(per, axis=1)
        states = cmd.arms or ()
        phases = np.array([PHASES.index(s.phase) if getattr(s, "phase", None) in PHASES else -1
                           for s in states] if len(states) == k else [-1] * k)  # fmt: skip
        r.setdefault("force_true_arms", []).append(true)
        r.setdefault("force_hat_arms", []).append(hat)
        r.setdefault("touch_phase_arms", []).append(phases)
        r.setdefault("contact_force_arms", []).append(np.linalg.norm(per, axis=1))
        measured, truth = np.full(k, np.nan), np.full(k, np.nan)
        views = getattr(view, "arms", ())
        for i, ref in enumerate(self.local_references or ()):
            if len(views) == k and views[i].found:
                measured[i] = task_image_error(views[i].points, ref)
            if self.truths_local is not None:
                truth[i] = task_image_error(self.truths_local[i](plant.q)[0], ref)
        r.setdefault("rmse_local_arms", []).append(measured)
        r.setdefault("rmse_local_true_arms", []).append(truth)
        if "rmse_local" in r:  # the single-arm series: the worse arm's
            r["rmse_local"][-1] = _worst(measured)
            r["rmse_local_true"][-1] = _worst(truth)
        if "force_true" in r:
            r["force_true"][-1] = float(np.mean(true))
            r["force_hat"][-1] = float(np.mean(hat))


__all__ = [
    "TOUCH_ARM_SERIES",
    "ArmTouchState",
    "ArmsForceBlock",
    "ArmsForceReading",
    "ArmsTouchLog",
    "ArmsTouchServo",
    "arm_contact_forces",
]
