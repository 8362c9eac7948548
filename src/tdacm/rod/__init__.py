"""The Cosserat rod: strain bases, material and section data, tendon routing."""

from .basis import MODE_NAMES, StrainBasis
from .rod import Rod
from .tendons import Tendons

__all__ = ["MODE_NAMES", "Rod", "StrainBasis", "Tendons"]
