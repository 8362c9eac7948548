"""The coupled TD-ACM model: kernels, the TDACM API, statics, integration, the paper system."""

from .integrate import SimulationResult, simulate
from .paper import PAPER_DEFAULTS_NOT_IN_PAPER, dual_paper_system, paper_system
from .tdacm import TDACM, Arm, Loads, SingularConfigurationError, Terms, default_attachment

__all__ = [
    "PAPER_DEFAULTS_NOT_IN_PAPER",
    "TDACM",
    "Arm",
    "Loads",
    "SimulationResult",
    "SingularConfigurationError",
    "Terms",
    "default_attachment",
    "dual_paper_system",
    "paper_system",
    "simulate",
]
