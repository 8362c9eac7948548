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


def array(name: str, value, shape: tuple) -> np.ndarray:
    """A finite float64 array of the given shape (``-1`` matches any length)."""
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a numeric array of shape {shape}, got {value!r}"
        ) from None
    if a.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, a.shape, strict=True)):
        raise ValueError(f"{name} must have shape {shape}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a!r}")
    return a


def transform(name: str, value) -> np.ndarray:
    """A 4x4 homogeneous transform with an orthonormal rotation block."""
    g = array(name, value, (4, 4))
    r = g[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-8) or np.linalg.det(r) < 0:
        raise ValueError(f"{name} must have a proper rotation block, got {r!r}")
    if not np.allclose(g[3], [0, 0, 0, 1]):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {g[3]!r}")
    return g
