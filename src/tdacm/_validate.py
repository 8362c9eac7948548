"""Input validation shared by every public constructor and entry point.

Errors are ``ValueError`` naming the parameter and the offending value, so a user sees at once
what to fix instead of a NaN three integration steps later.
"""

from __future__ import annotations

import numpy as np


def positive(name: str, value) -> float:
    """A finite, strictly positive scalar."""
    v = finite_scalar(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be positive, got {value!r}")
    return v


def nonnegative(name: str, value) -> float:
    """A finite scalar >= 0."""
    v = finite_scalar(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be non-negative, got {value!r}")
    return v


def finite_scalar(name: str, value) -> float:
    """A finite real scalar."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def in_open_interval(name: str, value, lo: float, hi: float) -> float:
    """A finite scalar in ``(lo, hi)``."""
    v = finite_scalar(name, value)
    if not lo < v < hi:
        raise ValueError(f"{name} must lie in ({lo}, {hi}), got {value!r}")
    return v


def positive_int(name: str, value) -> int:
    """An integer >= 1."""
    if isinstance(value, bool) or not float(value).is_integer() or int(value) < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def array(name: str, value, shape: tuple, *, allow_nan: bool = False) -> np.ndarray:
    """A float64 array (a copy) of the given shape (``-1`` matches any length), finite unless
    ``allow_nan`` (infinities are always refused)."""
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a numeric array of shape {shape}, got {value!r}"
        ) from None
    if a.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, a.shape, strict=True)):
        raise ValueError(f"{name} must have shape {shape}, got shape {a.shape}")
    bad = np.isinf(a) if allow_nan else ~np.isfinite(a)
    if np.any(bad):
        raise ValueError(f"{name} must be finite, got {a!r}")
    return a


def points(name: str, value, dim: int) -> np.ndarray:
    """``(N, dim)`` array; a single point of shape ``(dim,)`` is promoted to ``(1, dim)``."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 1:
        a = a.reshape(1, -1)
    return array(name, a, (-1, dim))


def rotation(name: str, value) -> np.ndarray:
    """A 3x3 rotation matrix."""
    r = array(name, value, (3, 3))
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0.0:
        raise ValueError(f"{name} must be a rotation matrix")
    return r


def transform(name: str, value) -> np.ndarray:
    """A 4x4 homogeneous transform with an orthonormal rotation block."""
    g = array(name, value, (4, 4))
    r = g[:3, :3]
    if not np.allclose(g[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {g[3]!r}")
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError(f"{name} must have a proper rotation block, got {r!r}")
    return g
