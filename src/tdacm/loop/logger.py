"""The logger block: one row per control period, numpy arrays at the end.

Keys and meanings are those of :mod:`tdacm.sim.outputs` (``LOG_KEYS``); the logger is the only
block that sees both the true state (``q``, ``qd``) and what the controller used.
"""

from __future__ import annotations

import numpy as np

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

    def __init__(self, desired_points, frame_composer=None):
        self.desired_points = np.asarray(desired_points, float)
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
        if self.frame_composer is not None:
            self.frames.append(self.frame_composer(readings, view, cmd, plant.t))

    def arrays(self) -> dict:
        return {k: np.asarray(v) for k, v in self.rows.items()}
