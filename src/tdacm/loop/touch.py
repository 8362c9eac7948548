"""Servoing into contact: a hybrid vision/force law on the estimated tip force.

Two blocks, used when ``[touch] enabled`` (:class:`~.config.TouchConfig`, docs/contact.md):

* :class:`TipForceBlock` estimates the normal force on the arm's contact sphere along the
  tip camera's optical axis every period, with no force sensor: the controller's model, the
  applied inputs and the state estimate on all rows (so the drone's balance sees a force
  along the rod's axis), tared when the servo asks for it (``ServoCommand.tare_force``, once
  hovering at the standoff, before touching); the residual of the model's balance from a
  generalized-momentum observer (``force_estimator = "momentum"``, no accelerations) or with
  accelerations from differenced velocities (``"differenced"``). Its step is the compiled
  :func:`~tdacm.estimation.contact_force.force_step` over the record
  :func:`~tdacm.estimation.contact_force.force_params` (the same least squares as
  :class:`~tdacm.estimation.contact_force.TipForceEstimator`, tested equal);
* :class:`TouchServo`, the robust servo (:class:`~.servo.RobustServo`) with four phases:

  1. ``approach``: IBVS (all six features) to the *standoff* view, the reference snapshot
     (the view at the contact pose) seen from ``standoff`` farther back along the camera
     axis: its points scaled by ``d / (d + standoff)`` (exact for a target facing the camera,
     ``d`` the reference depth); it ends once the RMSE to that view stays below
     ``start_rmse`` for ``dwell`` s (the force estimator is tared then);
  2. ``contact``: hybrid: the IBVS twist of C_V on the five features other than the
     perimeter ``p_z`` (the one that measures the distance), and the translation along the
     camera axis from the force loop: toward the surface at ``approach_gain`` times the
     distance left (read from ``p_z``), between ``touch_speed`` and ``approach_speed``,
     until the estimated force reaches ``detect_force`` (the first touch); from then on the
     probe counts as pinned (:func:`is_pinned`): the servo reads the task's view, the tip
     camera C_L against the reference snapshot in C_L, with the pinned law
     (:func:`pinned_error`: C_L's attitude features, the drone's lean), and the axis is the
     admittance law's (below); ``settle`` s after the touch the landing is checked
     (:func:`landing_kept`): a probe off the marker is lifted and lands again (with
     ``land_correction``, aimed off by the offset the lifted landings repeated,
     :func:`aim_shift`);
  3. ``hold``: the same, once the kept landing's force estimate has settled
     (:func:`force_settled`), for ``hold_time`` s;
  4. ``release``: IBVS of C_V back to the standoff view (the probe leaves the surface).

The hold is judged on the task: :func:`task_image_error`, the detected C_L points' normalized
RMSE to the reference snapshot in C_L (where the probe presses on the marker), not C_V's,
which moves with the drone's estimated tilt while the pinned camera does not
(docs/contact.md, "The hold judged on the task"). With ``touch.contact_view = "virtual"`` the
servo reads C_V throughout, as in free flight.

The admittance law sets the reference ``q_d`` along the camera axis (the joint displacement
of a unit translation of C_V along its z axis) at the offset
``force_gain e + force_integral int e dt`` from the estimated pose, ``e = F_d - F_hat`` (the
estimate low-pass filtered, ``force_filter``). The low-level controller turns that offset into
a force (its proportional term) and slowly absorbs the force into its estimate of the
unmodelled load (``Delta_hat``, an integral): the integral term of the law takes the offset
back as it does, so the force stays at ``F_d`` (measured in docs/contact.md).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numba import njit

from ..estimation.contact_force import (
    DIFFERENCED,
    MOMENTUM,
    ForceOut,
    ForceParams,
    ForceState,
    force_params,
    force_reset,
    force_step,
    force_tare,
)
from ..vision.features import min_edge2, min_edge2_of
from ..vision.ibvs import IBVSController, ibvs_law, ibvs_twist_of
from ..vision.mounts import tip_camera_pose_into
from ..vision.target_filter import points_in_kernel
from .config import TouchConfig
from .data import PHASES, ForceReading, LocalView, StateEstimate
from .servo import (
    PredictedView,
    RobustServo,
    ServoOut,
    joint_rates,
    normalized_rmse,
    rmse_to,
    servo_command,
    twist_argument,
)

APPROACH, CONTACT, HOLD, RELEASE = PHASES
#: the phases' codes in the compiled step (their index in PHASES)
APPROACH_CODE, CONTACT_CODE, HOLD_CODE, RELEASE_CODE = range(len(PHASES))


class TipForceBlock:
    """Estimated normal force on the probe along the tip camera's axis (module docstring), on
    every arm's probe with several (:class:`~tdacm.loop.touch_arms.ArmsForceBlock`): the
    record :func:`~tdacm.estimation.contact_force.force_params` validated once and the
    compiled :func:`~tdacm.estimation.contact_force.force_step` each period (the engine calls
    the same step).

    ``model``: the controller's :class:`~tdacm.control.EstimatedModel`; ``tip_mount``:
    ``g_{C_L}^L`` (several: one per arm); ``offset``: the contact sphere's centre in the tip
    frame; ``kind``: ``"momentum"`` (the generalized force from a momentum observer of gain
    ``gain``, no accelerations) or ``"differenced"`` (the model's balance with ``qdd`` the
    finite difference of ``qd_hat``)."""

    def __init__(self, model, tip_mount, offset, input_sigma: float, kind: str, gain: float):
        self.kind = kind
        self.model = model
        self._args = (tip_mount, offset, input_sigma, kind, gain)
        self.params = force_params(model, *self._args)
        self._revision = model.revision
        s = model.system
        self.state = ForceState.initial(s.n, s.n_u)
        self.out = ForceOut.empty(self.params.rods.shape[0])
        self._no_cov = np.zeros((0, 0))
        self._no_u = np.zeros(s.n_u)

    @property
    def arms(self) -> int:
        return self.params.rods.shape[0]

    def record(self, model=None) -> ForceParams:
        """The record of this block's estimate on ``model`` (default: its own) as now drawn
        (the engine's per-world records: each seed's model error)."""
        return force_params(self.model if model is None else model, *self._args)

    def reset(self) -> None:
        force_reset(self.state)

    def compute(self, est: StateEstimate, u_applied, dt: float) -> bool:
        """One period of :func:`~tdacm.estimation.contact_force.force_step` into
        :attr:`out`; whether the estimate is valid."""
        if self._revision != self.model.revision:  # the model was drawn again
            self.params = force_params(self.model, *self._args)
            self._revision = self.model.revision
        k = self.params.gain * dt
        if self.params.kind == MOMENTUM and not 0.0 < k < 2.0:
            raise ValueError(f"observer gain x period must be in (0, 2), got {k!r}")
        c = np.ascontiguousarray
        has_u = u_applied is not None
        u = c(u_applied, dtype=float) if has_u else self._no_u
        cov = self._no_cov
        if self.params.kind == DIFFERENCED and est.P is not None:
            cov = c(est.P, dtype=float)
        force_step(self.params, self.state, self.model.system.model_arrays,
                   c(est.q, dtype=float), c(est.qd, dtype=float), u, has_u, cov, float(dt),
                   self.out)  # fmt: skip
        return bool(self.out.valid[0])

    def step(self, est: StateEstimate, u_applied, dt: float) -> ForceReading:
        if not self.compute(est, u_applied, dt):
            return ForceReading(est.t)
        o = self.out
        return ForceReading(est.t, float(o.force[0]), float(o.sigma[0]), o.normals[0].copy(), True)

    def tare(self) -> None:
        """Take the last period's residual as the model's bias (contact-free: before touching)."""
        force_tare(self.state)


class TouchLaw(NamedTuple):
    """The law's settings (the ``[touch]`` keys it reads, :class:`~.config.TouchConfig`) as a
    record for the compiled steps; ``contact_local``: ``contact_view == "local"``."""

    force: float
    detect_force: float
    force_filter: float
    start_rmse: float
    dwell: float
    settle: float
    settle_wait: float
    settle_band: float
    hold_time: float
    land_rmse: float
    land_filter: float
    max_landings: int
    lift_time: float
    approach_speed: float
    touch_speed: float
    approach_gain: float
    force_gain: float
    force_integral: float
    land_correction: bool
    contact_local: bool

    @classmethod
    def from_config(cls, tc: TouchConfig) -> TouchLaw:
        names = [f for f in cls._fields if f != "contact_local"]
        values = {f: type(getattr(TouchConfig(), f))(getattr(tc, f)) for f in names}
        return cls(**values, contact_local=tc.contact_view == "local")


@njit(cache=True)
def low_pass_step(prev, x, dt, tau):
    """One step of a first-order low-pass filter of time constant ``tau`` (s) over ``dt``:
    ``prev + min(1, dt / tau) (x - prev)``; ``x`` itself when there is no ``prev`` (NaN) or
    ``tau`` is zero."""
    if not np.isfinite(prev) or tau <= 0.0:
        return x
    return prev + min(1.0, dt / tau) * (x - prev)


def low_pass(prev: float | None, x: float, dt: float, tau: float) -> float:
    """:func:`low_pass_step` with ``None`` for no ``prev``."""
    return low_pass_step(math.nan if prev is None else float(prev), float(x), dt, tau)


@njit(cache=True)
def approach_speed(depth, e_pz, p_z, tl):
    """The axial speed toward the surface before the touch (m/s): ``approach_gain`` times the
    distance left to the contact pose, read from the perimeter feature (``p_z ~ 1 / depth``:
    the distance left is ``depth * max(0, -e_pz) / p_z``, ``e_pz`` its error to the reference),
    between ``touch_speed`` and ``approach_speed`` (slow over the last centimetres: a softer
    impact); ``tl``: the :class:`TouchLaw`."""
    dist = depth * max(0.0, -e_pz) / p_z
    return min(tl.approach_speed, max(tl.touch_speed, tl.approach_gain * dist))


@njit(cache=True)
def release_twist(twist, tl):
    """The release's twist: the IBVS twist back to the standoff view with its axial part
    moving away from the surface at most at ``approach_speed`` (the probe leaves as it came;
    pulled back at the IBVS rate, 0.1 m/s at the first period, the EKF, whose model does not
    carry the contact force that just vanished, drifted and gated the tip camera's views out:
    docs/contact.md)."""
    v = twist.copy()
    v[5] = max(v[5], -tl.approach_speed)
    return v


def aim_shift(samples) -> np.ndarray:
    """The shift ``(2,)`` of the moving-in aim (normalized image coordinates, subtracted from
    the C_V reference's points) from the landings lifted so far: ``k / (k + 1)`` times the
    mean of ``samples``, each landing's measured C_L centroid offset plus the shift it was
    aimed with (the offset it would have had without a shift), ``k`` of them
    (:func:`aim_from`). What a run repeats from landing to landing (the drone's trim tilt and
    the model's bias, 1-2 mm at the probe's end) is removed, and the landings' scatter, of
    about the same size, is not followed: ``k / (k + 1)`` is the weight of the mean in the
    estimate of a bias whose spread is taken equal to the scatter (docs/contact.md, "Landing
    on the marker"); zero before any landing."""
    x = np.asarray(samples, float).reshape(-1, 2)
    return aim_from(x.sum(axis=0) if len(x) else np.zeros(2), len(x))


@njit(cache=True)
def aim_from(total, k):
    """:func:`aim_shift` from the sum ``total`` (2,) of ``k`` samples."""
    out = np.zeros(2)
    if k > 0:
        for i in range(2):
            out[i] = k / (k + 1.0) * (total[i] / k)
    return out


@njit(cache=True)
def landing_kept_step(task_error, landings, tl):
    """:func:`landing_kept` with NaN for no detection."""
    if landings >= tl.max_landings:
        return True
    return np.isfinite(task_error) and task_error <= tl.land_rmse


def landing_kept(task_error: float | None, landings: int, tl: TouchLaw) -> bool:
    """Whether the probe's landing is held (the hold starts) or lifted to land again, when the
    hold would start (``settle`` s after the touch): kept if the filtered task image error
    (:func:`task_image_error` of the detected C_L points, ``None`` without a detection) is at
    most ``land_rmse``, or if this was the ``max_landings``-th landing."""
    e = math.nan if task_error is None else float(task_error)
    return bool(landing_kept_step(e, int(landings), tl))


@njit(cache=True)
def force_settled(f, since, tl):
    """Whether the hold may start ``since`` s after the touch of a kept landing (at least
    ``settle``): the filtered force estimate ``f`` within ``settle_band`` of ``force``
    (relative), or ``settle_wait`` s past ``settle`` whatever it reads. The impact leaves the
    force 20-70 % above ``force`` at ``settle``, coming down over the next 1-2 s (more after a
    landing lifted and made again: the controller's absorbed load is still pushing); a hold
    started on it carried that decay into its RMS error (docs/contact.md, "Landing on the
    marker")."""
    if since >= tl.settle + tl.settle_wait - 1e-9:
        return True
    return abs(f - tl.force) <= tl.settle_band * tl.force


@njit(cache=True)
def force_offset(integral, err, dt, tl):
    """The admittance's PI offset of the reference along the camera axis (m) for the force
    error ``err = F_d - F_hat`` (N): ``(force_gain err + integral', integral')`` with
    ``integral' = integral + force_integral err dt`` (module docstring)."""
    integral = integral + tl.force_integral * err * dt
    return tl.force_gain * err + integral, integral


def task_image_error(points, reference) -> float:
    """The hold's image error, the task's: the normalized RMSE of the target's four points in
    the tip camera C_L (``points``, normalized coordinates) to the reference snapshot in C_L
    (``reference``: the view at ``[desired] q``), ``sqrt(mean_k |p_k - p_k*|^2)``; NaN without
    points (docs/contact.md, "The hold judged on the task")."""
    return normalized_rmse(points, reference)


def is_pinned(phase: str, touched: bool, contact_view: str) -> bool:
    """Whether the probe counts as pinned, the servo on the task's view C_L
    (:func:`pinned_error`): pressing (``phase`` contact or hold) after the first touch
    (``touched``: the estimated force reached ``detect_force``), with ``touch.contact_view``
    ``"local"``. Out of it (approach, moving in, release, or ``"virtual"``): C_V."""
    return touched and phase in (CONTACT, HOLD) and contact_view == "local"


@njit(cache=True)
def pinned_error_into(task_error, virtual_error, has_virtual, e):
    """:func:`pinned_error` into ``e`` (6,)."""
    for i in range(6):
        e[i] = 0.0
    for i in range(3):
        e[i] = task_error[i]
    if has_virtual:
        for i in range(3, 5):
            e[i] = virtual_error[i] - task_error[i]


def pinned_error(task_error, virtual_error) -> np.ndarray:
    """The servo's feature error ``(6,)`` while the probe is pinned on the surface
    (docs/contact.md, "The pinned law"), from C_L's error to its reference (``task_error``)
    and C_V's (``virtual_error``; ``None``: not available):

    * ``p_phi, p_theta, p_psi``: C_L's, the probe's attitude about the contact point (what the
      pinned arm can change);
    * ``p_x, p_y``: the lean, C_V's centroid error minus C_L's, the image of the drone's
      estimated tilt about the pinned point (C_L's own centroid error is where the probe
      landed, which no motion of a pinned arm changes; held at zero, the lean keeps the drone
      level, i.e. no lateral load on the probe); zero without ``virtual_error``;
    * ``p_z``: zero, the force loop's."""
    e = np.zeros(6)
    has = virtual_error is not None
    v = np.asarray(virtual_error, float) if has else e
    pinned_error_into(np.asarray(task_error, float), v, has, e)
    return e


# ------------------------------------------------------------------ the compiled step
#: a unit translation along the servo camera's z (the axis)
_AXIAL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


class TouchRefs(NamedTuple):
    """The views of the touch law (the record beside :class:`TouchLaw`): the standoff view
    ``standoff_points`` (4, 2) with its ``standoff_features`` (6,) and ``standoff_interaction``
    (6, 6) (at the reference's depths plus ``standoff``), the reference snapshot in C_L
    ``local_points``, ``local_features``, ``local_interaction``, and the reference's mean
    depth ``depth`` (m)."""

    standoff_points: np.ndarray
    standoff_features: np.ndarray
    standoff_interaction: np.ndarray
    local_points: np.ndarray
    local_features: np.ndarray
    local_interaction: np.ndarray
    depth: float


class TouchState(NamedTuple):
    """The law's state (one-element arrays; NaN: not set): the ``phase`` (an index of
    :data:`~.data.PHASES`), since when the standoff view has been held (``below_since``), the
    touch of this landing (``touch_t``), the hold's end (``hold_end``), the filtered force
    estimate ``f``, the admittance's ``integral``, whether the servo reads the pinned view
    (``pinned``), the ``landings`` so far, a lift under way (``lifting``, until
    ``lift_end``), the filtered task image error ``task_err`` and C_L centroid offset
    ``cent_err`` (2,), whether this landing passed its check (``kept``), the lifted landings'
    summed offsets ``aim_total`` (2,) and count ``aim_count``, the moving-in aim's shift
    ``aim`` (2,), and the force used this period ``f_used`` (zero at the tare)."""

    phase: np.ndarray
    below_since: np.ndarray
    touch_t: np.ndarray
    hold_end: np.ndarray
    f: np.ndarray
    integral: np.ndarray
    pinned: np.ndarray
    landings: np.ndarray
    lifting: np.ndarray
    lift_end: np.ndarray
    task_err: np.ndarray
    cent_err: np.ndarray
    kept: np.ndarray
    aim_total: np.ndarray
    aim_count: np.ndarray
    aim: np.ndarray
    f_used: np.ndarray

    @classmethod
    def initial(cls) -> TouchState:
        nan1 = lambda: np.full(1, np.nan)  # noqa: E731
        i1 = lambda: np.zeros(1, np.int64)  # noqa: E731
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        return cls(i1(), nan1(), nan1(), nan1(), nan1(), np.zeros(1), b1(), i1(), b1(), nan1(),
                   nan1(), np.full(2, np.nan), b1(), np.zeros(2), i1(), np.zeros(2),
                   np.zeros(1))  # fmt: skip


class TouchOut(NamedTuple):
    """What the law did in a period (written by :func:`touch_perceive`): the force estimator
    is to be tared (``tare``), the phase changed (``phase_changed``), the servo's view
    switched (``switched``: into or out of the pinned view), and the C_V view predicted this
    period (``ps_valid``, ``ps_points`` (4, 2), ``ps_depths`` (4,), ``ps_features``,
    ``ps_error`` (6,)), which the pinned view replaces in the servo's outputs."""

    tare: np.ndarray
    phase_changed: np.ndarray
    switched: np.ndarray
    ps_valid: np.ndarray
    ps_points: np.ndarray
    ps_depths: np.ndarray
    ps_features: np.ndarray
    ps_error: np.ndarray

    @classmethod
    def empty(cls) -> TouchOut:
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        return cls(b1(), b1(), b1(), b1(), np.zeros((4, 2)), np.zeros(4), np.zeros(6),
                   np.zeros(6))  # fmt: skip


class TouchRecords(NamedTuple):
    """The touch servo's and force estimate's records of a batch's worlds (the engine's,
    stacked over the worlds): whether the worlds servo into contact with one arm (``on``) or
    squeeze with several (``squeeze_on``; neither: the records below are unused), the law
    (:class:`TouchLaw`), the views of one arm (:class:`TouchRefs`), the tip force estimate's
    record (:class:`~tdacm.estimation.contact_force.ForceParams`, every arm's), and the
    squeeze's law (:class:`~tdacm.loop.touch_arms.SqueezeLaw`) and every arm's views
    (``arm_refs``: :class:`TouchRefs` with an arm axis)."""

    on: bool
    law: object
    refs: object
    force: object
    squeeze_on: bool
    squeeze: object
    arm_refs: object


class TouchData(NamedTuple):
    """The touch servo's state in a batch's worlds (stacked): the law's
    (:class:`TouchState`) and what it did in the period (:class:`TouchOut`), the force
    estimate's state and reading (:class:`~tdacm.estimation.contact_force.ForceState`,
    ``ForceOut``), and the squeeze's (:class:`~tdacm.loop.touch_arms.SqueezeState`,
    ``SqueezeOut``)."""

    state: object
    out: object
    force: object
    force_out: object
    squeeze_state: object
    squeeze_out: object


@njit(cache=True)
def touch_reset(s):
    """The law's state as built: approaching, nothing measured, no landing."""
    s.phase[0] = APPROACH_CODE
    s.below_since[0] = np.nan
    s.touch_t[0] = np.nan
    s.hold_end[0] = np.nan
    s.f[0] = np.nan
    s.integral[0] = 0.0
    s.pinned[0] = False
    s.landings[0] = 0
    s.lifting[0] = False
    s.lift_end[0] = np.nan
    s.task_err[0] = np.nan
    s.cent_err[:] = np.nan
    s.kept[0] = False
    s.aim_total[:] = 0.0
    s.aim_count[0] = 0
    s.aim[:] = 0.0
    s.f_used[0] = 0.0


@njit(cache=True)
def _transition(tl, tr, s, t, valid, points, f):
    """This period's phase change (module docstring) from the C_V prediction ``points`` (the
    standoff view, approach only; ``valid``) and the filtered force ``f``; True when the force
    estimator is to be tared (moving in starts)."""
    phase = s.phase[0]
    if phase == APPROACH_CODE:
        if valid:
            if rmse_to(points, tr.standoff_points) <= tl.start_rmse:
                if not np.isfinite(s.below_since[0]):
                    s.below_since[0] = t
                if t - s.below_since[0] >= tl.dwell:
                    s.phase[0] = CONTACT_CODE
                    return True
            else:
                s.below_since[0] = np.nan
    elif phase == CONTACT_CODE:
        if s.lifting[0]:  # no touch counts until the probe has been off for lift_time
            if f >= 0.5 * tl.detect_force:
                s.lift_end[0] = np.nan  # still pressed (the estimate)
            elif not np.isfinite(s.lift_end[0]):
                s.lift_end[0] = t + tl.lift_time
            elif t >= s.lift_end[0] - 1e-9:
                s.lifting[0] = False
                s.lift_end[0] = np.nan
        elif not np.isfinite(s.touch_t[0]) and f >= tl.detect_force:
            s.touch_t[0] = t
            s.landings[0] += 1
            s.kept[0] = False
        if np.isfinite(s.touch_t[0]) and t - s.touch_t[0] >= tl.settle:
            if not s.kept[0]:  # the landing check, once per landing
                s.kept[0] = landing_kept_step(s.task_err[0], s.landings[0], tl)
            if s.kept[0]:
                if force_settled(f, t - s.touch_t[0], tl):
                    s.phase[0] = HOLD_CODE
                    s.hold_end[0] = t + tl.hold_time
            else:  # lift the probe and land again; the force loop starts over
                if tl.land_correction and np.isfinite(s.cent_err[0]):
                    for i in range(2):
                        s.aim_total[i] += s.cent_err[i] + s.aim[i]
                    s.aim_count[0] += 1
                    s.aim[:] = aim_from(s.aim_total, s.aim_count[0])
                s.cent_err[:] = np.nan
                s.touch_t[0] = np.nan
                s.lifting[0] = True
                s.integral[0] = 0.0
                s.task_err[0] = np.nan
    elif phase == HOLD_CODE and t >= s.hold_end[0] - 1e-9:
        s.phase[0] = RELEASE_CODE
    return False


@njit(cache=True)
def _local_view(sp, ss, m, q, tr, xy, z, f, e):
    """The target's points predicted in the tip camera C_L at the estimate ``q`` from the
    smoothed target estimate, into ``xy`` (4, 2), ``z`` (4,), with their features ``f`` and
    error ``e`` to the reference in C_L; False before the first frame or with a point behind
    the camera (or coincident corners)."""
    if ss.tp_set[0] == 0.0:
        return False
    g_c = np.empty((4, 4))
    tip_camera_pose_into(q, m, sp.rod, sp.mount, g_c)
    points_in_kernel(sp.filter.record.object_points, g_c, ss.target_pose, xy, z)
    for i in range(4):
        if not z[i] > 0.0:
            return False
    if min_edge2(xy) < 1e-24:
        return False
    ff, ee, _ = ibvs_law(xy, z, tr.local_features, tr.local_interaction, sp.interaction,
                         sp.gain, sp.floor, sp.damped)  # fmt: skip
    f[:] = ff
    e[:] = ee
    return True


@njit(cache=True)
def touch_perceive(tl, tr, ts, sp, ss, m, t, dt, q, found, xy, f_hat, out, tout):
    """The first part of a period of the touch servo (:class:`TouchServo`, module
    docstring), after the robust servo's (:func:`~.servo.servo_perceive` into ``out``, on
    the frame ``found`` with its normalized points ``xy``): the force estimate ``f_hat``
    (NaN: none) filtered, the landed probe's task error from the measured C_L points ``xy``,
    the phase change, and the view the servo reads (the pinned view in C_L once touched) with
    its twist into ``out.ibvs_twist`` (``out.seen``: a view to servo on), ``out.rmse`` the
    RMSE the safety monitor watches; what changed into ``tout``."""
    prev = ts.phase[0]
    valid = out.seen[0]
    tout.ps_valid[0] = valid
    tout.ps_points[:, :] = out.points
    tout.ps_depths[:] = out.depths
    tout.ps_features[:] = out.features
    tout.ps_error[:] = out.error
    # the force estimate, low-pass filtered (force_filter)
    if np.isfinite(f_hat):
        ts.f[0] = low_pass_step(ts.f[0], f_hat, dt, tl.force_filter)
    f = ts.f[0] if np.isfinite(ts.f[0]) else 0.0
    if np.isfinite(ts.touch_t[0]) and found:  # where the landed probe aims (pixels)
        err = rmse_to(xy, tr.local_points)
        ts.task_err[0] = low_pass_step(ts.task_err[0], err, dt, tl.land_filter)
        for i in range(2):
            c = 0.0
            for j in range(4):
                c += xy[j, i] - tr.local_points[j, i]
            ts.cent_err[i] = low_pass_step(ts.cent_err[i], c / 4.0, dt, tl.land_filter)
    tare = _transition(tl, tr, ts, t, valid, tout.ps_points, f)
    if tare:  # the force loop starts from the tared estimate
        ts.f[0] = np.nan
        f = 0.0
    ts.f_used[0] = f
    phase = ts.phase[0]
    pressing = phase == CONTACT_CODE or phase == HOLD_CODE
    touched = np.isfinite(ts.touch_t[0])
    pinned = touched and pressing and tl.contact_local
    tout.switched[0] = pinned != ts.pinned[0]  # the view changes: the safety monitor re-arms
    ts.pinned[0] = pinned
    tout.tare[0] = tare
    tout.phase_changed[0] = prev != phase
    v = np.zeros(6)
    if pinned:  # the servo's view is the task's: C_L against its reference
        lz = np.empty(4)
        lf, le = np.empty(6), np.empty(6)
        lv = _local_view(sp, ss, m, q, tr, out.points, lz, lf, le)
        valid = valid and lv
        out.depths[:] = lz
        out.features[:] = lf
        out.error[:] = le
        out.rmse[0] = rmse_to(out.points, tr.local_points) if valid else np.nan
        out.rmse_measured[0] = rmse_to(xy, tr.local_points) if found else np.nan
        if valid:  # the pinned law: C_L's attitude rows and the lean, the axis the force's
            e = np.empty(6)
            pinned_error_into(le, tout.ps_error, tout.ps_valid[0], e)
            v = ibvs_twist_of(out.points, lz, e, tr.local_interaction, sp.interaction, sp.gain,
                              sp.floor, sp.damped)  # fmt: skip
            v[5] = 0.0
    elif valid and pressing:
        e = tout.ps_error.copy()
        # aimed at the reference's points less the aim's shift: the centroid rows (p_x, p_y,
        # the points' mean) by the shift, the rest unchanged
        e[3] += ts.aim[0]
        e[4] += ts.aim[1]
        e[5] = 0.0  # p_z (the perimeter: the distance) is the force loop's
        v = ibvs_twist_of(tout.ps_points, tout.ps_depths, e, sp.desired_interaction,
                          sp.interaction, sp.gain, sp.floor, sp.damped)  # fmt: skip
        if ts.lifting[0]:
            v[5] = -tl.approach_speed  # lifting off the surface
        elif not touched:
            v[5] = approach_speed(tr.depth, tout.ps_error[5], tout.ps_features[5], tl)
        else:
            v[5] = 0.0  # the axial reference is the admittance's (touch_command)
    elif valid:
        _, _, v = ibvs_law(tout.ps_points, tout.ps_depths, tr.standoff_features,
                           tr.standoff_interaction, sp.interaction, sp.gain, sp.floor,
                           sp.damped)  # fmt: skip
        if phase == RELEASE_CODE:
            v = release_twist(v, tl)
    if (phase == APPROACH_CODE or phase == RELEASE_CODE) and valid:
        # the RMSE the safety monitor watches: to the view this phase servoes to
        out.rmse[0] = rmse_to(tout.ps_points, tr.standoff_points)
    out.seen[0] = valid
    out.ibvs_twist[:] = v


@njit(cache=True)
def touch_command(tl, ts, sp, ss, m, t, dt, q, offered, twist_in, g_found, corners,
                  marker_seen, out):  # fmt: skip
    """The end of a period of the touch servo: the servo's command on the law's twist
    (:func:`~.servo.servo_command`), then, pressing after the touch with a view, the
    admittance (module docstring): the reference along the camera axis at the PI offset of
    the force error from the estimated pose, the other directions as the IBVS integrated
    them."""
    servo_command(sp, ss, m, t, dt, q, offered, twist_in, g_found, corners, marker_seen, out)
    phase = ts.phase[0]
    pressing = phase == CONTACT_CODE or phase == HOLD_CODE
    if not (pressing and np.isfinite(ts.touch_t[0]) and out.seen[0]):
        return
    n = q.shape[0]
    a = np.empty(n)
    joint_rates(sp, m, q, _AXIAL, a)  # joint displacement per metre along the axis
    aa = 0.0
    for i in range(n):
        aa += a[i] * a[i]
    if aa <= 0.0:
        return
    offset, ts.integral[0] = force_offset(ts.integral[0], tl.force - ts.f_used[0], dt, tl)
    now = 0.0
    along = 0.0
    for i in range(n):
        now += a[i] * (ss.q_d[i] - q[i])
        along += a[i] * ss.qd_d[i]
    now /= aa
    along /= aa
    for i in range(n):
        ss.q_d[i] += a[i] * (offset - now)
        ss.qd_d[i] -= a[i] * along


def touch_views(ibvs: IBVSController, reference, local_reference, standoff: float):
    """The touch law's views of a servo whose IBVS law is ``ibvs``, from its reference
    snapshot ``reference`` (``(points, depths)`` in the servo camera) and the one in C_L
    ``local_reference``: the IBVS laws to the standoff view (the reference's points scaled by
    ``d / (d + standoff)``, ``d`` their mean depth: exact for a target facing the camera) and
    to the C_L reference, and their :class:`TouchRefs`."""
    points, depths = np.asarray(reference[0], float), np.asarray(reference[1], float)
    d = float(np.mean(depths))
    law = {"gain": ibvs.gain, "mode": ibvs.mode, "floor": ibvs.floor, "solver": ibvs.solver}
    standoff_ibvs = IBVSController(points * (d / (d + standoff)), depths + standoff, **law)
    local_ibvs = IBVSController(np.asarray(local_reference[0], float),
                                np.asarray(local_reference[1], float), **law)  # fmt: skip
    c = np.ascontiguousarray
    refs = TouchRefs(
        c(standoff_ibvs.desired_points), c(standoff_ibvs.desired),
        c(standoff_ibvs.interaction_desired), c(local_ibvs.desired_points),
        c(local_ibvs.desired), c(local_ibvs.interaction_desired), d,
    )  # fmt: skip
    return standoff_ibvs, local_ibvs, refs


class TouchServo(RobustServo):
    """The robust servo with the phases of the module docstring; ``touch``: the
    :class:`~.config.TouchConfig`; ``local_reference``: ``(points, depths)``, the reference
    snapshot in C_L (the view at ``[desired] q`` in the tip camera itself; default: the
    reference given for C_V, the same view when ``[desired] q`` is level), the servo's
    reference once the probe is pinned with ``touch.contact_view = "local"``.

    Its period is the compiled :func:`touch_perceive` and :func:`touch_command` over the
    servo's records and the law's (:attr:`law`, :attr:`refs`, :attr:`touch_state`). The
    squeeze (:class:`~tdacm.loop.touch_arms.ArmsTouchServo`) runs one per arm for its records
    and its first part (:meth:`perceive_period`), its own law over them."""

    def __init__(self, *args, touch: TouchConfig | None = None, local_reference=None, **kwargs):
        self.touch = touch or TouchConfig(enabled=True)  # before the base's reset
        self.touch_state = TouchState.initial()
        super().__init__(*args, **kwargs)
        tc = self.touch
        if local_reference is None:
            local_reference = (self.desired_points, self.desired_depths)
        self.standoff_ibvs, self.local_ibvs, self.refs = touch_views(
            self.ibvs, (self.desired_points, self.desired_depths), local_reference, tc.standoff
        )
        self._depth = self.refs.depth
        self.standoff_points = self.standoff_ibvs.desired_points
        self.local_points = self.local_ibvs.desired_points
        self.local_depths = np.asarray(local_reference[1], float)
        self.law = TouchLaw.from_config(tc)
        self._touch_out = TouchOut.empty()
        self._compiled = True  # the period is touch_perceive and touch_command
        self._touch_memo = None  # period_view's (view, estimate) this period
        touch_reset(self.touch_state)

    @property
    def phase(self) -> str:
        return PHASES[int(self.touch_state.phase[0])]

    @phase.setter
    def phase(self, value: str) -> None:
        self.touch_state.phase[0] = PHASES.index(value)

    @property
    def touched(self) -> bool:
        """The probe has touched in this landing (the force estimate reached
        ``detect_force``)."""
        return bool(np.isfinite(self.touch_state.touch_t[0]))

    @property
    def target_pose(self):
        """The smoothed target estimate (4, 4) the views are predicted from; None before the
        first frame."""
        if getattr(self, "_compiled", False):
            st = self.state
            return st.target_pose.copy() if st.tp_set[0] else None
        return self._target_pose

    @target_pose.setter
    def target_pose(self, value) -> None:  # the robust servo's set-up
        self._target_pose = value

    @property
    def landings(self) -> int:
        """Landings so far."""
        return int(self.touch_state.landings[0])

    @property
    def lifting(self) -> bool:
        """Lifting the probe off the surface to land again."""
        return bool(self.touch_state.lifting[0])

    @property
    def aim(self) -> np.ndarray:
        """The moving-in aim's shift (:func:`aim_shift`)."""
        return self.touch_state.aim.copy()

    def reset(self, q0, first_view: LocalView | None = None) -> None:
        super().reset(q0, first_view)
        touch_reset(self.touch_state)
        self._touch_memo = None

    def local_view(self, q) -> PredictedView:
        """The target's points predicted in the tip camera C_L at the estimated pose ``q``
        (from the same smoothed target estimate as the C_V prediction), with their features,
        error and twist against the reference in C_L (:attr:`local_ibvs`); invalid before the
        first frame or with a point behind the camera."""
        if self.target_pose is None:
            return PredictedView()
        xy, z = self.target_filter.points_in(self.local_camera_pose(q), self.target_pose)
        if np.any(z <= 0) or min_edge2_of(xy) < 1e-24:
            return PredictedView()
        f, e, v = self.local_ibvs.features_error_twist(xy, z)
        return PredictedView(xy, z, f, e, v)

    def predicted(self) -> PredictedView:
        """The C_V view predicted in the last period (before the pinned view replaced it)."""
        o = self._touch_out
        if not o.ps_valid[0]:
            return PredictedView()
        return PredictedView(o.ps_points.copy(), o.ps_depths.copy(), o.ps_features.copy(),
                             o.ps_error.copy(), None)  # fmt: skip

    def period_view(self, t, dt, view, est, force: ForceReading | None = None) -> ServoOut:
        """The first part of the period: the robust servo's (:meth:`perceive_period`), then
        :func:`touch_perceive` (the phases' changes, and the pinned C_L view in place of C_V's
        prediction once the probe is pinned), once: asked again with the same ``view`` and
        ``est`` (an env's observation, then the period's step), it returns the same
        outputs."""
        memo = self._touch_memo
        if memo is not None and memo[0] is view and memo[1] is est:
            return self._out
        p, st, ts, tout = self.params, self.state, self.touch_state, self._touch_out
        f_hat = force.force if force is not None and force.valid else math.nan
        out = self.perceive_period(t, dt, view, est)  # the servo's first part, once a period
        self._memo = None
        q, _, found, _, xy, _, _ = self._frame
        touch_perceive(self.law, self.refs, ts, p, st, self._m, float(t), float(dt), q, found,
                       xy, float(f_hat), out, tout)  # fmt: skip
        self._touch_memo = (view, est)
        return out

    def step(self, t, dt, view, gview, est, twist=None, force: ForceReading | None = None):
        p, st, ts, tout = self.params, self.state, self.touch_state, self._touch_out
        out = self.period_view(t, dt, view, est, force)
        self._touch_memo = None
        q = self._frame[0]
        offered, g_found, corners, seen = self.global_arguments(gview, out)
        tw = twist_argument(twist)
        touch_command(self.law, ts, p, st, self._m, float(t), float(dt), q, offered, tw,
                      g_found, corners, seen, out)  # fmt: skip
        cmd = self._command_of(out)
        event = f"touch: {self.phase}" if tout.phase_changed[0] else cmd.event
        changed = bool(tout.phase_changed[0] or tout.switched[0])  # the monitor re-arms
        return replace(cmd, event=event, phase=self.phase, tare_force=bool(tout.tare[0]),
                       phase_changed=changed, landing=self.landings)  # fmt: skip
