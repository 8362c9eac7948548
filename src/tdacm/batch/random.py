"""One random stream per world: a counter-based generator (SplitMix64).

Why counter-based: a world's draws must not depend on how many worlds run beside it, on its
index in the batch or on the thread that steps it (the equality the engine is tested for). A
world's stream is a pure function of its seed and a stream number: the ``k``-th draw is
``mix(key + k * GOLDEN)`` with ``key = mix(seed, stream)``, so the state of a world is two
unsigned integers (its key and its counter) in a ``(N, 2)`` ``uint64`` array that any thread,
or one GPU thread per world, advances on its own.

``mix`` is the SplitMix64 finalizer (Steele, Lea and Flood, "Fast splittable pseudorandom
number generators", OOPSLA 2014), which passes BigCrush as a counter-based generator; uniform
doubles take its top 53 bits, normals come from the Box-Muller transform of two uniforms.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_ONE = np.uint64(1)
_TWO_53 = 1.0 / 9007199254740992.0


@njit(cache=True, inline="always")
def _mix(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def stream_state(seeds, stream: int = 0) -> np.ndarray:
    """``(N, 2)`` ``uint64`` states (key, counter) of the worlds of ``seeds`` (non-negative
    integers) on stream ``stream`` (independent streams of one seed: a world's sensors and
    its plant draw from different streams)."""
    seeds = np.asarray(seeds, dtype=np.int64).ravel()
    if np.any(seeds < 0):
        raise ValueError("seeds must be non-negative integers")
    out = np.zeros((seeds.shape[0], 2), np.uint64)
    with np.errstate(over="ignore"):
        for i, s in enumerate(seeds):
            k = _mix_py(np.uint64(s) * _GOLDEN + np.uint64(stream))
            out[i, 0] = _mix_py(k ^ np.uint64(0x5DEECE66D))
    return out


def _mix_py(z):
    z = np.uint64(z)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True)
def uniform(state):
    """The next uniform double in ``[0, 1)`` of the stream ``state`` (2,) (advanced)."""
    state[1] += _ONE
    x = _mix(state[0] + state[1] * _GOLDEN)
    return float(x >> _S11) * _TWO_53


@njit(cache=True)
def normal(state):
    """The next standard normal of the stream ``state`` (2,) (Box-Muller; two uniforms)."""
    u1 = uniform(state)
    u2 = uniform(state)
    return np.sqrt(-2.0 * np.log(1.0 - u1)) * np.cos(2.0 * np.pi * u2)
