"""Servoing into contact: a hybrid vision/force law on the estimated tip force.

Two blocks, used when ``[touch] enabled`` (:class:`~.config.TouchConfig`, docs/contact.md):

* :class:`TipForceBlock` estimates the normal force on the arm's contact sphere along the
  tip camera's optical axis every period, with no force sensor: the controller's model, the
  applied inputs and the state estimate (:class:`~tdacm.estimation.contact_force.TipForceEstimator`
  on all rows, so the drone's balance sees a force along the rod's axis), tared when the servo
  asks for it (``ServoCommand.tare_force``, once hovering at the standoff, before touching);
  the residual of the model's balance from a generalized-momentum observer
  (:class:`~tdacm.estimation.contact_force.MomentumObserver`, ``force_estimator =
  "momentum"``, no accelerations) or with accelerations from differenced velocities
  (``"differenced"``);
* :class:`TouchServo`, the robust servo (:class:`~.servo.RobustServo`) with four phases:

  1. ``approach``: IBVS (all six features) to the *standoff* view, the reference snapshot
     (the view at the contact pose) seen from ``standoff`` farther back along the camera
     axis: its points scaled by ``d / (d + standoff)`` (exact for a target facing the camera,
     ``d`` the reference depth); it ends once the RMSE to that view stays below
     ``start_rmse`` for ``dwell`` s (the force estimator is tared then);
  2. ``contact``: hybrid: the IBVS twist on the five features other than the perimeter
     ``p_z`` (the one that measures the distance), and the translation along the camera axis
     from the force loop: toward the surface at ``approach_gain`` times the distance left
     (read from ``p_z``), between ``touch_speed`` and ``approach_speed``, until the
     estimated force reaches ``detect_force``; from then on the admittance law below;
  3. ``hold``: the same law, ``settle`` s after the first touch, for ``hold_time`` s;
  4. ``release``: IBVS back to the standoff view (the probe leaves the surface).

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

from ..estimation.contact_force import MomentumObserver, TipForceEstimator
from ..vision.ibvs import IBVSController
from .config import TouchConfig
from .data import PHASES, ForceReading, LocalView, StateEstimate
from .servo import RobustServo, normalized_rmse

APPROACH, CONTACT, HOLD, RELEASE = PHASES


def observer_step(block, q, qd, u_applied, dt):
    """One period of a force block's momentum observer (``block.observer``, its last
    residual kept in ``block._last``): the residual, or None while there is no applied input
    (the observer restarts) or it is starting."""
    if u_applied is None:
        block.observer.reset()
        block._last = None
        return None
    started = block.observer.started
    r = block.observer.step(q, qd, u_applied, dt)
    block._last = r
    return r if started else None


class TipForceBlock:
    """Estimated normal force on the probe along the tip camera's axis (module docstring).

    ``model``: the controller's :class:`~tdacm.control.EstimatedModel`; ``tip_mount``:
    ``g_{C_L}^L``; ``offset``: the contact sphere's centre in the tip frame; ``kind``:
    ``"momentum"`` (the generalized force from a
    :class:`~tdacm.estimation.contact_force.MomentumObserver` of gain ``gain``, no
    accelerations) or ``"differenced"`` (the model's balance with ``qdd`` the finite
    difference of ``qd_hat``)."""

    def __init__(self, model, tip_mount, offset, input_sigma: float, kind: str, gain: float):
        if kind not in ("momentum", "differenced"):
            raise ValueError(f"kind must be 'momentum' or 'differenced', got {kind!r}")
        self.kind = kind
        self.estimator = TipForceEstimator(model, "all", input_sigma=input_sigma, offset=offset)
        self.observer = MomentumObserver(model, gain) if kind == "momentum" else None
        self.system = model.system
        self.tip_mount = np.asarray(tip_mount, float)
        self.reset()

    def reset(self) -> None:
        self.estimator.clear_tare()
        if self.observer is not None:
            self.observer.reset()
        self._qd_prev = None
        self._last = None

    def step(self, est: StateEstimate, u_applied, dt: float) -> ForceReading:
        q, qd = np.asarray(est.q, float), np.asarray(est.qd, float)
        if self.observer is not None:
            return self._step_momentum(est, q, qd, u_applied, dt)
        qdd = None if self._qd_prev is None else (qd - self._qd_prev) / dt
        self._qd_prev = qd.copy()
        if u_applied is None or qdd is None:
            self._last = None
            return ForceReading(est.t)
        normal = -(self.system.tip_pose(q) @ self.tip_mount)[:3, 2]
        u = np.asarray(u_applied, float)
        self._last = (q, qd, u, qdd)
        f, sigma = self.estimator.normal_force(q, qd, u, normal, qdd, est.P)
        return ForceReading(est.t, f, sigma, normal, True)

    def _step_momentum(self, est, q, qd, u_applied, dt) -> ForceReading:
        r = observer_step(self, q, qd, u_applied, dt)
        if r is None:
            return ForceReading(est.t)
        normal = -(self.system.tip_pose(q) @ self.tip_mount)[:3, 2]
        # the inputs' white noise through the observer's first-order lag: the steady variance
        # of x_k = (1 - k) x_{k-1} + k w_k is k / (2 - k) that of w (k = K_o dt)
        k = self.observer.gain * dt
        cov = self.estimator.input_cov(q) * (k / (2.0 - k))
        f, sigma = self.estimator.normal_force_of(q, r, normal, cov)
        return ForceReading(est.t, f, sigma, normal, True)

    def tare(self) -> None:
        """Take the last period's residual as the model's bias (contact-free: before touching)."""
        if self._last is None:
            return
        if self.observer is not None:
            self.estimator.bias = self._last.copy()
        else:
            self.estimator.tare(*self._last)


class TouchServo(RobustServo):
    """The robust servo with the phases of the module docstring; ``touch``: the
    :class:`~.config.TouchConfig`."""

    def __init__(self, *args, touch: TouchConfig | None = None, **kwargs):
        self.touch = touch or TouchConfig(enabled=True)  # before the base's reset
        super().__init__(*args, **kwargs)
        tc = self.touch
        d = float(np.mean(self.desired_depths))
        self._depth = d
        k = d / (d + tc.standoff)
        self.standoff_points = self.desired_points * k
        self.standoff_ibvs = IBVSController(
            self.standoff_points,
            self.desired_depths + tc.standoff,
            gain=self.ibvs.gain,
            mode=self.ibvs.mode,
            floor=self.ibvs.floor,
            solver=self.ibvs.solver,
        )
        self._reset_phase()

    def _reset_phase(self) -> None:
        self.phase = APPROACH
        self._below_since = None
        self._touch_t = None
        self._hold_end = None
        self._f = None
        self._integral = 0.0

    def reset(self, q0, first_view: LocalView | None = None) -> None:
        super().reset(q0, first_view)
        self._reset_phase()

    def predicted_view(self, servo_pose, camera_pose=None):
        ps = super().predicted_view(servo_pose, camera_pose)
        self._ps = ps
        return ps

    def step(self, t, dt, view, gview, est, twist=None, force: ForceReading | None = None):
        self._ps = None
        per = self.perceive(t, dt, view, est)
        mode, event, seen, ibvs_twist, points, features, error, rmse, extra = per
        tc = self.touch
        prev = self.phase
        tare = False
        ps = self._ps
        valid = seen and ps is not None and ps.valid
        # the force estimate, low-pass filtered (`force_filter`)
        f_hat = force.force if force is not None and force.valid else float("nan")
        if np.isfinite(f_hat):
            a = min(1.0, dt / tc.force_filter) if tc.force_filter > 0 else 1.0
            self._f = f_hat if self._f is None else self._f + a * (f_hat - self._f)
        f = self._f if self._f is not None else 0.0
        # phase transitions
        if self.phase == APPROACH and valid:
            r = normalized_rmse(ps.points, self.standoff_points)
            if r <= tc.start_rmse:
                self._below_since = t if self._below_since is None else self._below_since
                if t - self._below_since >= tc.dwell:
                    self.phase = CONTACT
                    tare = True
                    self._f = None
                    f = 0.0
            else:
                self._below_since = None
        elif self.phase == CONTACT:
            if self._touch_t is None and f >= tc.detect_force:
                self._touch_t = t
            if self._touch_t is not None and t - self._touch_t >= tc.settle:
                self.phase = HOLD
                self._hold_end = t + tc.hold_time
        elif self.phase == HOLD and t >= self._hold_end - 1e-9:
            self.phase = RELEASE
        pressing = self.phase in (CONTACT, HOLD)
        if twist is None and valid:
            if pressing:
                e = ps.error.copy()
                e[5] = 0.0  # p_z (the perimeter: the distance) is the force loop's
                v = self.ibvs.twist(ps.points, ps.depths, error=e)
                if self._touch_t is None:
                    # the distance left to the contact pose from the perimeter (~ 1 / depth):
                    # slow down to touch_speed over the last centimetres (a softer impact)
                    dist = self._depth * max(0.0, -ps.error[5]) / ps.features[5]
                    v[5] = min(tc.approach_speed, max(tc.touch_speed, tc.approach_gain * dist))
                else:
                    v[5] = 0.0  # the axial reference is set below (admittance)
                twist = v
            else:
                twist = self.standoff_ibvs.features_error_twist(ps.points, ps.depths)[2]
        if self.phase in (APPROACH, RELEASE) and valid:
            # the RMSE the safety monitor watches: to the view this phase servoes to
            rmse = normalized_rmse(ps.points, self.standoff_points)
        if prev != self.phase:
            event = f"touch: {self.phase}"
        cmd = self.command(t, dt, est.q, gview, twist, mode, event, seen, ibvs_twist, points,
                           features, error, rmse, extra)  # fmt: skip
        fields = {}
        if pressing and self._touch_t is not None and valid:
            # admittance (module docstring): the reference along the camera axis at the PI
            # offset of the force error from the estimated pose, the other directions as the
            # IBVS integrated them
            a = self.joint_rates(est.q, _AXIAL)  # joint displacement per metre along the axis
            aa = float(a @ a)
            if aa > 0.0:
                err = tc.force - f
                self._integral += tc.force_integral * err * dt
                offset = tc.force_gain * err + self._integral
                now = float(a @ (self.q_d - est.q)) / aa
                self.q_d = self.q_d + a * (offset - now)
                self.qd_d = self.qd_d - a * (float(a @ self.qd_d) / aa)
                fields = {"q_d": self.q_d.copy(), "qd_d": self.qd_d.copy()}
        return replace(cmd, phase=self.phase, tare_force=tare, phase_changed=prev != self.phase,
                       **fields)  # fmt: skip


_AXIAL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # a unit translation along C_V's z (the axis)
