"""Cubic joint-space trajectory with zero end velocities (paper, "Smooth Joint Trajectory
Tracking"): ``q_i(t) = sum_j a_ij t^j`` with ``q(t0) = q0``, ``q(tf) = qf``,
``qdot(t0) = qdot(tf) = 0``, i.e. ``q(t) = q0 + (qf - q0)(3 tau^2 - 2 tau^3)``,
``tau = (t - t0)/(tf - t0)``; held at ``qf`` after ``tf``."""

from __future__ import annotations

import numpy as np


class CubicTrajectory:
    """Cubic from ``q0`` at ``t0`` to ``qf`` at ``tf`` (vectors of equal shape)."""

    def __init__(self, q0, qf, t0: float, tf: float):
        self.q0 = np.atleast_1d(np.asarray(q0, dtype=float)).copy()
        self.qf = np.atleast_1d(np.asarray(qf, dtype=float)).copy()
        if self.q0.shape != self.qf.shape:
            raise ValueError(
                f"q0 and qf must have the same shape, got {self.q0.shape}, {self.qf.shape}"
            )
        if not (np.all(np.isfinite(self.q0)) and np.all(np.isfinite(self.qf))):
            raise ValueError("q0 and qf must be finite")
        self.t0, self.tf = float(t0), float(tf)
        if not self.tf > self.t0:
            raise ValueError(f"tf must be after t0, got t0={t0!r}, tf={tf!r}")
        h = self.tf - self.t0
        d = self.qf - self.q0
        # coefficients a_ij of sum_j a_ij (t - t0)^j
        self.coefficients = np.stack(
            (self.q0, np.zeros_like(d), 3 * d / h**2, -2 * d / h**3), axis=1
        )

    @classmethod
    def with_speed(cls, q0, qf, t0: float, max_speed: float, min_duration: float = 0.5):
        """Duration chosen so that the peak speed ``1.5 |dq| / T`` stays below ``max_speed``."""
        d = float(np.max(np.abs(np.asarray(qf, float) - np.asarray(q0, float))))
        return cls(q0, qf, t0, t0 + max(min_duration, 1.5 * d / float(max_speed)))

    @property
    def duration(self) -> float:
        return self.tf - self.t0

    def __call__(self, t: float):
        """``(q, qdot, qddot)`` at time ``t`` (clamped to ``[t0, tf]``)."""
        h = self.tf - self.t0
        tt = min(max(float(t) - self.t0, 0.0), h)
        a = self.coefficients
        q = a[:, 0] + a[:, 2] * tt**2 + a[:, 3] * tt**3
        if float(t) >= self.tf or float(t) < self.t0:
            z = np.zeros_like(q)
            return q, z, z.copy()
        qd = 2 * a[:, 2] * tt + 3 * a[:, 3] * tt**2
        qdd = 2 * a[:, 2] + 6 * a[:, 3] * tt
        return q, qd, qdd
