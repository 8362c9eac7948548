"""``np.linalg.solve`` for the small float64 systems of the control period.

``np.linalg.solve`` spends most of its ~8 us on a 6 x 6 system in generic argument handling
(array wrapping, dtype promotion, stacking checks); :func:`solve` calls the same LAPACK
gufunc under the same error state, so the results are bit-identical and a singular matrix
still raises ``LinAlgError("Singular matrix")``. Anything but a float64 square matrix and a
float64 ``(M,)`` or ``(M, K)`` right-hand side goes to ``np.linalg.solve`` unchanged.
"""

from __future__ import annotations

import numpy as np

try:  # numpy's private gufuncs (numpy >= 2); np.linalg.solve is the fallback
    from numpy.linalg import _umath_linalg as _ul

    _SOLVE1, _SOLVE = _ul.solve1, _ul.solve
except (ImportError, AttributeError):  # pragma: no cover
    _SOLVE1 = _SOLVE = None


def _singular(err, flag):
    raise np.linalg.LinAlgError("Singular matrix")


def solve(a, b) -> np.ndarray:
    """``np.linalg.solve(a, b)`` (same LAPACK call, same errors) with less overhead."""
    if (
        _SOLVE is None
        or type(a) is not np.ndarray
        or type(b) is not np.ndarray
        or a.dtype != np.float64
        or b.dtype != np.float64
        or a.ndim != 2
        or a.shape[0] != a.shape[1]
        or not 1 <= b.ndim <= 2
        or b.shape[0] != a.shape[0]
    ):
        return np.linalg.solve(a, b)
    with np.errstate(
        call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"
    ):
        return (_SOLVE1 if b.ndim == 1 else _SOLVE)(a, b, signature="dd->d")
