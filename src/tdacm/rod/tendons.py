"""Tendon routing and its generalized actuation ``B_s(q)`` (paper eq. (13)).

Tendon ``i`` runs at the offset ``d_i(s)`` in the cross-section plane (local y-z).  Its tangent
in the local frame is ``t = (k x d + u + d') / |k x d + u + d'|`` and its length derivative is
``dl_i/dq = int_0^L B_q^T [d~ t; t] ds``.  A tension ``T_i >= 0`` (tendons only pull) does the
generalized force ``-T_i dl_i/dq``, so the columns of ``B_s`` are ``-dl_i/dq`` (the distributed
actuation wrench ``B_a = -[d~ t; t]``).  Pulling a tendon bends the rod toward it: with no
gravity and a straight parallel tendon at offset ``r``, the curvature is ``T r / (E I)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from .. import paper_values as PV


@dataclass
class Tendons:
    """A set of tendons.

    Parameters
    ----------
    offsets : (n_a, 3) constant offsets ``d_i`` in the section frame (x component must be 0), for
        parallel routing; ignored when ``offset_function`` is given.
    offset_function : optional ``f(X) -> (n_a, 3)`` for non-parallel routing, ``X = s/L``; its
        derivative is taken by central differences unless ``offset_derivative`` is given
        (``d/dX``; the model divides by ``L``).
    max_tension : upper bound used by allocation (N), > 0
    ends : optional (n_a,) arc lengths (m) where each tendon is anchored; ``None`` (or an entry
        ``None``/``inf``) means at the tip.  A tendon runs from the rod base to its end and acts
        only there (its length and ``B_s`` integrate over ``[0, end]``); on a
        :class:`~tdacm.rod.SectionedRod` it is routed through every section it crosses.
    """

    offsets: np.ndarray | None = None
    offset_function: Callable | None = None
    offset_derivative: Callable | None = None
    max_tension: float = PV.TENDON_MAX_TENSION
    ends: np.ndarray | None = None

    def __post_init__(self):
        if self.offset_function is None:
            if self.offsets is None:
                raise ValueError("Tendons need offsets or an offset_function")
            off = V.array("offsets", self.offsets, (-1, 3))
            if off.shape[0] < 1:
                raise ValueError("offsets must hold at least one tendon")
            if np.any(np.abs(off[:, 0]) > 1e-12):
                raise ValueError(
                    f"tendon offsets must lie in the section plane (x = 0), got {off!r}"
                )
            self.offsets = off
        self.max_tension = V.positive("max_tension", self.max_tension)
        if self.ends is not None:
            raw = [
                np.inf if e is None else e
                for e in np.atleast_1d(np.asarray(self.ends, dtype=object))
            ]
            ends = np.array(
                [
                    V.positive(f"ends[{i}]", e) if np.isfinite(float(e)) else np.inf
                    for i, e in enumerate(raw)
                ]
            )
            if ends.shape != (self.n,):
                raise ValueError(
                    f"ends must hold one arc length per tendon ({self.n}), got {self.ends!r}"
                )
            self.ends = ends

    def end_lengths(self, length: float) -> np.ndarray:
        """Anchor arc length of every tendon on a rod of ``length`` (m); ``ValueError`` beyond it."""
        if self.ends is None:
            return np.full(self.n, float(length))
        ends = np.where(np.isinf(self.ends), length, self.ends)
        if np.any(ends > length * (1 + 1e-12)):
            raise ValueError(f"tendon ends {self.ends.tolist()} lie beyond the rod length {length}")
        return np.minimum(ends, length)

    @classmethod
    def parallel(
        cls,
        radius: float = PV.TENDON_RADIUS,
        count: int = PV.TENDON_COUNT,
        max_tension: float = PV.TENDON_MAX_TENSION,
        ends=None,
    ) -> Tendons:
        """``count`` parallel tendons evenly spaced at ``radius``; the first on +y.

        With ``count = 4`` they form two antagonistic pairs: (+y, -y) and (+z, -z), i.e. tendons
        0 and 2 bend about z, tendons 1 and 3 bend about y.
        """
        radius = V.positive("radius", radius)
        if count < 1:
            raise ValueError(f"count must be >= 1, got {count!r}")
        ang = 2 * np.pi * np.arange(count) / count
        off = np.column_stack([np.zeros(count), radius * np.cos(ang), radius * np.sin(ang)])
        off[np.abs(off) < 1e-15] = 0.0
        return cls(offsets=off, max_tension=max_tension, ends=ends)

    @property
    def n(self) -> int:
        if self.offset_function is not None:
            return int(np.asarray(self.offset_function(0.0)).shape[0])
        return int(self.offsets.shape[0])

    def at(self, xs: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
        """Offsets ``d`` and ``d' = dd/ds`` at normalized positions ``xs``: (len(xs), n_a, 3)."""
        xs = np.atleast_1d(np.asarray(xs, dtype=float))
        if self.offset_function is None:
            d = np.broadcast_to(self.offsets, (xs.size, *self.offsets.shape)).copy()
            return d, np.zeros_like(d)
        d = np.array([self.offset_function(x) for x in xs], dtype=float)
        if self.offset_derivative is not None:
            dd = np.array([self.offset_derivative(x) for x in xs], dtype=float)
        else:
            h = 1e-6
            dd = np.array(
                [
                    (
                        np.asarray(self.offset_function(min(x + h, 1.0)))
                        - np.asarray(self.offset_function(max(x - h, 0.0)))
                    )
                    / (min(x + h, 1.0) - max(x - h, 0.0))
                    for x in xs
                ]
            )
        return d, dd / length
