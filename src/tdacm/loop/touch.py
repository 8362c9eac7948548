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

from dataclasses import replace

import numpy as np

from ..estimation.contact_force import (
    DIFFERENCED,
    MOMENTUM,
    ForceOut,
    ForceState,
    force_params,
    force_reset,
    force_step,
    force_tare,
)
from ..vision.features import min_edge2_of
from ..vision.ibvs import IBVSController
from .config import TouchConfig
from .data import PHASES, ForceReading, LocalView, StateEstimate
from .servo import PredictedView, RobustServo, normalized_rmse

APPROACH, CONTACT, HOLD, RELEASE = PHASES


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


def low_pass(prev: float | None, x: float, dt: float, tau: float) -> float:
    """One step of a first-order low-pass filter of time constant ``tau`` (s) over ``dt``:
    ``prev + min(1, dt / tau) (x - prev)``; ``x`` itself when there is no ``prev`` or ``tau``
    is zero."""
    if prev is None or tau <= 0.0:
        return x
    return prev + min(1.0, dt / tau) * (x - prev)


def approach_speed(depth: float, e_pz: float, p_z: float, tc: TouchConfig) -> float:
    """The axial speed toward the surface before the touch (m/s): ``approach_gain`` times the
    distance left to the contact pose, read from the perimeter feature (``p_z ~ 1 / depth``:
    the distance left is ``depth * max(0, -e_pz) / p_z``, ``e_pz`` its error to the reference),
    between ``touch_speed`` and ``approach_speed`` (slow over the last centimetres: a softer
    impact)."""
    dist = depth * max(0.0, -e_pz) / p_z
    return min(tc.approach_speed, max(tc.touch_speed, tc.approach_gain * dist))


def release_twist(twist, tc: TouchConfig) -> np.ndarray:
    """The release's twist: the IBVS twist back to the standoff view with its axial part
    moving away from the surface at most at ``approach_speed`` (the probe leaves as it came;
    pulled back at the IBVS rate, 0.1 m/s at the first period, the EKF, whose model does not
    carry the contact force that just vanished, drifted and gated the tip camera's views out:
    docs/contact.md)."""
    v = np.array(twist, float)
    v[5] = max(v[5], -tc.approach_speed)
    return v


def aim_shift(samples) -> np.ndarray:
    """The shift ``(2,)`` of the moving-in aim (normalized image coordinates, subtracted from
    the C_V reference's points) from the landings lifted so far: ``k / (k + 1)`` times the
    mean of ``samples``, each landing's measured C_L centroid offset plus the shift it was
    aimed with (the offset it would have had without a shift), ``k`` of them. What a run
    repeats from landing to landing (the drone's trim tilt and the model's bias, 1-2 mm at the
    probe's end) is removed, and the landings' scatter, of about the same size, is not
    followed: ``k / (k + 1)`` is the weight of the mean in the estimate of a bias whose spread
    is taken equal to the scatter (docs/contact.md, "Landing on the marker"); zero before any
    landing."""
    if not samples:
        return np.zeros(2)
    k = len(samples)
    return k / (k + 1.0) * np.mean(np.asarray(samples, float), axis=0)


def landing_kept(task_error: float | None, landings: int, tc: TouchConfig) -> bool:
    """Whether the probe's landing is held (the hold starts) or lifted to land again, when the
    hold would start (``settle`` s after the touch): kept if the filtered task image error
    (:func:`task_image_error` of the detected C_L points, ``None`` without a detection) is at
    most ``land_rmse``, or if this was the ``max_landings``-th landing."""
    if landings >= tc.max_landings:
        return True
    return task_error is not None and task_error <= tc.land_rmse


def force_settled(f: float, since: float, tc: TouchConfig) -> bool:
    """Whether the hold may start ``since`` s after the touch of a kept landing (at least
    ``settle``): the filtered force estimate ``f`` within ``settle_band`` of ``force``
    (relative), or ``settle_wait`` s past ``settle`` whatever it reads. The impact leaves the
    force 20-70 % above ``force`` at ``settle``, coming down over the next 1-2 s (more after a
    landing lifted and made again: the controller's absorbed load is still pushing); a hold
    started on it carried that decay into its RMS error (docs/contact.md, "Landing on the
    marker")."""
    if since >= tc.settle + tc.settle_wait - 1e-9:
        return True
    return abs(f - tc.force) <= tc.settle_band * tc.force


def force_offset(integral: float, err: float, dt: float, tc: TouchConfig) -> tuple[float, float]:
    """The admittance's PI offset of the reference along the camera axis (m) for the force
    error ``err = F_d - F_hat`` (N): ``(force_gain err + integral', integral')`` with
    ``integral' = integral + force_integral err dt`` (module docstring)."""
    integral = integral + tc.force_integral * err * dt
    return tc.force_gain * err + integral, integral


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
    e[0:3] = task_error[0:3]
    if virtual_error is not None:
        e[3:5] = virtual_error[3:5] - task_error[3:5]
    return e


class TouchServo(RobustServo):
    """The robust servo with the phases of the module docstring; ``touch``: the
    :class:`~.config.TouchConfig`; ``local_reference``: ``(points, depths)``, the reference
    snapshot in C_L (the view at ``[desired] q`` in the tip camera itself; default: the
    reference given for C_V, the same view when ``[desired] q`` is level), the servo's
    reference once the probe is pinned with ``touch.contact_view = "local"``."""

    def __init__(self, *args, touch: TouchConfig | None = None, local_reference=None, **kwargs):
        self.touch = touch or TouchConfig(enabled=True)  # before the base's reset
        super().__init__(*args, **kwargs)
        tc = self.touch
        d = float(np.mean(self.desired_depths))
        self._depth = d
        k = d / (d + tc.standoff)
        self.standoff_points = self.desired_points * k
        law = {"gain": self.ibvs.gain, "mode": self.ibvs.mode, "floor": self.ibvs.floor,
               "solver": self.ibvs.solver}  # fmt: skip
        self.standoff_ibvs = IBVSController(
            self.standoff_points, self.desired_depths + tc.standoff, **law
        )
        if local_reference is None:
            local_reference = (self.desired_points, self.desired_depths)
        self.local_points = np.asarray(local_reference[0], float)
        self.local_depths = np.asarray(local_reference[1], float)
        self.local_ibvs = IBVSController(self.local_points, self.local_depths, **law)
        self._reset_phase()

    def _reset_phase(self) -> None:
        self.phase = APPROACH
        self._below_since = None
        self._touch_t = None
        self._hold_end = None
        self._f = None
        self._integral = 0.0
        self._pinned = False
        self._landings = 0  # landings so far
        self._lifting = False  # lifting the probe off the surface to land again
        self._lift_end = None  # ... until then (set once the force estimate has dropped)
        self._task_err = None  # the measured task image error, filtered (land_filter)
        self._kept = False  # this landing passed the landing check
        self._cent_err = None  # the detected C_L centroid's offset, filtered (land_filter)
        self._aim_samples = []  # each lifted landing's offset as aimed without a shift
        self._aim = np.zeros(2)  # the moving-in aim's shift (aim_shift)

    def reset(self, q0, first_view: LocalView | None = None) -> None:
        super().reset(q0, first_view)
        self._reset_phase()

    def predicted_view(self, servo_pose, camera_pose=None):
        ps = super().predicted_view(servo_pose, camera_pose)
        self._ps = ps
        return ps

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

    def pinned_twist(self, lv: PredictedView, ps: PredictedView | None) -> np.ndarray:
        """The pinned law's C_L twist: :func:`pinned_error` of C_L's prediction ``lv`` and
        C_V's ``ps`` through C_L's interaction matrix, without the axial translation (the
        admittance sets it)."""
        virtual = ps.error if ps is not None and ps.valid else None
        e = pinned_error(lv.error, virtual)
        v = self.local_ibvs.twist(lv.points, lv.depths, error=e)
        v[5] = 0.0
        return v

    def _transition(self, t: float, ps, f: float) -> bool:
        """This period's phase change (module docstring) from the C_V prediction ``ps`` (the
        standoff view, approach only; ``None`` if invalid) and the filtered force ``f``;
        True when the force estimator is to be tared (moving in starts)."""
        tc = self.touch
        if self.phase == APPROACH and ps is not None:
            if normalized_rmse(ps.points, self.standoff_points) <= tc.start_rmse:
                self._below_since = t if self._below_since is None else self._below_since
                if t - self._below_since >= tc.dwell:
                    self.phase = CONTACT
                    return True
            else:
                self._below_since = None
        elif self.phase == CONTACT:
            if self._lifting:  # no touch counts until the probe has been off for lift_time
                if f >= 0.5 * tc.detect_force:
                    self._lift_end = None  # still pressed (the estimate)
                elif self._lift_end is None:
                    self._lift_end = t + tc.lift_time
                elif t >= self._lift_end - 1e-9:
                    self._lifting, self._lift_end = False, None
            elif self._touch_t is None and f >= tc.detect_force:
                self._touch_t = t
                self._landings += 1
                self._kept = False
            if self._touch_t is not None and t - self._touch_t >= tc.settle:
                if not self._kept:  # the landing check, once per landing
                    self._kept = landing_kept(self._task_err, self._landings, tc)
                if self._kept:
                    if force_settled(f, t - self._touch_t, tc):
                        self.phase = HOLD
                        self._hold_end = t + tc.hold_time
                else:  # lift the probe and land again; the force loop starts over
                    if tc.land_correction and self._cent_err is not None:
                        self._aim_samples.append(self._cent_err + self._aim)
                        self._aim = aim_shift(self._aim_samples)
                    self._cent_err = None
                    self._touch_t = None
                    self._lifting = True
                    self._integral = 0.0
                    self._task_err = None
        elif self.phase == HOLD and t >= self._hold_end - 1e-9:
            self.phase = RELEASE
        return False

    def step(self, t, dt, view, gview, est, twist=None, force: ForceReading | None = None):
        self._ps = None
        per = self.perceive(t, dt, view, est)
        mode, event, seen, ibvs_twist, points, features, error, rmse, extra = per
        tc = self.touch
        prev = self.phase
        ps = self._ps
        valid = seen and ps is not None and ps.valid
        # the force estimate, low-pass filtered (`force_filter`)
        f_hat = force.force if force is not None and force.valid else float("nan")
        if np.isfinite(f_hat):
            self._f = low_pass(self._f, f_hat, dt, tc.force_filter)
        f = self._f if self._f is not None else 0.0
        if self._touch_t is not None and view.found:  # where the landed probe aims (pixels)
            err = task_image_error(view.points, self.local_points)
            self._task_err = low_pass(self._task_err, err, dt, tc.land_filter)
            c = np.mean(np.asarray(view.points, float) - self.local_points, axis=0)
            self._cent_err = low_pass(self._cent_err, c, dt, tc.land_filter)
        tare = self._transition(t, ps if valid else None, f)
        if tare:  # the force loop starts from the tared estimate
            self._f = None
            f = 0.0
        pressing = self.phase in (CONTACT, HOLD)
        pinned = is_pinned(self.phase, self._touch_t is not None, tc.contact_view)
        switched = pinned != self._pinned  # the view changes: the safety monitor re-arms
        self._pinned = pinned
        lv = None
        if pinned:  # the servo's view is the task's: C_L against its reference
            lv = self.local_view(est.q)
            valid = seen and lv.valid
            points, features, error = lv.points, lv.features, lv.error
            rmse = task_image_error(lv.points, self.local_points) if valid else float("nan")
            measured = task_image_error(view.points if view.found else None, self.local_points)
            extra = {**extra, "rmse_measured": measured}
        if twist is None and valid:
            if pinned:
                twist = self.pinned_twist(lv, ps)
            elif pressing:
                e = ps.error.copy()
                # aimed at the reference's points less the aim's shift: the centroid rows
                # (p_x, p_y, the points' mean) by the shift, the rest unchanged
                e[3:5] += self._aim
                e[5] = 0.0  # p_z (the perimeter: the distance) is the force loop's
                v = self.ibvs.twist(ps.points, ps.depths, error=e)
                if self._lifting:
                    v[5] = -tc.approach_speed  # lifting off the surface
                elif self._touch_t is None:
                    v[5] = approach_speed(self._depth, ps.error[5], ps.features[5], tc)
                else:
                    v[5] = 0.0  # the axial reference is set below (admittance)
                twist = v
            else:
                twist = self.standoff_ibvs.features_error_twist(ps.points, ps.depths)[2]
                if self.phase == RELEASE:
                    twist = release_twist(twist, tc)
        if self.phase in (APPROACH, RELEASE) and valid:
            # the RMSE the safety monitor watches: to the view this phase servoes to
            rmse = normalized_rmse(ps.points, self.standoff_points)
        if prev != self.phase:
            event = f"touch: {self.phase}"
        cmd = self.command(t, dt, est.q, gview, twist, mode, event, valid, ibvs_twist, points,
                           features, error, rmse, extra)  # fmt: skip
        fields = {}
        if pressing and self._touch_t is not None and valid:
            # admittance (module docstring): the reference along the camera axis at the PI
            # offset of the force error from the estimated pose, the other directions as the
            # IBVS integrated them
            a = self.joint_rates(est.q, _AXIAL)  # joint displacement per metre along the axis
            aa = float(a @ a)
            if aa > 0.0:
                offset, self._integral = force_offset(self._integral, tc.force - f, dt, tc)
                now = float(a @ (self.q_d - est.q)) / aa
                self.q_d = self.q_d + a * (offset - now)
                self.qd_d = self.qd_d - a * (float(a @ self.qd_d) / aa)
                fields = {"q_d": self.q_d.copy(), "qd_d": self.qd_d.copy()}
        changed = prev != self.phase or switched  # a new phase or view: the monitor re-arms
        return replace(cmd, phase=self.phase, tare_force=tare, phase_changed=changed,
                       landing=self._landings, **fields)  # fmt: skip


_AXIAL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # a unit translation along C_V's z (the axis)
