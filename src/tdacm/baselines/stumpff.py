"""Stumpff functions: the singularity-free building blocks of constant-curvature kinematics.

``c_k(z) = sum_j (-z)^j / (k + 2 j)!`` (entire functions of ``z = (kappa s)^2``), so that

    c_0 = cos(kappa s),  c_1 = sin(kappa s)/(kappa s),  c_2 = (1 - cos(kappa s))/(kappa s)^2,
    c_3 = (kappa s - sin(kappa s))/(kappa s)^3, ...

They are finite at ``kappa = 0`` (``c_k(0) = 1/k!``) and their derivatives stay in the family,
``c_k'(z) = (k c_{k+2}(z) - c_{k+1}(z)) / 2``, so sympy can differentiate the constant-curvature
kinematics any number of times without ever producing ``kappa`` in a denominator.  The symbolic
classes (:data:`STUMPFF`) carry that rule in ``fdiff``; the numeric implementation
(:func:`stumpff_all`) evaluates the whole family at once: a short series plus the stable
downward recursion ``c_k = 1/k! - z c_{k+2}`` for ``z < 4``, the closed forms ``cos``, ``sin``
plus the upward recursion ``c_{k+2} = (1/k! - c_k) / z`` above (relative error below ~1e-13 for
every ``k <= 9``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import sympy as sp

#: highest index evaluated numerically (the 8-DoF derivation uses up to c_7)
KMAX = 9
_INV_FACT = tuple(1.0 / math.factorial(k) for k in range(KMAX + 3))
_SWITCH = 4.0


def _series(k: int, z: float) -> float:
    term = _INV_FACT[k]
    acc = term
    j = 1
    while True:
        term *= -z / ((k + 2 * j - 1) * (k + 2 * j))
        acc += term
        if abs(term) < 1e-18 * abs(acc) or j > 40:
            return acc
        j += 1


@lru_cache(maxsize=256)
def stumpff_all(z: float) -> tuple:
    """``(c_0(z), ..., c_KMAX(z))`` for ``z >= 0`` (memoized: every generated expression asks
    for several indices at the same few arguments)."""
    c = [0.0] * (KMAX + 1)
    if z < _SWITCH:
        c[KMAX] = _series(KMAX, z)
        c[KMAX - 1] = _series(KMAX - 1, z)
        for k in range(KMAX - 2, -1, -1):
            c[k] = _INV_FACT[k] - z * c[k + 2]
    else:
        th = math.sqrt(z)
        c[0] = math.cos(th)
        c[1] = math.sin(th) / th
        for k in range(0, KMAX - 1):
            c[k + 2] = (_INV_FACT[k] - c[k]) / z
    return tuple(c)


def _make_numeric(k):
    def ck(z):
        return stumpff_all(float(z))[k]

    ck.__name__ = f"stumpff{k}"
    return ck


#: numeric ``c_k`` (scalar), index = k
NUMERIC = tuple(_make_numeric(k) for k in range(KMAX + 1))


def _make_symbolic(k):
    def fdiff(self, argindex=1):
        if argindex != 1:
            raise sp.ArgumentIndexError(self, argindex)
        if k + 2 > KMAX:
            raise ValueError(f"derivative of c_{k} needs c_{k + 2}: raise KMAX")
        z = self.args[0]
        return (k * STUMPFF[k + 2](z) - STUMPFF[k + 1](z)) / 2

    def _eval_evalf(self, prec):
        z = self.args[0].evalf(prec)
        if z.is_Number:
            return sp.Float(stumpff_all(float(z))[k], prec)
        return None

    return type(
        f"stumpff{k}", (sp.Function,), {"nargs": 1, "fdiff": fdiff, "_eval_evalf": _eval_evalf}
    )


#: symbolic ``c_k`` (sympy Function classes), index = k
STUMPFF = tuple(_make_symbolic(k) for k in range(KMAX + 1))
