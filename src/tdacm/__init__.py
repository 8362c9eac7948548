"""tdacm: tendon-driven aerial continuum manipulators.

A geometrically exact strain-parameterized (GVS) Cosserat rod coupled with an underactuated
quadrotor on SE(3), dual-camera visual servoing and adaptive control, after Amiri and
Janabi-Sharifi, "Strain-Parameterized Coupled Dynamics and Dual-Camera Visual Servoing for
Aerial Continuum Manipulators".
"""

from .base import FixedBase, Quadrotor
from .rod import Rod, SectionedRod, StrainBasis, Tendons
from .system import (
    TDACM,
    Loads,
    SimulationResult,
    SingularConfigurationError,
    Terms,
    dual_paper_system,
    paper_system,
    simulate,
)

__version__ = "0.1.0"

__all__ = [
    "TDACM",
    "FixedBase",
    "Loads",
    "Quadrotor",
    "Rod",
    "SectionedRod",
    "SimulationResult",
    "SingularConfigurationError",
    "StrainBasis",
    "Tendons",
    "Terms",
    "dual_paper_system",
    "paper_system",
    "simulate",
]
