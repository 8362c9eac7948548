"""Flight aerodynamics: the rotor wake, drag on the rod, the tip body and the drone, and wind.

This package sits at the layer of ``rod`` and ``base`` (it imports only ``_validate``, numpy and
numba), below ``system``, whose kernels call its numba functions inside the coupled dynamics
(the distributed wrench of eq. (16)).  :func:`tdacm.system.aero.aero_array` packs an
:class:`Aerodynamics` record for a built model.
"""

from .params import LAYOUTS, Aerodynamics, Air, Drag, RotorWake
from .wake import induced_velocity, jet_speed, wake_field
from .wind import DrydenTurbulence, Gust, SteadyWind, Wind, low_altitude_scales

__all__ = [
    "LAYOUTS",
    "Aerodynamics",
    "Air",
    "Drag",
    "DrydenTurbulence",
    "Gust",
    "RotorWake",
    "SteadyWind",
    "Wind",
    "induced_velocity",
    "jet_speed",
    "low_altitude_scales",
    "wake_field",
]
