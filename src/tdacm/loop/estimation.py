"""The estimation block's simplest form: the true state (the paper's idealized simulations).

:class:`TrueState` passes the plant's state through, as if every coordinate were measured
exactly; it is the sensor of ``estimation.source = "true"``. It is the one place after the
sensors that reads the plant, on purpose and by name. The real estimator,
:class:`tdacm.estimation.FilterBlock` (``estimation.source = "estimated"``, assembled by
:func:`tdacm.sim.assemble.estimation_block`), implements the same
:class:`~.protocols.Estimator` protocol from the sensor readings instead.
"""

from __future__ import annotations

from .data import SensorReadings, StateEstimate


class TrueState:
    """``estimate = plant state`` (no covariance)."""

    def __init__(self, plant):
        self._plant = plant

    def reset(self, t: float = 0.0) -> StateEstimate:
        s = self._plant.state
        return StateEstimate(s.t, s.q, s.qd)

    def step(self, readings: SensorReadings, u_applied, dt: float) -> StateEstimate:
        s = self._plant.state
        return StateEstimate(s.t, s.q, s.qd)
