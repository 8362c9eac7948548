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
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numba import njit

from .._records import stack, take
from ..system import kernels as K
from ..vision.ibvs import ibvs_law, ibvs_twist_of, law_interaction
from .arms import (
    ArmServoState,
    ArmsLog,
    ArmsServo,
    arms_command,
    feature_joint_rates,
    twist_arguments,
)
from .data import PHASES, ForceReading, ServoCommand
from .servo import IBVS, NO_FAILURE, rmse_to
from .touch import (
    APPROACH_CODE,
    CONTACT_CODE,
    HOLD_CODE,
    RELEASE_CODE,
    TipForceBlock,
    TouchLaw,
    _local_view,
    approach_speed,
    landing_kept_step,
    low_pass_step,
    pinned_error_into,
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


# ============================================================================ compiled step
class SqueezeLaw(NamedTuple):
    """The squeeze's own settings (``[touch]``, :class:`~.config.TouchConfig`) beside the
    touch law's (:class:`~.touch.TouchLaw`): the unloading's ``unload_time`` (s) and the
    balance loop's ``balance_gain`` (m/N), ``balance_damping`` and ``balance_filter`` (s)."""

    unload_time: float
    balance_gain: float
    balance_damping: float
    balance_filter: float

    @classmethod
    def from_config(cls, tc) -> SqueezeLaw:
        return cls(*(float(getattr(tc, f)) for f in cls._fields))


class SqueezeState(NamedTuple):
    """The squeeze's state, per arm (k,): its ``phase`` (an index of :data:`~.data.PHASES`),
    since when it has held its standoff view (``below_since``), its touch of this landing
    (``touch_t``), its filtered force estimate ``f`` and the force used this period
    ``f_used`` (zero at the tare), its filtered task image error ``task_err``, whether its
    servo reads the pinned view (``pinned``); of the squeeze (one-element arrays): the mean
    loop's ``integral`` and whether it runs (``engaged``), the unloading's start
    (``unload_t``), the hold's end (``hold_end``), the ``landings`` so far, and the balance
    loop's last correction ``balance`` (k - 1,) and filtered rates ``rate`` (k - 1,), each
    valid once set (``balance_on``, ``rate_on``). NaN: not set."""

    phase: np.ndarray
    below_since: np.ndarray
    touch_t: np.ndarray
    f: np.ndarray
    f_used: np.ndarray
    task_err: np.ndarray
    pinned: np.ndarray
    integral: np.ndarray
    engaged: np.ndarray
    unload_t: np.ndarray
    hold_end: np.ndarray
    landings: np.ndarray
    balance: np.ndarray
    balance_on: np.ndarray
    rate: np.ndarray
    rate_on: np.ndarray

    @classmethod
    def initial(cls, k: int) -> SqueezeState:
        nan = lambda n: np.full(n, np.nan)  # noqa: E731
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        s = cls(np.zeros(k, np.int64), nan(k), nan(k), nan(k), np.zeros(k), nan(k),
                np.zeros(k, np.bool_), np.zeros(1), b1(), nan(1), nan(1), np.zeros(1, np.int64),
                np.zeros(k - 1), b1(), np.zeros(k - 1), b1())  # fmt: skip
        squeeze_reset(s)
        return s


class SqueezeOut(NamedTuple):
    """What the squeeze did in a period (written by :func:`squeeze_perceive`): the force
    estimators are to be tared (``tare``), an arm's phase or view changed (``phase_changed``:
    the safety monitor re-arms), the run's phase changed (``run_changed``); each arm's C_V
    view predicted this period (``ps_valid`` (k,), ``ps_error`` (k, 6)), whether it presses
    (``pressing`` (k,)) and the interaction matrix of the view its law servoes on
    (``weights`` (k, 6, 6); ``weights_ok``: every arm has one), the rows of the mapping in
    feature space (:func:`~.arms.feature_joint_rates`)."""

    tare: np.ndarray
    phase_changed: np.ndarray
    run_changed: np.ndarray
    ps_valid: np.ndarray
    ps_error: np.ndarray
    pressing: np.ndarray
    weights: np.ndarray
    weights_ok: np.ndarray

    @classmethod
    def empty(cls, k: int) -> SqueezeOut:
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        return cls(b1(), b1(), b1(), np.zeros(k, np.bool_), np.zeros((k, 6)),
                   np.zeros(k, np.bool_), np.zeros((k, 6, 6)), b1())  # fmt: skip


@njit(cache=True)
def squeeze_reset(s):
    """The squeeze's state as built: every arm approaching, nothing measured, no landing."""
    for a in range(s.phase.shape[0]):
        s.phase[a] = APPROACH_CODE
        s.below_since[a] = np.nan
        s.touch_t[a] = np.nan
        s.f[a] = np.nan
        s.f_used[a] = 0.0
        s.task_err[a] = np.nan
        s.pinned[a] = False
    s.landings[0] = 0
    _land_again(s)


@njit(cache=True)
def _land_again(s):
    """Every arm back to its approach after the unloading of a landing off the marker (the
    standoff view, leaving the surface at no more than ``approach_speed``), the force and
    balance loops disengaged; the squeeze moves in again once every arm has held its standoff
    view for ``dwell`` s (the estimators tared again then)."""
    for a in range(s.phase.shape[0]):
        s.phase[a] = APPROACH_CODE
        s.below_since[a] = np.nan
        s.touch_t[a] = np.nan
        s.task_err[a] = np.nan
    s.unload_t[0] = np.nan
    s.hold_end[0] = np.nan
    s.engaged[0] = False
    s.integral[0] = 0.0
    s.balance[:] = 0.0
    s.balance_on[0] = False
    s.rate[:] = 0.0
    s.rate_on[0] = False


@njit(cache=True)
def desired_force(tl, sl, s, t):
    """The mean loop's desired force at ``t`` (N): ``force``, ramped linearly toward zero at
    ``force / unload_time`` once a landing off the marker is unloaded (both arms together,
    the balance loop still on: a probe leaving first would push the drone sideways), until it
    is down to ``detect_force`` and the arms go back to their approach."""
    if not np.isfinite(s.unload_t[0]):
        return tl.force
    return tl.force * max(0.0, 1.0 - (t - s.unload_t[0]) / sl.unload_time)


@njit(cache=True)
def _touched(s, a):
    return np.isfinite(s.touch_t[a])


@njit(cache=True)
def squeeze_transitions(tl, sl, trs, s, outs, t, forces):
    """The phases' changes this period (module docstring) from each arm's C_V prediction in
    ``outs`` and the filtered ``forces``; True: the force estimators are to be tared."""
    k = s.phase.shape[0]
    approaching = True
    for a in range(k):
        approaching = approaching and s.phase[a] == APPROACH_CODE
    if approaching:
        ready = True
        for a in range(k):
            tr = take(trs, a)
            if outs.seen[a, 0] and rmse_to(outs.points[a], tr.standoff_points) <= tl.start_rmse:
                if not np.isfinite(s.below_since[a]):
                    s.below_since[a] = t
            else:
                s.below_since[a] = np.nan
            ready = ready and np.isfinite(s.below_since[a]) and t - s.below_since[a] >= tl.dwell
        if ready:
            for a in range(k):
                s.phase[a] = CONTACT_CODE
                s.f[a] = np.nan
            return True
        return False
    if np.isfinite(s.unload_t[0]):  # the force ramped down on every arm, then back off
        # the probes leave once the ramp is down to detect_force (a touch by the law's own
        # measure): ramped further, they slid off the object one after the other, each
        # slide a jump of the views (docs/contact.md, "The squeeze on estimates")
        if desired_force(tl, sl, s, t) <= tl.detect_force + 1e-12:
            _land_again(s)
        return False
    for a in range(k):
        if s.phase[a] == CONTACT_CODE and not _touched(s, a) and forces[a] >= tl.detect_force:
            s.touch_t[a] = t
            every = True
            for b in range(k):
                every = every and _touched(s, b)
            if every:
                s.landings[0] += 1  # every probe down: one landing of the squeeze
    every = True
    last = -np.inf
    for a in range(k):
        every = every and _touched(s, a)
        last = max(last, s.touch_t[a])
    if not np.isfinite(s.hold_end[0]) and every:
        if t - last >= tl.settle:
            kept = True
            for a in range(k):
                kept = kept and landing_kept_step(s.task_err[a], s.landings[0], tl)
            if kept:
                for a in range(k):
                    s.phase[a] = HOLD_CODE
                s.hold_end[0] = t + tl.hold_time
            else:  # unload every probe, then land again from the standoff views
                s.unload_t[0] = t
    elif np.isfinite(s.hold_end[0]) and t >= s.hold_end[0] - 1e-9:
        for a in range(k):
            s.phase[a] = RELEASE_CODE
    return False


@njit(cache=True)
def _run_phase(s):
    """The run's phase: the least advanced arm's."""
    p = s.phase[0]
    for a in range(1, s.phase.shape[0]):
        p = min(p, s.phase[a])
    return p


@njit(cache=True)
def squeeze_perceive(tl, sl, trs, s, ps, ss, m, t, dt, q, found, xy, f_hat, outs, sout):
    """The first part of a period of the squeeze (:class:`ArmsTouchServo`, module
    docstring), after every arm's :func:`~.servo.servo_perceive` into its row of ``outs``
    (``ps``, ``ss``, ``trs``: the arms' servo and touch records, stacked; each arm's frame
    ``found`` (k,) with its normalized points ``xy`` (k, 4, 2), its force estimate ``f_hat``
    (k,), NaN: none): the forces filtered, the landed probes' task errors, the phases'
    changes, and each arm's view (the pinned view in C_L once its probe is pinned), the twist
    of its phase into ``outs.ibvs_twist``, the RMSE the safety monitor watches into
    ``outs.rmse``, and ``outs.seen`` (the arm's view and, pinned, its C_L view); what changed
    and the mapping's rows into ``sout``."""
    k = s.phase.shape[0]
    prev = s.phase.copy()
    prev_run = _run_phase(s)
    for a in range(k):
        sout.ps_valid[a] = outs.seen[a, 0]
        for i in range(6):
            sout.ps_error[a, i] = outs.error[a, i]
    forces = np.zeros(k)
    for a in range(k):  # the force estimates, low-pass filtered (force_filter)
        if np.isfinite(f_hat[a]):
            s.f[a] = low_pass_step(s.f[a], f_hat[a], dt, tl.force_filter)
        forces[a] = s.f[a] if np.isfinite(s.f[a]) else 0.0
    for a in range(k):  # where each landed probe aims (pixels)
        if _touched(s, a) and found[a]:
            err = rmse_to(xy[a], trs.local_points[a])
            s.task_err[a] = low_pass_step(s.task_err[a], err, dt, tl.land_filter)
    tare = squeeze_transitions(tl, sl, trs, s, outs, t, forces)
    if tare:  # the force loops start from the tared estimates
        forces[:] = 0.0
    every = True
    seen_all = True
    for a in range(k):
        s.f_used[a] = forces[a]
        every = every and _touched(s, a)
        seen_all = seen_all and outs.seen[a, 0]
    switched = False
    pinned = np.zeros(k, np.bool_)
    lxy = np.zeros((k, 4, 2))
    lz = np.zeros((k, 4))
    lf = np.zeros((k, 6))
    le = np.zeros((k, 6))
    lvalid = np.zeros(k, np.bool_)
    for a in range(k):
        pressing = s.phase[a] == CONTACT_CODE or s.phase[a] == HOLD_CODE
        sout.pressing[a] = pressing
        pinned[a] = _touched(s, a) and pressing and tl.contact_local
        switched = switched or pinned[a] != s.pinned[a]
        s.pinned[a] = pinned[a]
        if pinned[a]:  # a pinned arm reads its C_L view (the task's)
            lvalid[a] = _local_view(take(ps, a), take(ss, a), m, q, take(trs, a), lxy[a], lz[a],
                                    lf[a], le[a])  # fmt: skip
            seen_all = seen_all and lvalid[a]
    sout.weights_ok[0] = True
    for a in range(k):
        p, tr, out = take(ps, a), take(trs, a), take(outs, a)
        phase = s.phase[a]
        pressing = sout.pressing[a]
        ps_valid = out.seen[0]
        if pinned[a]:  # the task's view replaces C_V's prediction in the arm's outputs
            out.points[:, :] = lxy[a]
            out.depths[:] = lz[a]
            out.features[:] = lf[a]
            out.error[:] = le[a]
            out.rmse[0] = rmse_to(lxy[a], tr.local_points) if lvalid[a] else np.nan
            out.rmse_measured[0] = rmse_to(xy[a], tr.local_points) if found[a] else np.nan
            valid = lvalid[a]
            desired_interaction = tr.local_interaction
        else:
            valid = ps_valid
            desired_interaction = p.desired_interaction if pressing else tr.standoff_interaction
        v = np.zeros(6)
        if out.mode[0] == IBVS and seen_all:
            if pinned[a]:  # the pinned law: C_L's attitude rows and the lean
                e = np.empty(6)
                pinned_error_into(le[a], sout.ps_error[a], sout.ps_valid[a], e)
                v = ibvs_twist_of(lxy[a], lz[a], e, tr.local_interaction, p.interaction, p.gain,
                                  p.floor, p.damped)  # fmt: skip
                v[5] = 0.0  # the axis is the force loop's
            elif pressing:
                e = out.error.copy()
                e[5] = 0.0  # p_z (the distance) is the force loop's
                v = ibvs_twist_of(out.points, out.depths, e, p.desired_interaction,
                                  p.interaction, p.gain, p.floor, p.damped)  # fmt: skip
                v[5] = 0.0  # after the touch the axis is the force loop's
            else:
                _, _, v = ibvs_law(out.points, out.depths, tr.standoff_features,
                                   tr.standoff_interaction, p.interaction, p.gain, p.floor,
                                   p.damped)  # fmt: skip
                if phase == RELEASE_CODE or s.landings[0] > 0:  # leaving the surface
                    v = release_twist(v, tl)
            if pressing and not every:  # moving in until every probe is down
                v[5] = approach_speed(tr.depth, out.error[5], out.features[5], tl)
        if (phase == APPROACH_CODE or phase == RELEASE_CODE) and ps_valid:
            # the RMSE the safety monitor watches: to the view this phase servoes to
            out.rmse[0] = rmse_to(out.points, tr.standoff_points)
        if valid:
            sout.weights[a] = law_interaction(out.points, out.depths, desired_interaction,
                                              p.interaction)  # fmt: skip
        else:
            sout.weights_ok[0] = False
        out.ibvs_twist[:] = v
        out.seen[0] = ps_valid and valid  # arms_command follows the rates when all are
    changed = switched
    for a in range(k):
        changed = changed or prev[a] != s.phase[a]
    sout.tare[0] = tare
    sout.phase_changed[0] = changed
    sout.run_changed[0] = prev_run != _run_phase(s)


@njit(cache=True)
def squeeze_command(tl, sl, s, sout, ps, ss, m, t, dt, q, qd, offered, twist_in, g_found,
                    corners, marker_seen, outs, memo, robot):  # fmt: skip
    """The end of a period of the squeeze (after :func:`squeeze_perceive`): the command of
    the servo of several arms (:func:`~.arms.arms_command`) on the arms' twists through the
    stacked mapping in feature space (:func:`~.arms.feature_joint_rates`, the pressing arms'
    distance rows replaced by their axial velocities' sum), then, when the arms' rates were
    followed, the force loops (:func:`squeeze_force_loops`; ``qd`` the estimate's
    velocities)."""
    weights = sout.weights if sout.weights_ok[0] else np.zeros((0, 6, 6))
    arms_command(ps, ss, m, t, dt, q, offered, twist_in, g_found, corners, marker_seen, outs,
                 memo, robot, weights, sout.pressing, AXIAL_WEIGHT)  # fmt: skip
    if robot.failure[0] != NO_FAILURE:
        return
    if robot.mode[0] == IBVS and robot.seen[0] and sout.weights_ok[0]:
        squeeze_force_loops(tl, sl, s, ps, take(ss, 0), m, t, dt, q, qd, sout.weights)


@njit(cache=True)
def squeeze_direction(ps, m, q, weights, out):
    """``a`` (n,) into ``out``: the joint displacement of the stacked mapping in feature space
    (every arm pressing, the arms' interaction matrices ``weights``) that moves the arms'
    cameras one metre along their optical axes (the sum of their axial displacements: ``k``
    metres), every view's other features as that motion leaves them (least squares)."""
    k = weights.shape[0]
    twists = np.zeros((k, 6))
    twists[:, 5] = 1.0
    feature_joint_rates(ps, m, q, twists, weights, np.ones(k, np.bool_), AXIAL_WEIGHT, False,
                        out)  # fmt: skip


@njit(cache=True)
def balance_directions(ps, m, q, weights, out):
    """The ``k - 1`` joint displacements ``b_j`` (``out`` (k - 1, n)) of the stacked mapping
    (every arm pressing, one axial row per arm) that move arm ``j``'s camera one metre forward
    along its axis and every camera ``-1 / k`` m (the arms' axial sum unchanged), every view's
    other features as that motion leaves them; for two arms the one direction ``b`` moving
    camera 0 half a metre in and camera 1 half a metre out."""
    k = weights.shape[0]
    pressing = np.ones(k, np.bool_)
    for j in range(k - 1):
        twists = np.zeros((k, 6))
        for i in range(k):
            twists[i, 5] = (1.0 if i == j else 0.0) - 1.0 / k
        feature_joint_rates(ps, m, q, twists, weights, pressing, AXIAL_WEIGHT, True, out[j])


@njit(cache=True)
def squeeze_force_loops(tl, sl, s, ps, lead, m, t, dt, q, qd, weights):
    """The squeeze's force loops (module docstring), from the first arm's touch while every
    arm presses: the mean loop, ``touch-target``'s PI law on ``F_d - mean_k f_k`` along ``a``
    (:func:`squeeze_direction`), started bumplessly from the offset it finds, setting the
    lead arm's reference ``q_d`` along ``a`` and removing ``qd_d``'s part along it; then the
    balance loop (:func:`balance_step`)."""
    k = s.phase.shape[0]
    touched = False
    for a in range(k):
        if not (s.phase[a] == CONTACT_CODE or s.phase[a] == HOLD_CODE):
            return
        touched = touched or _touched(s, a)
    # from the first touch: the mean loop pushes on while the other probes are still off
    # (its error counts their zero force) and the balance loop moves them in, instead of
    # each probe tapping the object until its own estimate reaches detect_force
    if not touched:
        return
    n = q.shape[0]
    a_dir = np.empty(n)
    squeeze_direction(ps, m, q, weights, a_dir)
    aa = 0.0
    for i in range(n):
        aa += a_dir[i] * a_dir[i]
    if aa == 0.0:
        return
    mean = 0.0
    for a in range(k):
        mean += s.f_used[a]
    mean /= k
    err = desired_force(tl, sl, s, t) - mean
    now = 0.0
    for i in range(n):
        now += a_dir[i] * (lead.q_d[i] - q[i])
    now /= aa
    if not s.engaged[0]:  # bumpless: the PI starts from the offset it finds
        s.engaged[0] = True
        s.integral[0] = now - tl.force_gain * err
    s.integral[0] += tl.force_integral * err * dt
    offset = tl.force_gain * err + s.integral[0]
    along = 0.0
    for i in range(n):
        lead.q_d[i] += a_dir[i] * (offset - now)
        along += a_dir[i] * lead.qd_d[i]
    along /= aa
    for i in range(n):
        lead.qd_d[i] -= a_dir[i] * along
    if sl.balance_gain != 0.0 or sl.balance_damping != 0.0:
        balance_step(sl, s, ps, take(ps, 0), lead, m, dt, q, qd, a_dir, weights)


@njit(cache=True)
def balance_step(sl, s, ps, lead_params, lead, m, dt, q, qd, a_dir, weights):
    """The balance loop (module docstring): along each balance direction ``b_j``
    (:func:`balance_directions`, made orthogonal to ``a_dir`` so that the mean loop's offset
    is left as it is), the correction ``g (mean_i f_i - f_j) - c s_j`` added to the lead's
    reference ``q_d`` (``g``: ``balance_gain``, ``c``: ``balance_damping``, ``s_j`` the mode's
    velocity ``b_j . qdot / |b_j|^2`` over the drone's coordinates on a floating base, the
    estimate's ``qd``, low-pass filtered over ``balance_filter`` from rest); each period
    replaces the last period's correction (what the reference's leak toward ``q`` left of
    it)."""
    k = s.phase.shape[0]
    n = q.shape[0]
    nb = k - 1
    dirs = np.empty((nb, n))
    balance_directions(ps, m, q, weights, dirs)
    aa = 0.0
    for i in range(n):
        aa += a_dir[i] * a_dir[i]
    # the mode's velocity read from the drone's coordinates on a floating base (the rods'
    # strain rates are the estimate's noisiest, differenced encoders: docs/contact.md)
    cols = 6 if m.floating else n
    mean = 0.0
    for a in range(k):
        mean += s.f_used[a]
    mean /= k
    keep = 1.0 - lead_params.leak * dt if m.floating else 1.0
    corr = np.empty(nb)
    for j in range(nb):
        ab = 0.0
        for i in range(n):
            ab += a_dir[i] * dirs[j, i]
        for i in range(n):
            dirs[j, i] -= a_dir[i] * (ab / aa)
        num, den = 0.0, 0.0
        for i in range(cols):
            num += dirs[j, i] * qd[i]
            den += dirs[j, i] * dirs[j, i]
        rate = num / den
        if sl.balance_filter > 0.0:  # from rest: one period's rate is mostly noise on estimates
            prev = s.rate[j] if s.rate_on[0] else 0.0
            rate = prev + min(1.0, dt / sl.balance_filter) * (rate - prev)
        s.rate[j] = rate
        corr[j] = sl.balance_gain * (mean - s.f_used[j]) - sl.balance_damping * rate
    s.rate_on[0] = True
    for j in range(nb):
        prev = keep * s.balance[j] if s.balance_on[0] else 0.0
        for i in range(n):
            lead.q_d[i] += dirs[j, i] * (corr[j] - prev)
        s.balance[j] = corr[j]
    s.balance_on[0] = True


class ArmsTouchServo(ArmsServo):
    """The squeeze of the module docstring over ``arms``, one
    :class:`~.touch.TouchServo` per arm (each with its rod), sharing ``touch``
    (:class:`~.config.TouchConfig`). Its period is the compiled :func:`squeeze_perceive` and
    :func:`squeeze_command` over the arms' stacked records and the squeeze's
    (:attr:`law`, :attr:`squeeze`, :attr:`refs`, :attr:`squeeze_state`), the steps the
    batched engine calls for every world."""

    def __init__(self, arms, touch):
        super().__init__(arms)
        self.touch = touch
        self.law = TouchLaw.from_config(touch)
        self.squeeze = SqueezeLaw.from_config(touch)
        self.refs = stack([a.refs for a in self.arms])
        k = len(self.arms)
        self.squeeze_state = SqueezeState.initial(k)
        self.squeeze_out = SqueezeOut.empty(k)
        self._view_memo = None  # period_views' (view, estimate, q) this period

    def reset(self, q0, first_view=None) -> None:
        super().reset(q0, first_view)
        squeeze_reset(self.squeeze_state)
        self._view_memo = None

    @property
    def phases(self) -> list[str]:
        """Each arm's phase."""
        return [PHASES[int(p)] for p in self.squeeze_state.phase]

    @property
    def phase(self) -> str:
        """The run's phase: the least advanced arm's."""
        return PHASES[int(_run_phase(self.squeeze_state))]

    @property
    def landings(self) -> int:
        """The squeeze's landings so far (every arm touched once each)."""
        return int(self.squeeze_state.landings[0])

    def desired_force(self, t: float) -> float:
        """The mean loop's desired force at ``t`` (:func:`desired_force`)."""
        return float(desired_force(self.law, self.squeeze, self.squeeze_state, float(t)))

    def period_views(self, t: float, dt: float, view, est, force=None):
        """The first part of the period: every arm's (:meth:`~.arms.ArmsServo.perceive_arms`),
        then :func:`squeeze_perceive` (the phases' changes, each arm's view and twist), once:
        asked again with the same ``view`` and ``est`` (an env's observation, then the
        period's step), it returns the same outputs. Returns the arms' stacked
        :class:`~.servo.ServoOut` (what an env observes)."""
        memo = self._view_memo
        if memo is not None and memo[0] is view and memo[1] is est:
            return self._outs
        k = len(self.arms)
        q = self.perceive_arms(t, dt, view, est)
        found = np.array([arm._frame[2] for arm in self.arms], np.bool_)
        xy = np.ascontiguousarray([arm._frame[4] for arm in self.arms], dtype=float)
        readings = getattr(force, "arms", ()) or (None,) * k
        f_hat = np.array([r.force if r is not None and r.valid else math.nan for r in readings])
        squeeze_perceive(self.law, self.squeeze, self.refs, self.squeeze_state, self.params,
                         self.state, self.arms[0]._m, float(t), float(dt), q, found, xy, f_hat,
                         self._outs, self.squeeze_out)  # fmt: skip
        self._view_memo = (view, est, q)
        return self._outs

    def step(self, t: float, dt: float, view, gview, est, twist=None, force=None) -> ServoCommand:
        k = len(self.arms)
        m = self.arms[0]._m
        self.period_views(t, dt, view, est, force)
        q = self._view_memo[2]
        self._view_memo = None
        st, so = self.squeeze_state, self.squeeze_out
        qd = np.ascontiguousarray(est.qd, dtype=float)
        offered, g_found, corners, seen = self.global_arguments(gview)
        squeeze_command(self.law, self.squeeze, st, so, self.params, self.state, m, float(t),
                        float(dt), q, qd, offered, twist_arguments(twist, k), g_found, corners,
                        seen, self._outs, self.memo, self._robot)  # fmt: skip
        extra = {"phase": self.phase, "tare_force": bool(so.tare[0]),
                 "phase_changed": bool(so.phase_changed[0]), "landing": self.landings}  # fmt: skip
        if so.run_changed[0]:
            extra["event"] = f"touch: {self.phase}"
        return self.command_of_outputs(**extra)

    def arm_state(self, a: int, out) -> ArmTouchState:
        base = super().arm_state(a, out)
        st = self.squeeze_state
        values = {f.name: getattr(base, f.name) for f in fields(base)}
        return ArmTouchState(**values, phase=PHASES[int(st.phase[a])], force=float(st.f_used[a]))

    def squeeze_direction(self, q) -> np.ndarray:
        """``(n,)``: :func:`squeeze_direction` at ``q`` with this period's interaction
        matrices."""
        out = np.empty(self.n)
        squeeze_direction(self.params, self.arms[0]._m, np.ascontiguousarray(q, dtype=float),
                          self.squeeze_out.weights, out)  # fmt: skip
        return out

    def balance_directions(self, q) -> np.ndarray:
        """``(k - 1, n)``: :func:`balance_directions` at ``q`` with this period's interaction
        matrices."""
        out = np.empty((len(self.arms) - 1, self.n))
        balance_directions(self.params, self.arms[0]._m, np.ascontiguousarray(q, dtype=float),
                           self.squeeze_out.weights, out)  # fmt: skip
        return out


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
    "SqueezeLaw",
    "SqueezeOut",
    "SqueezeState",
    "arm_contact_forces",
    "squeeze_command",
    "squeeze_perceive",
    "squeeze_reset",
    "squeeze_transitions",
]
