"""The Cosserat rod: strain bases, material and section data, tendon routing."""

from .basis import MODE_NAMES, StrainBasis
from .rod import Rod, SectionedRod, default_gauss_points, min_gauss_points
from .tendons import Tendons

__all__ = [
    "MODE_NAMES",
    "Rod",
    "SectionedRod",
    "StrainBasis",
    "Tendons",
    "default_gauss_points",
    "min_gauss_points",
]
