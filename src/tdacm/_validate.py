"""Input validation shared by every public constructor and entry point.

Errors are ``ValueError`` naming the parameter and the offending value, so a user sees at once
what to fix instead of a NaN three integration steps later.
"""

from __future__ import annotations

import math

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
    got = a.shape
    if len(got) != len(shape):
        raise ValueError(f"{name} must have shape {shape}, got shape {got}")
    for s, d in zip(shape, got, strict=True):
        if s != -1 and s != d:
            raise ValueError(f"{name} must have shape {shape}, got shape {got}")
    # called every control period on small arrays: a finite sum proves every entry finite
    # (an inf or NaN entry makes the sum inf or NaN), so the element-wise test runs only
    # when the sum is not finite (a bad entry, an overflow, or an allowed NaN)
    if not math.isfinite(a.sum()):
        bad = np.isinf(a) if allow_nan else ~np.isfinite(a)
        if bad.any():
            raise ValueError(f"{name} must be finite, got {a!r}")
    return a


def points(name: str, value, dim: int) -> np.ndarray:
    """``(N, dim)`` array; a single point of shape ``(dim,)`` is promoted to ``(1, dim)``."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 1:
        a = a.reshape(1, -1)
    return array(name, a, (-1, dim))


def unit_vector(name: str, value, dim: int = 3) -> np.ndarray:
    """A non-zero ``(dim,)`` direction, returned normalized."""
    v = array(name, value, (dim,))
    norm = float(np.linalg.norm(v))
    if norm < 1e-9:
        raise ValueError(f"{name} must be a non-zero vector")
    return v / norm


# np.allclose(x, y, atol=a) is |x - y| <= a + 1e-5 |y|; the bounds are precomputed because
# transforms are checked every control period (np.allclose costs ~20 us a call)
_EYE3 = np.eye(3)
_ORTHO_TOL = 1e-6 + 1e-5 * _EYE3


def _proper_rotation(r: np.ndarray) -> bool:
    """``r^T r`` within 1e-6 of the identity (as ``np.allclose``) and ``det r >= 0``."""
    if not (np.abs(r.T @ r - _EYE3) <= _ORTHO_TOL).all():
        return False
    # an orthonormal matrix has det +-1: the triple product gives its sign without LAPACK
    (a, b, c), (d, e, f), (g, h, i) = r.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) >= 0.0


def rotation(name: str, value) -> np.ndarray:
    """A 3x3 rotation matrix."""
    r = array(name, value, (3, 3))
    if not _proper_rotation(r):
        raise ValueError(f"{name} must be a rotation matrix")
    return r


def transform(name: str, value) -> np.ndarray:
    """A 4x4 homogeneous transform with an orthonormal rotation block."""
    g = array(name, value, (4, 4))
    r = g[:3, :3]
    w0, w1, w2, w3 = g[3].tolist()
    if not (
        abs(w0) <= 1e-9 and abs(w1) <= 1e-9 and abs(w2) <= 1e-9 and abs(w3 - 1.0) <= 1e-9 + 1e-5
    ):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {g[3]!r}")
    if not _proper_rotation(r):
        raise ValueError(f"{name} must have a proper rotation block, got {r!r}")
    return g


def npz_problem(exc: BaseException) -> str:
    """Why ``numpy.load`` of an ``.npz`` failed, in a user's words (not numpy's: a pickled
    object array's "allow_pickle" advice would tell a user to load an untrusted file
    unsafely)."""
    text = str(exc)
    if isinstance(exc, KeyError):
        # numpy's NpzFile: "NAME is not a file in the archive"
        name = str(exc.args[0]).removesuffix(" is not a file in the archive") if exc.args else ""
        return f"no {name!r} array" if name else "an array is missing"
    if "allow_pickle" in text or "pickle" in text.lower():
        return "it holds Python objects (pickled), not plain arrays; such files are not loaded"
    if isinstance(exc, EOFError) or "zip" in text.lower() or "truncated" in text.lower():
        return "not an .npz archive, or a truncated one"
    return text.splitlines()[0] if text else type(exc).__name__
