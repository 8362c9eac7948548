"""Strain bases ``B_q(X)`` of the geometric variable-strain (GVS) rod (paper, eq. (8)).

The strain twist of the rod is ``xi(X) = xi*(X) + B_q(X) q_s`` with ``X = s / L`` in ``[0, 1]``.
Each of the six strain modes ``[k1, k2, k3, u1, u2, u3]`` (torsion, two bendings, elongation, two
shears) may be active with its own polynomial order; an active mode of order ``p`` contributes
``p + 1`` columns ``phi_j(X)``, ``j = 0..p`` (monomials ``X^j`` or shifted Legendre polynomials
``P_j(2X - 1)``).  The columns are ordered mode by mode, lowest order first, so ``q_s`` has the
units of the strains (1/m for curvatures, - for stretch/shear).

The paper's rod is ``StrainBasis.bending(order=0)``: two constant bending curvatures, ``n_s = 2``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import legendre

#: Highest polynomial order accepted for ``kind="monomial"`` (see :class:`StrainBasis`).
MAX_MONOMIAL_ORDER = 6

MODE_NAMES = ("torsion", "bending_y", "bending_z", "elongation", "shear_y", "shear_z")


@dataclass(frozen=True)
class StrainBasis:
    """Which strain modes are active and the polynomial order of each.

    Parameters
    ----------
    orders : six entries, one per mode ``[k1, k2, k3, u1, u2, u3]``; ``None`` (or a negative
        number) means the mode is inactive (held at its reference value), ``p >= 0`` means a
        polynomial of order ``p``.
    kind : ``"legendre"`` (default, well conditioned) or ``"monomial"`` (refused above order
        :data:`MAX_MONOMIAL_ORDER`: its stiffness becomes ill-conditioned).
    """

    orders: tuple = (None, 0, 0, None, None, None)
    kind: str = "legendre"
    _columns: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        orders = tuple(self.orders)
        if len(orders) != 6:
            raise ValueError(f"orders must have 6 entries (one per strain mode), got {orders!r}")
        clean = []
        for name, p in zip(MODE_NAMES, orders, strict=True):
            if p is None or (isinstance(p, int | np.integer) and p < 0):
                clean.append(None)
            elif isinstance(p, int | np.integer):
                clean.append(int(p))
            else:
                raise ValueError(f"order of mode {name} must be an int or None, got {p!r}")
        if self.kind not in ("legendre", "monomial"):
            raise ValueError(f"kind must be 'legendre' or 'monomial', got {self.kind!r}")
        if all(p is None for p in clean):
            raise ValueError("a strain basis needs at least one active mode")
        if self.kind == "monomial" and max(p for p in clean if p is not None) > MAX_MONOMIAL_ORDER:
            raise ValueError(
                f"monomial bases above order {MAX_MONOMIAL_ORDER} are refused: their stiffness "
                "matrix is ill-conditioned (condition number 1.5e10 at order 7) and statics fail "
                "to converge; kind='legendre' spans the same polynomials and is well conditioned"
            )
        object.__setattr__(self, "orders", tuple(clean))
        cols = tuple((m, j) for m, p in enumerate(clean) if p is not None for j in range(p + 1))
        object.__setattr__(self, "_columns", cols)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def bending(cls, order: int = 0, kind: str = "legendre") -> StrainBasis:
        """Both bending curvatures with the same order (the paper's rod: ``order=0``)."""
        return cls((None, order, order, None, None, None), kind)

    @classmethod
    def from_modes(cls, modes: dict, kind: str = "legendre") -> StrainBasis:
        """From ``{"bending_y": 2, "torsion": 1, ...}`` (names in :data:`MODE_NAMES`)."""
        orders = [None] * 6
        for name, p in modes.items():
            if name not in MODE_NAMES:
                raise ValueError(f"unknown strain mode {name!r}; choose from {MODE_NAMES}")
            orders[MODE_NAMES.index(name)] = p
        return cls(tuple(orders), kind)

    @classmethod
    def full(cls, order: int, kind: str = "legendre") -> StrainBasis:
        """All six modes with the same order (a shearable, extensible Cosserat rod)."""
        return cls((order,) * 6, kind)

    # ------------------------------------------------------------------ evaluation
    @property
    def n(self) -> int:
        """Number of strain coordinates ``n_s``."""
        return len(self._columns)

    @property
    def max_order(self) -> int:
        """Highest polynomial order of the active modes."""
        return max(p for p in self.orders if p is not None)

    @property
    def stiff(self) -> bool:
        """True when the basis has torsion, elongation or shear: modes of thousands of rad/s
        (or millions, for shear) that an explicit integrator must resolve."""
        return any(self.orders[m] is not None for m in (0, 3, 4, 5))

    @property
    def active_modes(self) -> tuple:
        return tuple(MODE_NAMES[m] for m, p in enumerate(self.orders) if p is not None)

    def functions(self, x: np.ndarray, order: int) -> np.ndarray:
        """Values ``phi_j(X)``, ``j = 0..order``, shape ``(order + 1, len(X))``."""
        x = np.atleast_1d(np.asarray(x, dtype=float))
        if self.kind == "monomial":
            return np.vstack([x**j for j in range(order + 1)])
        return np.vstack(
            [legendre.legval(2.0 * x - 1.0, np.eye(order + 1)[j]) for j in range(order + 1)]
        )

    def __call__(self, x) -> np.ndarray:
        """``B_q(X)`` at normalized arc length(s) ``X``: shape ``(6, n_s)`` or ``(len(X), 6, n_s)``."""
        xs = np.asarray(x, dtype=float)
        scalar = xs.ndim == 0
        xs = np.atleast_1d(xs)
        if np.any(~np.isfinite(xs)) or np.any(xs < -1e-12) or np.any(xs > 1 + 1e-12):
            raise ValueError(f"normalized arc length X must lie in [0, 1], got {x!r}")
        out = np.zeros((xs.size, 6, self.n))
        col = 0
        for m, p in enumerate(self.orders):
            if p is None:
                continue
            out[:, m, col : col + p + 1] = self.functions(xs, p).T
            col += p + 1
        return out[0] if scalar else out

    def describe(self) -> str:
        parts = [f"{MODE_NAMES[m]}(order {p})" for m, p in enumerate(self.orders) if p is not None]
        return f"{self.kind} basis, n_s = {self.n}: " + ", ".join(parts)
