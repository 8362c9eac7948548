"""Cosserat rod parameters and cross-section matrices (circular section).

Section matrices follow SoRoSim's choices (``shared/NOTES.md``):

* ``A = pi d^2/4``, ``I_y = I_z = pi d^4/64``, ``J = I_y + I_z``, ``G = E / (2 (1 + nu))``;
* inertia density ``Mbar = rho diag(J, I_y, I_z, A, A, A)`` (paper eq. (11));
* stiffness ``Hbar = diag(G J, E I_y, E I_z, E A, G A, G A)`` (paper eq. (18));
* damping ``Dbar = eta diag(J, 3 I_y, 3 I_z, 3 A, A, A)`` (paper eq. (17)).

The reference strain is ``xi* = [0, 0, 0, 1, 0, 0]``: a straight, unstretched rod along the local
x axis.  A point mass with a rotational inertia may sit at the tip (the tip camera).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _validate as V
from .basis import StrainBasis


@dataclass
class Rod:
    """A uniform circular Cosserat rod.

    Parameters (SI units)
    ----------
    length, diameter, density, youngs_modulus : strictly positive
    poisson_ratio : in (-1, 0.5)
    damping : material viscosity ``eta`` (Pa s), >= 0
    basis : the strain basis (default: the paper's two constant bending curvatures)
    n_gauss : Gauss-Legendre quadrature points along the rod (>= 1)
    magnus_order : 2 (the paper) or 4 (Zanna)
    tip_mass : point mass at the tip (kg), >= 0
    tip_inertia : principal inertias of the tip body about the tip frame axes (kg m^2)
    reference_strain : ``xi*`` (6,), constant along the rod
    """

    length: float = 1.0
    diameter: float = 2e-3
    density: float = 6.45e3
    youngs_modulus: float = 5e10
    poisson_ratio: float = 0.33
    damping: float = 1e2
    basis: StrainBasis = field(default_factory=StrainBasis)
    n_gauss: int = 8
    magnus_order: int = 4
    tip_mass: float = 0.0
    tip_inertia: tuple = (0.0, 0.0, 0.0)
    reference_strain: tuple = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0)

    def __post_init__(self):
        self.length = V.positive("length", self.length)
        self.diameter = V.positive("diameter", self.diameter)
        self.density = V.positive("density", self.density)
        self.youngs_modulus = V.positive("youngs_modulus", self.youngs_modulus)
        self.poisson_ratio = V.in_open_interval("poisson_ratio", self.poisson_ratio, -1.0, 0.5)
        self.damping = V.nonnegative("damping", self.damping)
        if not isinstance(self.basis, StrainBasis):
            raise ValueError(f"basis must be a StrainBasis, got {self.basis!r}")
        if not isinstance(self.n_gauss, int | np.integer) or self.n_gauss < 1:
            raise ValueError(f"n_gauss must be an integer >= 1, got {self.n_gauss!r}")
        if self.magnus_order not in (2, 4):
            raise ValueError(f"magnus_order must be 2 or 4, got {self.magnus_order!r}")
        self.tip_mass = V.nonnegative("tip_mass", self.tip_mass)
        ti = V.array("tip_inertia", self.tip_inertia, (3,))
        if np.any(ti < 0):
            raise ValueError(f"tip_inertia must be non-negative, got {self.tip_inertia!r}")
        self.tip_inertia = tuple(ti)
        self.reference_strain = tuple(V.array("reference_strain", self.reference_strain, (6,)))

    # ------------------------------------------------------------------ section properties
    @property
    def area(self) -> float:
        return np.pi * self.diameter**2 / 4.0

    @property
    def second_moment(self) -> float:
        """``I_y = I_z = pi d^4 / 64``."""
        return np.pi * self.diameter**4 / 64.0

    @property
    def polar_moment(self) -> float:
        """``J = I_y + I_z``."""
        return 2.0 * self.second_moment

    @property
    def shear_modulus(self) -> float:
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def bending_stiffness(self) -> float:
        """``E I``."""
        return self.youngs_modulus * self.second_moment

    @property
    def mass(self) -> float:
        """Mass of the rod without the tip body."""
        return self.density * self.area * self.length

    @property
    def inertia_density(self) -> np.ndarray:
        """``Mbar = rho diag(J, I_y, I_z, A, A, A)`` (6x6)."""
        a, i = self.area, self.second_moment
        return self.density * np.diag([2 * i, i, i, a, a, a])

    @property
    def stiffness_density(self) -> np.ndarray:
        """``Hbar = diag(G J, E I_y, E I_z, E A, G A, G A)`` (6x6)."""
        a, i, e, g = self.area, self.second_moment, self.youngs_modulus, self.shear_modulus
        return np.diag([g * 2 * i, e * i, e * i, e * a, g * a, g * a])

    @property
    def damping_density(self) -> np.ndarray:
        """``Dbar = eta diag(J, 3 I_y, 3 I_z, 3 A, A, A)`` (6x6)."""
        a, i = self.area, self.second_moment
        return self.damping * np.diag([2 * i, 3 * i, 3 * i, 3 * a, a, a])

    @property
    def tip_spatial_inertia(self) -> np.ndarray:
        """6x6 spatial inertia of the tip body in the tip frame (angular first)."""
        return np.diag([*self.tip_inertia, self.tip_mass, self.tip_mass, self.tip_mass])

    def quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Legendre abscissae ``X`` in (0, 1) and weights (summing to 1)."""
        x, w = np.polynomial.legendre.leggauss(self.n_gauss)
        return 0.5 * (x + 1.0), 0.5 * w
