"""The logger block: one row per control period, numpy arrays at the end.

Keys and meanings are those of :mod:`tdacm.sim.outputs` (``LOG_KEYS``); the logger is the only
block that sees both the true state (``q``, ``qd``) and what the controller used.
"""

from __future__ import annotations

import numpy as np

from .._linalg import solve as _solve
from ..lie.se3 import rotation_angle
from ..sim.outputs import LOG_KEYS
from .data import (
    ActuatorCommand,
    LocalView,
    PlantState,
    SensorReadings,
    ServoCommand,
    StateEstimate,
)
from .servo import MODE_CODES, normalized_rmse

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
        g = readings.global_
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
        if self.frame_composer is not None:
            self.frames.append(self.frame_composer(readings, view, cmd, plant.t))

    def arrays(self) -> dict:
        return {k: np.asarray(v) for k, v in self.rows.items()}
