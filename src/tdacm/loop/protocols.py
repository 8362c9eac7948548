"""What a replaceable block receives and returns (structural protocols, no base class needed).

A user's controller or servo is any object with these methods; pass it to
:class:`~tdacm.loop.ClosedLoop` (``controller=``, ``servo=``) or name its class in a scenario
(``controller.class = "package.module:ClassName"``, constructed as ``ClassName(context)`` with
a :class:`ControllerContext`).

Data flow of one period: ``Estimator.step`` -> ``Servo.step`` -> ``LowLevelController.step``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from .data import (
    ActuatorCommand,
    GlobalView,
    LocalView,
    SensorReadings,
    ServoCommand,
    StateEstimate,
)


@runtime_checkable
class LowLevelController(Protocol):
    """Joint reference -> actuator inputs.

    ``step(estimate, command, dt)`` receives the state estimate (``q``, ``qd``: the only state it
    may use), the servo's :class:`ServoCommand` (``q_d``, ``qd_d``, ``qdd_d``) and the control
    period, and returns an :class:`ActuatorCommand` whose ``u`` is
    ``[4 thrusts, n_a tensions]`` (tensions only for a fixed base), thrusts in
    ``[0, max_thrust]`` and tensions in ``[0, max_tension]``. ``reset(estimate)`` starts a run.
    """

    def reset(self, estimate: StateEstimate) -> None: ...

    def step(
        self, estimate: StateEstimate, command: ServoCommand, dt: float
    ) -> ActuatorCommand: ...


@runtime_checkable
class Servo(Protocol):
    """Perception and estimate -> joint reference.

    ``step(t, dt, view, global_view, estimate, twist=None)`` returns a :class:`ServoCommand`;
    ``reset(q0, first_view)`` starts a run; ``mode`` is ``"ibvs"`` or ``"recovery"``;
    ``desired_points`` is the reference snapshot (for the logs and the safety monitor).
    """

    mode: str
    desired_points: np.ndarray

    def reset(self, q0, first_view: LocalView | None = None) -> None: ...

    def step(
        self,
        t: float,
        dt: float,
        view: LocalView,
        global_view: GlobalView | None,
        estimate: StateEstimate,
        twist: np.ndarray | None = None,
    ) -> ServoCommand: ...


@runtime_checkable
class Estimator(Protocol):
    """Sensor readings (and the applied input) -> state estimate."""

    def reset(self, t: float) -> StateEstimate: ...

    def step(self, readings: SensorReadings, u_applied: np.ndarray, dt: float) -> StateEstimate: ...


@dataclass(frozen=True)
class ControllerContext:
    """What a controller built from a scenario receives.

    ``system`` is the robot's structure (kinematics, limits, ``Gamma``); ``model`` the
    controller's *perturbed* model (:class:`~tdacm.control.EstimatedModel`), the only dynamics
    it may use; ``q_star`` the desired configuration; ``options`` the scenario's
    ``[controller]`` keys of the adaptive law and every key of ``[controller.options]``;
    ``law`` the same keys of the adaptive law as their record
    (:class:`~tdacm.control.config.ControlLawConfig`; ``None``: read from ``options``)."""

    system: object
    model: object
    q_star: np.ndarray
    dt: float
    options: dict = field(default_factory=dict)
    law: object = None
