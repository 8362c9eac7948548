"""Cosserat rod parameters and cross-section matrices (circular section).

Section matrices follow SoRoSim's choices for a circular section (``docs/model.md``):

* ``A = pi d^2/4``, ``I_y = I_z = pi d^4/64``, ``J = I_y + I_z``, ``G = E / (2 (1 + nu))``;
* inertia density ``Mbar = rho diag(J, I_y, I_z, A, A, A)`` (paper eq. (11));
* stiffness ``Hbar = diag(G J, E I_y, E I_z, E A, G A, G A)`` (paper eq. (18));
* damping ``Dbar = eta diag(J, 3 I_y, 3 I_z, 3 A, A, A)`` (paper eq. (17)).

The reference strain is ``xi* = [0, 0, 0, 1, 0, 0]``: a straight, unstretched rod along the local
x axis.  A point mass with a rotational inertia may sit at the tip (the tip camera).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as V
from .. import paper_values as PV
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
    n_gauss : Gauss-Legendre quadrature points along the rod; ``None`` (the default) picks
        :func:`default_gauss_points` (8 for up to order 5, ``2 (p + 1)`` above).  It must exceed
        the number of coefficients ``p + 1`` of every mode (see :func:`min_gauss_points`).
    magnus_order : 2 (the paper) or 4 (Zanna); ``None`` (the default) picks 4.  Order 2 is
        exact only for piecewise-constant strains: with a richer basis it stalls at 0.1-1 % of
        the rod length in large deflections (a ``UserWarning`` says so).
    tip_mass : point mass at the tip (kg), >= 0
    tip_inertia : principal inertias of the tip body about the tip frame axes (kg m^2)
    reference_strain : ``xi*`` (6,), constant along the rod
    """

    length: float = PV.ROD_LENGTH
    diameter: float = PV.ROD_DIAMETER
    density: float = PV.ROD_DENSITY
    youngs_modulus: float = PV.ROD_YOUNGS_MODULUS
    poisson_ratio: float = PV.ROD_POISSON_RATIO
    damping: float = PV.ROD_DAMPING
    basis: StrainBasis = field(default_factory=StrainBasis)
    n_gauss: int | None = None
    magnus_order: int | None = None
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
        if self.n_gauss is None:
            self.n_gauss = default_gauss_points(self.basis)
        if not isinstance(self.n_gauss, int | np.integer) or self.n_gauss < 1:
            raise ValueError(f"n_gauss must be an integer >= 1, got {self.n_gauss!r}")
        self.n_gauss = int(self.n_gauss)
        need = min_gauss_points(self.basis)
        if self.n_gauss < need:
            raise ValueError(
                f"n_gauss = {self.n_gauss} is too few for {self.basis.describe()}: a mode with "
                f"{need - 1} coefficients needs at least {need} Gauss points (with as many points "
                "as coefficients the quadrature is exact only for the stiffness and a spurious "
                "stiff mode appears; with fewer the stiffness is singular)"
            )
        if self.magnus_order is None:
            self.magnus_order = 4
        if self.magnus_order not in (2, 4):
            raise ValueError(f"magnus_order must be 2 or 4, got {self.magnus_order!r}")
        if self.magnus_order == 2 and self.basis.max_order > 0:
            warnings.warn(
                f"magnus_order=2 with {self.basis.describe()}: order 2 is exact only for "
                "constant strains and stalls at 0.1-1 % of the rod length in large deflections; "
                "set magnus_order=4 (the default) for this basis",
                UserWarning,
                stacklevel=3,
            )
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


def min_gauss_points(basis: StrainBasis) -> int:
    """Fewest Gauss points a basis accepts: one more than the coefficients of its richest mode.

    With ``n_gauss <= p + 1`` the ``p + 1`` functions of a mode are (almost) interpolated by the
    quadrature: fewer points make the stiffness singular, as many create a spurious stiff mode
    (104,000 rad/s for order 7 with 8 points)."""
    return basis.max_order + 2


def default_gauss_points(basis: StrainBasis) -> int:
    """The default quadrature: 8 points up to order 5, ``2 (p + 1)`` above (Gauss-Legendre with
    ``g`` points integrates polynomials of degree ``2 g - 1`` exactly, so products of two basis
    functions stay well resolved)."""
    return max(8, 2 * (basis.max_order + 1))


@dataclass
class SectionedRod:
    """Several uniform :class:`Rod` sections joined end to end (a multi-section continuum robot).

    Each section has its own length, material, strain basis, quadrature and Magnus order (the
    Magnus order must be the same for all).  Section ``i`` starts where section ``i - 1`` ends,
    with the same frame (the rod is continuous; its strains may jump).  The ``tip_mass`` and
    ``tip_inertia`` of an inner section are a point body at its end (a joint, a spacer disk); the
    last section's are the rod's tip body.  Each section's ``reference_strain`` is its own.
    """

    sections: tuple

    def __post_init__(self):
        secs = tuple(self.sections)
        if len(secs) < 1:
            raise ValueError("a SectionedRod needs at least one section")
        for i, sec in enumerate(secs):
            if not isinstance(sec, Rod):
                raise ValueError(f"sections[{i}] must be a Rod, got {sec!r}")
        orders = {sec.magnus_order for sec in secs}
        if len(orders) > 1:
            raise ValueError(
                f"all sections must use the same magnus_order, got {[s.magnus_order for s in secs]}"
            )
        self.sections = secs

    @property
    def length(self) -> float:
        return float(sum(s.length for s in self.sections))

    @property
    def starts(self) -> np.ndarray:
        """Arc length at which every section starts (m)."""
        return np.concatenate([[0.0], np.cumsum([s.length for s in self.sections])[:-1]])

    @property
    def mass(self) -> float:
        """Mass of the sections and of the inner joint bodies, without the tip body."""
        return float(
            sum(s.mass for s in self.sections) + sum(s.tip_mass for s in self.sections[:-1])
        )

    @property
    def tip_mass(self) -> float:
        return self.sections[-1].tip_mass

    @property
    def magnus_order(self) -> int:
        return self.sections[0].magnus_order

    @property
    def n_strains(self) -> int:
        return int(sum(s.basis.n for s in self.sections))

    def section_at(self, s: float) -> int:
        """Index of the section holding arc length ``s`` (the first one at a joint)."""
        ends = np.cumsum([sec.length for sec in self.sections])
        return int(min(np.searchsorted(ends, s - 1e-12 * self.length), len(self.sections) - 1))
