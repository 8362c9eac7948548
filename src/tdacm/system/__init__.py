"""The coupled TD-ACM model: kernels, the TDACM API, statics, integration, the paper system."""

from .integrate import SimulationResult, simulate
from .paper import PAPER_DEFAULTS_NOT_IN_PAPER, paper_system
from .tdacm import TDACM, Loads, SingularConfigurationError, Terms, default_attachment

__all__ = [
    "PAPER_DEFAULTS_NOT_IN_PAPER",
    "TDACM",
    "Loads",
    "SimulationResult",
    "SingularConfigurationError",
    "Terms",
    "default_attachment",
    "paper_system",
    "simulate",
]
