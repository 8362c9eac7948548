"""tdacm: tendon-driven aerial continuum manipulators.

A geometrically exact strain-parameterized (GVS) Cosserat rod coupled with an underactuated
quadrotor on SE(3), dual-camera visual servoing and adaptive control, after Amiri and
Janabi-Sharifi, "Strain-Parameterized Coupled Dynamics and Dual-Camera Visual Servoing for
Aerial Continuum Manipulators".
"""

# Before any kernel is defined: where numba caches the package's kernels and for which CPU (a
# wheel's shipped kernels, tdacm._jitcache), and the notice of what compiles (tdacm._compiling).
from ._jitcache import activate as _activate_kernel_cache

_activate_kernel_cache()

from ._compiling import install as _install_compile_notice  # noqa: E402

_install_compile_notice()

from .base import FixedBase, Quadrotor  # noqa: E402
from .rod import Rod, SectionedRod, StrainBasis, Tendons  # noqa: E402
from .system import (  # noqa: E402
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
