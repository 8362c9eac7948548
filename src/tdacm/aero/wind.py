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
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.linalg import expm

from .. import _validate as V

FT = 0.3048  # m per foot


class WindParams(NamedTuple):
    """A wind as the record of its compiled step (:func:`wind_velocity`): the sum of the
    steady winds ``steady`` (3,), the 1-cosine gusts ``gusts`` (G, 5: amplitude (3), start,
    duration) and at most one Dryden turbulence (``turbulence``) sampled every ``turb_dt`` s:
    the inertial directions of ``u, v, w`` (``axes`` (3, 3), columns), and per component its
    shaping filter's exact discretization (:class:`DrydenTurbulence`): the transition ``phi``
    (3, 2, 2), the Cholesky factors of the sample covariance ``lq`` and of the stationary
    covariance ``l0`` (3, 2, 2), the output row ``c`` (3, 2) (``u`` has one state: its rows
    and columns beyond the first are zero)."""

    steady: np.ndarray
    gusts: np.ndarray
    turbulence: bool
    turb_dt: float
    axes: np.ndarray
    phi: np.ndarray
    lq: np.ndarray
    c: np.ndarray
    l0: np.ndarray


class WindState(NamedTuple):
    """A wind's state: the turbulence samples taken (``taken`` (1,)) and its filters' states
    ``x`` (5,: ``u``'s one, ``v``'s two, ``w``'s two)."""

    taken: np.ndarray
    x: np.ndarray

    @classmethod
    def initial(cls) -> WindState:
        return cls(np.zeros(1), np.zeros(N_WIND_NORMALS))


#: standard normals a turbulence sample draws (and its initial state): ``u``'s, then ``v``'s
#: two, then ``w``'s two, the order of :class:`DrydenTurbulence`
N_WIND_NORMALS = 5
#: each filter's state dimension and its first entry in :attr:`WindState.x`
_DIMS = (1, 2, 2)


@njit(cache=True)
def wind_start(p, st, normals):
    """The turbulence's initial state from ``normals`` (:data:`N_WIND_NORMALS`,): the
    stationary distribution of its filters (``x_i = L0_i z_i``), no sample taken yet."""
    st.taken[0] = 0.0
    for i in range(N_WIND_NORMALS):
        st.x[i] = 0.0
    if not p.turbulence:
        return
    z = 0
    for f in range(3):
        k = 1 if f == 0 else 2
        for r in range(k):
            acc = 0.0
            for c in range(k):
                acc += p.l0[f, r, c] * normals[z + c]
            st.x[z + r] = acc
        z += k


@njit(cache=True)
def wind_samples_due(p, st, t):
    """The turbulence samples to take to reach time ``t`` (each draws
    :data:`N_WIND_NORMALS` normals); ``ValueError`` if ``t`` is before the last sample."""
    if not p.turbulence:
        return 0
    k = int(math.floor(t / p.turb_dt + 1e-9))
    taken = int(st.taken[0])
    if k < taken:
        raise ValueError("turbulence is sampled forward in time")
    return k - taken


@njit(cache=True)
def _turbulence_step(p, st, normals):
    """One sample of the turbulence: ``x_i <- Phi_i x_i + Lq_i z_i`` (the exact discretization
    of the shaping filters)."""
    z = 0
    for f in range(3):
        k = 1 if f == 0 else 2
        x0 = st.x[z]
        x1 = st.x[z + 1] if k == 2 else 0.0
        for r in range(k):
            a = p.phi[f, r, 0] * x0
            b = p.lq[f, r, 0] * normals[z]
            if k == 2:
                a += p.phi[f, r, 1] * x1
                b += p.lq[f, r, 1] * normals[z + 1]
            st.x[z + r] = a + b
        z += k
    st.taken[0] += 1.0


@njit(cache=True)
def wind_velocity(p, st, t, normals, out):
    """The wind (3,) at time ``t`` into ``out``: steady + gusts + turbulence, the turbulence
    brought to its sample ``floor(t / turb_dt)`` first with one row of ``normals`` (rows, 5)
    per sample (:func:`wind_samples_due` of them; ``ValueError`` if fewer)."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for i in range(3):
        out[i] = out[i] + p.steady[i]
    for g in range(p.gusts.shape[0]):
        x = (t - p.gusts[g, 3]) / p.gusts[g, 4]
        if 0.0 <= x <= 1.0:
            h = 1.0 - math.cos(2.0 * math.pi * x)
            for i in range(3):
                out[i] = out[i] + 0.5 * p.gusts[g, i] * h
    if p.turbulence:
        due = wind_samples_due(p, st, t)
        if due > normals.shape[0]:
            raise ValueError("turbulence: more samples due than rows of normals")
        for row in range(due):
            _turbulence_step(p, st, normals[row])
        # the filters' outputs c_i . x_i (u: one state, v and w: two)
        u_ = p.c[0, 0] * st.x[0]
        v_ = p.c[1, 0] * st.x[1] + p.c[1, 1] * st.x[2]
        w_ = p.c[2, 0] * st.x[3] + p.c[2, 1] * st.x[4]
        for i in range(3):
            out[i] = out[i] + (p.axes[i, 0] * u_ + p.axes[i, 1] * v_ + p.axes[i, 2] * w_)


class Wind:
    """Base class: ``velocity(t, p=None)`` the wind (3,) at time ``t`` and point ``p``; winds add
    with ``+``. A wind is the record :meth:`params` (:class:`WindParams`) of the compiled
    :func:`wind_velocity` with its state; a turbulence draws its normals from its own seeded
    generator (:meth:`normals`)."""

    def parts(self) -> tuple:
        """The winds this one sums (itself for a single wind)."""
        return (self,)

    def params(self) -> WindParams:
        """The record of the sum of :meth:`parts` (:func:`wind_params`)."""
        return wind_params(self.parts())

    def turbulence(self):
        """The :class:`DrydenTurbulence` among :meth:`parts`, or ``None``."""
        found = [w for w in self.parts() if isinstance(w, DrydenTurbulence)]
        return found[0] if found else None

    def velocity(self, t: float, p=None) -> np.ndarray:
        """The wind at time ``t`` (:func:`wind_velocity`; the turbulence asked at
        non-decreasing times)."""
        if getattr(self, "state", None) is None:
            self.reset()
        rec, st = self.record, self.state
        due = wind_samples_due(rec, st, float(t))
        out = np.empty(3)
        wind_velocity(rec, st, float(t), self.normals(due), out)
        return out

    def normals(self, samples: int) -> np.ndarray:
        """``(samples, 5)`` standard normals of the turbulence's next samples (from its
        generator, in its order; none without turbulence)."""
        turb = self.turbulence()
        if turb is None or samples <= 0:
            return np.zeros((0, N_WIND_NORMALS))
        return turb.rng.standard_normal((samples, N_WIND_NORMALS))

    def __add__(self, other: Wind) -> Wind:
        return _Sum((self, other))

    def reset(self) -> None:
        """Restart a random wind's sequence (same seed, same samples): its generator and its
        filters' initial state (:func:`wind_start`): :attr:`record` and :attr:`state`, the
        record and the state :func:`wind_velocity` advances (a plant integrating this wind
        advances the same state)."""
        #: the wind's record (:func:`wind_params`)
        self.record = self.params()
        #: the wind's state (:class:`WindState`)
        self.state = WindState.initial()
        turb = self.turbulence()
        if turb is not None:
            turb.rng = np.random.default_rng(turb.seed)
            wind_start(self.record, self.state, turb.rng.standard_normal(N_WIND_NORMALS))


def wind_params(parts) -> WindParams:
    """The :class:`WindParams` of the sum of the winds ``parts`` (steady winds, gusts and at
    most one turbulence; ``ValueError`` for a second one)."""
    steady = np.zeros(3)
    gusts = []
    turb = None
    for w in parts:
        if isinstance(w, SteadyWind):
            steady = steady + w.value
        elif isinstance(w, Gust):
            gusts.append([*w.amplitude, w.start, w.duration])
        elif isinstance(w, DrydenTurbulence):
            if turb is not None:
                raise ValueError("wind: at most one Dryden turbulence in a sum")
            turb = w
        else:
            raise ValueError(f"wind: {type(w).__name__} is not a steady wind, gust or turbulence")
    phi, lq, l0 = np.zeros((3, 2, 2)), np.zeros((3, 2, 2)), np.zeros((3, 2, 2))
    c = np.zeros((3, 2))
    axes, dt = np.eye(3), 1.0
    if turb is not None:
        axes, dt = turb.axes, turb.dt
        for i, (f_phi, f_lq, f_c, f_p0) in enumerate(turb._filters):
            k = f_phi.shape[0]
            phi[i, :k, :k] = f_phi
            lq[i, :k, :k] = f_lq
            l0[i, :k, :k] = np.linalg.cholesky(f_p0)
            c[i, :k] = f_c
    g = np.array(gusts, float).reshape(-1, 5)
    return WindParams(steady, np.ascontiguousarray(g), turb is not None, float(dt),
                      np.ascontiguousarray(axes, float), phi, lq, c, l0)  # fmt: skip


class _Sum(Wind):
    def __init__(self, parts):
        self._parts = tuple(parts)

    def parts(self) -> tuple:
        return tuple(p for w in self._parts for p in w.parts())


class SteadyWind(Wind):
    """A constant wind ``velocity`` (3,) (m/s, inertial frame)."""

    def __init__(self, velocity=(0.0, 0.0, 0.0)):
        self.value = V.array("velocity", velocity, (3,))


class Gust(Wind):
    """A 1-cosine discrete gust (MIL-F-8785C, sec. 3.7.4), in time for a hovering vehicle:
    ``amplitude/2 (1 - cos(2 pi (t - start) / duration))`` during ``[start, start + duration]``."""

    def __init__(self, amplitude, start: float, duration: float):
        self.amplitude = V.array("amplitude", amplitude, (3,))
        self.start = V.finite_scalar("start", start)
        self.duration = V.positive("duration", duration)


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
        self.rng = np.random.default_rng(self.seed)

    def sample(self, n: int) -> np.ndarray:
        """The next ``n`` samples (n, 3) in the ``u, v, w`` components (not rotated)."""
        if getattr(self, "state", None) is None:
            self.reset()
        out = np.empty((n, 3))
        for k in range(n):
            t = (int(self.state.taken[0]) + 1) * self.dt
            out[k] = self.axes.T @ self.velocity(t)
        return out


def _stationary(phi, q):
    """Stationary covariance of ``x+ = Phi x + w``, ``w ~ N(0, Q)``."""
    n = phi.shape[0]
    lhs = np.eye(n * n) - np.kron(phi, phi)
    p = np.linalg.solve(lhs, q.ravel()).reshape(n, n)
    return 0.5 * (p + p.T) + 1e-300 * np.eye(n)
