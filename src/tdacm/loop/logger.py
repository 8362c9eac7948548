"""The logger block: one row per control period, numpy arrays at the end.

The logged series and their units and meanings are defined here (:data:`LOG_KEYS`,
:data:`SERIES_INFO`); the run folder (:mod:`tdacm.sim.outputs`) writes them. The logger is the
only block that sees both the true state (``q``, ``qd``) and what the controller used.
"""

from __future__ import annotations

import numpy as np

from .._linalg import solve as _solve
from ..lie.se3 import rotation_angle
from .data import (
    PHASES,
    ActuatorCommand,
    ForceReading,
    LocalView,
    PlantState,
    SensorReadings,
    ServoCommand,
    StateEstimate,
)
from .servo import MODE_CODES, normalized_rmse
from .touch import task_image_error

#: One value per control step (written as single CSV columns).
SCALAR_SERIES = (
    "rmse",
    "rmse_raw",
    "rmse_measured",
    "rmse_true",
    "target_error_deg",
    "mode",
    "V",
    "detected_local",
    "detected_global",
    "thrust_saturated",
    "tension_saturated",
)
#: Vector series (one CSV column per component), then the scalar ones: what the runner logs.
VECTOR_SERIES = (
    "t",
    "q",
    "qd",
    "q_d",
    "qd_d",
    "u",
    "tau",
    "q_ref",
    "features",
    "feature_error",
    "points_local",
    "points_virtual",
    "twist",
    "delta_hat",
    "q_hat",  # the state estimate the blocks after the sensors used (= q for source "true")
    "qd_hat",
    "P_diag",  # diagonal of its covariance [q, qd] (NaN for the true state)
)
LOG_KEYS = VECTOR_SERIES + SCALAR_SERIES
#: Logged only when the plant has obstacles (:attr:`RunLog.contact` set).
CONTACT_SERIES = ("contact_tip", "contact_rod")
#: Logged only when the loop estimates the tip force (servoing into contact, ``[touch]``).
TOUCH_SERIES = (
    "force_true", "force_hat", "force_sigma", "touch_phase", "touch_landing", "rmse_local",
    "rmse_local_true",
)  # fmt: skip

#: series -> (unit, meaning). Units of configuration-space series depend on the coordinate:
#: "q" means rad (angles), m (positions), 1/m (strains); "qd" their rates; "tau" N m, N, N m^2.
SERIES_INFO = {
    "t": ("s", "simulated time of the control step"),
    "q": ("q", "true configuration [phi, theta, psi, x, y, z, q_s...] (ZYX Euler angles)"),
    "qd": ("qd", "true generalized velocity"),
    "q_d": ("q", "desired configuration sent to the low-level controller (IBVS or recovery)"),
    "qd_d": ("qd", "desired generalized velocity"),
    "q_ref": ("q", "reference used by the low-level controller (roll/pitch from the drone loop)"),
    "u": ("N", "inputs: 4 rotor thrusts f_i (floating base), then tendon tensions T_i"),
    "tau": ("tau", "generalized force commanded by the adaptive controller"),
    "delta_hat": ("tau", "adaptive estimate of the unmodelled generalized force"),
    "features": ("feat", "advanced image features [p_phi, p_theta, p_psi, p_x, p_y, p_z]"),
    "feature_error": ("feat", "advanced-feature error p* - p*_d"),
    "points_local": ("-", "detected points in C_L, normalized image coordinates (x, y) x 4"),
    "points_virtual": ("-", "points in the virtual camera C_V (floating) or C_L, normalized"),
    "twist": ("twist", "commanded local camera twist [w_x, w_y, w_z, v_x, v_y, v_z]"),
    "rmse": (
        "-",
        "normalized RMSE of the points used by the servo to the desired points (several arms: "
        "the largest over the arms)",
    ),
    "rmse_raw": ("-", "normalized RMSE of the raw C_L points to the desired points"),
    "mode": ("-", "0 = IBVS, 1 = recovery (trajectory planned from one C_G snapshot)"),
    "V": ("J", "Lyapunov function of the adaptive controller (known part)"),
    "detected_local": ("-", "1 if the target was detected in C_L"),
    "detected_global": (
        "-",
        "1 if the target was detected in C_G (0 when C_G was not rendered: it renders for the "
        "servo's recovery snapshot, every cameras.global_output_every periods and for a video)",
    ),
    "thrust_saturated": ("-", "1 if a rotor thrust hit its limit"),
    "tension_saturated": ("-", "1 if a tendon tension hit its limit"),
    "q_hat": ("q", "state estimate used after the sensors (= q for estimation.source = true)"),
    "qd_hat": ("qd", "generalized-velocity estimate used after the sensors"),
    "P_diag": ("var", "variances of the estimate [q_hat, qd_hat] (NaN for the true state)"),
    "contact_tip": ("N", "contact force of the obstacles on the tip sphere (inertial x, y, z)"),
    "contact_rod": ("N", "total contact force of the obstacles on the rod (inertial x, y, z)"),
    "force_true": ("N", "true contact force (tip sphere and rod) along the estimate's normal"),
    "force_hat": ("N", "estimated normal force on the probe (tendons, thrusts, model)"),
    "force_sigma": ("N", "standard deviation of the estimated normal force"),
    "touch_phase": ("-", "0 = approach, 1 = contact, 2 = hold, 3 = release ([touch])"),
    "touch_landing": (
        "-",
        "[touch]: the probe's landings so far (a landing off the marker is lifted)",
    ),
    "rmse_local": (
        "-",
        "[touch]: the task's image error, the detected C_L points' normalized RMSE to the "
        "reference snapshot in C_L (NaN without a detection)",
    ),
    "rmse_local_true": ("-", "[touch]: the same for the true C_L points (the simulator's)"),
    "rmse_local_arms": ("-", "several arms, [touch]: each arm's rmse_local"),
    "rmse_local_true_arms": ("-", "several arms, [touch]: each arm's rmse_local_true"),
    "rmse_arms": ("-", "several arms: each arm's normalized RMSE of the points its servo used"),
    "rmse_true_arms": ("-", "several arms: each arm's RMSE of the true points in its C_V"),
    "detected_arms": ("-", "several arms: 1 if the arm's target was detected in its C_L"),
    "points_arms": ("-", "several arms: the points each arm's servo used (its C_V), normalized"),
    "points_local_arms": ("-", "several arms: each arm's detected points in its C_L, normalized"),
    "twist_arms": ("twist", "several arms: each arm's commanded C_L twist [w; v]"),
}

_NAN4 = np.full((4, 2), np.nan)
_NAN6 = np.full(6, np.nan)


class RunLog:
    """Collects the per-period records (``record``) and returns them as arrays (``arrays``)."""

    def __init__(self, desired_points, frame_composer=None, truth=None):
        self.desired_points = np.asarray(desired_points, float)
        # truth(q) -> (true points in the servo camera (4, 2), true target pose (4x4)):
        # the logger is the one block allowed to compare with the simulated world
        self.truth = truth
        self.rows = {k: [] for k in LOG_KEYS}
        self.frames = []
        self.frame_composer = frame_composer
        #: ``(q, qd) -> (tip force, rod force)`` of the obstacles: adds :data:`CONTACT_SERIES`
        self.contact = None
        #: servoing into contact: the reference snapshot in C_L ``(4, 2)`` and ``q -> (true
        #: points in C_L, target pose)``, for the task's image error (``rmse_local``)
        self.local_reference = None
        self.truth_local = None

    def __len__(self) -> int:
        return len(self.rows["t"])

    def record(
        self,
        plant: PlantState,
        readings: SensorReadings,
        view: LocalView,
        estimate: StateEstimate,
        cmd: ServoCommand,
        act: ActuatorCommand,
        force: ForceReading | None = None,
    ) -> None:
        r = self.rows
        raw = view.points if view.found else None
        r["t"].append(plant.t)
        r["q"].append(plant.q)
        r["qd"].append(plant.qd)
        r["q_d"].append(cmd.q_d)
        r["qd_d"].append(cmd.qd_d)
        r["u"].append(act.u)
        r["tau"].append(act.tau)
        r["q_ref"].append(act.q_ref)
        r["features"].append(cmd.features if cmd.features is not None else _NAN6)
        r["feature_error"].append(cmd.error if cmd.error is not None else _NAN6)
        r["points_local"].append(raw if raw is not None else _NAN4)
        r["points_virtual"].append(cmd.points if cmd.points is not None else _NAN4)
        r["rmse"].append(cmd.rmse)
        r["rmse_raw"].append(normalized_rmse(raw, self.desired_points))
        r["rmse_measured"].append(cmd.rmse_measured if np.isfinite(cmd.rmse_measured) else (
            normalized_rmse(cmd.points, self.desired_points) if view.found else np.nan
        ))  # fmt: skip
        te, rt = np.nan, np.nan
        if self.truth is not None:
            pts, g_t = self.truth(plant.q)
            rt = normalized_rmse(pts, self.desired_points)
            if cmd.target_pose is not None:
                d = _solve(g_t, cmd.target_pose)[:3, :3]
                te = float(np.degrees(rotation_angle(d)))
        r["rmse_true"].append(rt)
        r["target_error_deg"].append(te)
        r["mode"].append(MODE_CODES[cmd.mode])
        r["V"].append(act.V)
        r["detected_local"].append(bool(view.found))
        g = readings.global_rendered  # not rendered this period: logged as not detected
        r["detected_global"].append(bool(g.found) if g is not None else False)
        r["thrust_saturated"].append(bool(act.thrust_saturated))
        r["tension_saturated"].append(bool(act.tension_saturated))
        r["twist"].append(cmd.twist)
        dh = act.delta_hat if act.delta_hat is not None else np.zeros(len(plant.q))
        r["delta_hat"].append(dh)
        r["q_hat"].append(estimate.q)
        r["qd_hat"].append(estimate.qd)
        n2 = 2 * len(plant.q)
        r["P_diag"].append(
            np.diag(estimate.P).copy() if estimate.P is not None else np.full(n2, np.nan)
        )
        tip = rod = None
        if self.contact is not None:
            tip, rod = self.contact(plant.q, plant.qd)
            r.setdefault("contact_tip", []).append(tip)
            r.setdefault("contact_rod", []).append(rod)
        if force is not None:
            true = np.nan
            if force.valid and tip is not None:
                true = float((tip + rod) @ force.normal)
            elif tip is not None:
                true = float(np.linalg.norm(tip + rod))
            r.setdefault("force_true", []).append(true)
            r.setdefault("force_hat", []).append(force.force)
            r.setdefault("force_sigma", []).append(force.sigma)
            phase = PHASES.index(cmd.phase) if cmd.phase in PHASES else -1
            r.setdefault("touch_phase", []).append(phase)
            r.setdefault("touch_landing", []).append(cmd.landing)
            ref = self.local_reference
            measured = truth = np.nan
            if ref is not None:
                measured = task_image_error(raw, ref) if raw is not None else np.nan
                if self.truth_local is not None:
                    truth = task_image_error(self.truth_local(plant.q)[0], ref)
            r.setdefault("rmse_local", []).append(measured)
            r.setdefault("rmse_local_true", []).append(truth)
        if self.frame_composer is not None:
            self.frames.append(self.frame_composer(readings, view, cmd, plant.t))

    def arrays(self) -> dict:
        return {k: np.asarray(v) for k, v in self.rows.items()}


class NullLog(RunLog):
    """A logger that keeps nothing (the Gymnasium env: an episode's rows are not needed, and
    recording them costs about a tenth of a period)."""

    def record(self, *args, **kwargs) -> None:
        pass
