"""Wind: a steady wind, 1-cosine gusts and Dryden turbulence, each giving the wind velocity
(inertial frame, m/s, z up) at a time and a point.

The wind is uniform over the vehicle (the arm is 1 m long; the low-altitude turbulence scales
are the height above ground and more), so the point is accepted for the interface and ignored.

Dryden turbulence (MIL-F-8785C, sec. 3.7.2; MIL-HDBK-1797, low-altitude form, h < 1000 ft):
one-sided spectra in temporal frequency ``omega`` (rad/s) for a vehicle at airspeed ``V``
through frozen turbulence (for a hovering drone, the mean wind carries the turbulence past it),

    Phi_u(omega) = sigma_u^2 (2 L_u / (pi V)) / (1 + (L_u omega / V)^2)
    Phi_v(omega) = sigma_v^2 (L_v / (pi V)) (1 + 3 (L_v omega / V)^2) / (1 + (L_v omega / V)^2)^2

(``Phi_w`` as ``Phi_v`` with ``L_w``, ``sigma_w``; each integrates to ``sigma^2``), with, for the
height ``h`` in feet, ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2``,
``sigma_w = 0.1 W_20`` and ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4``
(``W_20`` the wind speed at 20 ft).  ``u`` is along the mean wind (body x when there is none),
``w`` vertical.  The components are white noise through the shaping filters
``H_u = sigma_u sqrt(2 L_u / V) / (1 + (L_u / V) s)`` and
``H_v = sigma_v sqrt(L_v / V) (1 + sqrt(3) (L_v / V) s) / (1 + (L_v / V) s)^2``
(``|H|^2 = pi Phi``), sampled exactly: each step of ``dt`` draws the discrete-time transition and
covariance of the filter state (Van Loan's matrix exponential), so the samples have the
filter's exact statistics for any ``dt``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from .. import _validate as V

FT = 0.3048  # m per foot


class Wind:
    """Base class: ``velocity(t, p=None)`` the wind (3,) at time ``t`` and point ``p``; winds add
    with ``+``."""

    def velocity(self, t: float, p=None) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def __add__(self, other: Wind) -> Wind:
        return _Sum((self, other))

    def reset(self) -> None:
        """Restart a random wind's sequence (same seed, same samples); nothing for the others."""


class _Sum(Wind):
    def __init__(self, parts):
        self.parts = tuple(parts)

    def reset(self) -> None:
        for w in self.parts:
            w.reset()

    def velocity(self, t, p=None):
        return sum((w.velocity(t, p) for w in self.parts), np.zeros(3))


class SteadyWind(Wind):
    """A constant wind ``velocity`` (3,) (m/s, inertial frame)."""

    def __init__(self, velocity=(0.0, 0.0, 0.0)):
        self.value = V.array("velocity", velocity, (3,))

    def velocity(self, t, p=None):
        return self.value.copy()


class Gust(Wind):
    """A 1-cosine discrete gust (MIL-F-8785C, sec. 3.7.4), in time for a hovering vehicle:
    ``amplitude/2 (1 - cos(2 pi (t - start) / duration))`` during ``[start, start + duration]``."""

    def __init__(self, amplitude, start: float, duration: float):
        self.amplitude = V.array("amplitude", amplitude, (3,))
        self.start = V.finite_scalar("start", start)
        self.duration = V.positive("duration", duration)

    def velocity(self, t, p=None):
        x = (t - self.start) / self.duration
        if not 0.0 <= x <= 1.0:
            return np.zeros(3)
        return 0.5 * self.amplitude * (1.0 - math.cos(2.0 * math.pi * x))


def low_altitude_scales(height: float, wind20: float) -> tuple[np.ndarray, np.ndarray]:
    """MIL-F-8785C low-altitude Dryden parameters: ``(sigma_uvw (3,), L_uvw (3,) in m)`` at
    ``height`` (m above ground, clamped to the spec's 10 ft floor) for a wind ``wind20`` (m/s)
    at 20 ft."""
    h = max(V.positive("height", height) / FT, 10.0)
    if h >= 1000.0:
        raise ValueError(
            f"height must be below 1000 ft (304.8 m) for the low-altitude form, got {height!r}"
        )
    c = 0.177 + 0.000823 * h
    sw = 0.1 * V.nonnegative("wind20", wind20)
    su = sw / c**0.4
    lu = h / c**1.2 * FT
    return np.array([su, su, sw]), np.array([lu, lu, h * FT])


def dryden_psd(omega, sigma: float, scale: float, airspeed: float, longitudinal: bool):
    """One-sided Dryden PSD (module docstring) at ``omega`` (rad/s); ``longitudinal`` for ``u``."""
    x = scale * np.asarray(omega, float) / airspeed
    if longitudinal:
        return sigma**2 * 2.0 * scale / (math.pi * airspeed) / (1.0 + x * x)
    return sigma**2 * scale / (math.pi * airspeed) * (1.0 + 3.0 * x * x) / (1.0 + x * x) ** 2


def _filter(sigma, scale, airspeed, longitudinal):
    """State space ``(A, B, C)`` of the shaping filter, driven by unit white noise."""
    tau = scale / airspeed
    if longitudinal:
        k = sigma * math.sqrt(2.0 * tau)
        return np.array([[-1.0 / tau]]), np.array([1.0]), np.array([k / tau])
    k = sigma * math.sqrt(tau)
    a = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]])
    return a, np.array([0.0, 1.0]), np.array([k / tau**2, k * math.sqrt(3.0) / tau])


def _discretize(a, b, dt):
    """Exact transition ``Phi = e^{A dt}`` and noise covariance ``int_0^dt e^{At} b b^T e^{A^T t}``
    (Van Loan 1978)."""
    n = a.shape[0]
    big = np.zeros((2 * n, 2 * n))
    big[:n, :n] = -a
    big[:n, n:] = np.outer(b, b)
    big[n:, n:] = a.T
    e = expm(big * dt)
    phi = e[n:, n:].T
    q = phi @ e[:n, n:]
    return phi, 0.5 * (q + q.T)


class DrydenTurbulence(Wind):
    """Dryden turbulence, seeded, sampled every ``dt`` (held in between).

    sigma, scale : (3,) intensities (m/s) and scale lengths (m) of ``u, v, w``
        (:func:`low_altitude_scales` gives the MIL-F-8785C values)
    airspeed : speed (m/s) at which the frozen turbulence passes the vehicle (> 0; the mean
        wind speed for a hovering drone)
    direction : horizontal direction (x, y) of ``u``, the mean wind's (default inertial +x)
    seed : of the generator; ``velocity`` must be asked at non-decreasing times (a call at an
        earlier time raises)
    """

    def __init__(
        self, sigma, scale, airspeed: float, dt: float, seed: int = 0, direction=(1.0, 0.0)
    ):
        self.sigma = V.array("sigma", sigma, (3,))
        self.scale = V.array("scale", scale, (3,))
        if np.any(self.sigma < 0) or np.any(self.scale <= 0):
            raise ValueError(f"sigma must be >= 0 and scale > 0, got {sigma!r}, {scale!r}")
        self.airspeed = V.positive("airspeed", airspeed)
        self.dt = V.positive("dt", dt)
        d = V.array("direction", direction, (2,))
        if np.linalg.norm(d) == 0:
            raise ValueError("direction must be non-zero")
        d = d / np.linalg.norm(d)
        # columns: inertial directions of u (along the wind), v (left of it), w (up)
        self.axes = np.array([[d[0], -d[1], 0.0], [d[1], d[0], 0.0], [0.0, 0.0, 1.0]])
        self.seed = int(seed)
        self._filters = []
        for i in range(3):
            a, b, c = _filter(self.sigma[i], self.scale[i], self.airspeed, i == 0)
            phi, q = _discretize(a, b, self.dt)
            # stationary initial state: the solution of P = Phi P Phi^T + Q
            p0 = _stationary(phi, q)
            self._filters.append((phi, np.linalg.cholesky(q + 1e-300 * np.eye(len(b))), c, p0))
        self.reset()

    def reset(self) -> None:
        """Restart the sequence (same seed, same samples)."""
        self._rng = np.random.default_rng(self.seed)
        self._x = [
            np.linalg.cholesky(p0) @ self._rng.standard_normal(p0.shape[0])
            for *_, p0 in self._filters
        ]
        self._k = 0
        self._value = self._output()

    def _output(self):
        uvw = np.array([c @ x for (_, _, c, _), x in zip(self._filters, self._x, strict=True)])
        return self.axes @ uvw

    def _step(self):
        for i, (phi, lq, _, _) in enumerate(self._filters):
            self._x[i] = phi @ self._x[i] + lq @ self._rng.standard_normal(lq.shape[0])
        self._k += 1
        self._value = self._output()

    def sample(self, n: int) -> np.ndarray:
        """The next ``n`` samples (n, 3) in the ``u, v, w`` components (not rotated)."""
        out = np.empty((n, 3))
        for k in range(n):
            self._step()
            out[k] = self.axes.T @ self._value
        return out

    def velocity(self, t, p=None):
        k = int(math.floor(t / self.dt + 1e-9))
        if k < self._k:
            raise ValueError(
                f"DrydenTurbulence is sampled forward in time: t = {t!r} is before the last sample; call reset()"
            )
        while self._k < k:
            self._step()
        return self._value.copy()


def _stationary(phi, q):
    """Stationary covariance of ``x+ = Phi x + w``, ``w ~ N(0, Q)``."""
    n = phi.shape[0]
    lhs = np.eye(n * n) - np.kron(phi, phi)
    p = np.linalg.solve(lhs, q.ravel()).reshape(n, n)
    return 0.5 * (p + p.T) + 1e-300 * np.eye(n)
