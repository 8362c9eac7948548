"""Model-based control of the TD-ACM (paper, "Model-Based Control" and the recovery branch
of "Dual-Camera Servoing Algorithm"). See ``docs/control.md``.

* :mod:`.model` - estimated (perturbed) dynamics :class:`EstimatedModel`;
* :mod:`.adaptive` - the adaptive sliding-mode law, gain condition, Lyapunov function;
* :mod:`.allocation` - thrusts through ``Gamma`` and non-negative tendon tensions;
* :mod:`.hierarchical` - translational loop, attitude loop, allocation: :class:`TDACMController`;
* :mod:`.trajectory` - cubic joint trajectory;
* :mod:`.planner` - target pose from C_G (IPPE square), ``q_s^d`` minimization, mode switch.
"""

from .adaptive import (
    AdaptiveController,
    AdaptiveGains,
    AdaptiveOutput,
    GainConditionError,
    check_gains,
)
from .allocation import (
    TendonAllocation,
    ThrustAllocation,
    allocate_tensions,
    allocate_thrusts,
)
from .hierarchical import ControlStep, TDACMController, attitude_from_force, default_gains
from .model import EstimatedModel, EstimatedTerms
from .planner import (
    Mode,
    ModeSwitch,
    PlanResult,
    estimate_target_pose,
    plan_rod_configuration,
    target_in_local_camera,
)
from .trajectory import CubicTrajectory

__all__ = [
    "AdaptiveController",
    "AdaptiveGains",
    "AdaptiveOutput",
    "ControlStep",
    "CubicTrajectory",
    "EstimatedModel",
    "EstimatedTerms",
    "GainConditionError",
    "Mode",
    "ModeSwitch",
    "PlanResult",
    "TDACMController",
    "TendonAllocation",
    "ThrustAllocation",
    "allocate_tensions",
    "allocate_thrusts",
    "attitude_from_force",
    "check_gains",
    "default_gains",
    "estimate_target_pose",
    "plan_rod_configuration",
    "target_in_local_camera",
]
