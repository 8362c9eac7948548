"""Adaptive sliding-mode controller (paper, "Model-Based Control", eqs. S2-S10).

    qdot_r = qdot_d - beta e,           e = q - q_d
    s_q    = qdot - qdot_r = edot + beta e
    tau_a  = M_hat qdd_r + (C_hat + D_hat) qdot_r + K_hat - A_d edot - A_p e + Delta_hat
    d Delta_hat / dt = -A_a s_q

with the Lyapunov function of the stability analysis

    V = 1/2 s_q^T M_hat s_q + 1/2 e^T (beta A_d + A_p) e + 1/2 Delta_tilde^T A_a^-1 Delta_tilde

and the gain condition ``A_p > A_d beta / (2 eps)`` for some ``eps`` in (0, 1)
(:func:`check_gains`; violated gains raise :class:`GainConditionError`). ``beta`` is diagonal;
``A_d, A_p, A_a`` are symmetric positive definite matrices (given as vectors of diagonals
or full matrices). ``Delta_tilde = Delta_hat - Delta`` needs the
true uncertainty; :meth:`AdaptiveController.lyapunov` returns the part without it unless
``delta_true`` is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .model import EstimatedModel


class GainConditionError(ValueError):
    """The gains violate the paper's stability condition ``A_p > A_d beta / (2 eps)``."""


def _diag(name: str, value, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise ValueError(
            f"gain {name} must be a scalar or a vector of {n} diagonal entries, got shape {a.shape}"
        )
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ValueError(f"gain {name} must be positive definite (positive diagonal), got {a!r}")
    return a


def _matrix(name: str, value, n: int) -> np.ndarray:
    """A positive definite gain: scalar, diagonal vector or symmetric (n, n) matrix."""
    a = np.asarray(value, dtype=float)
    if a.ndim < 2:
        return np.diag(_diag(name, a, n))
    if a.shape != (n, n) or not np.all(np.isfinite(a)) or not np.allclose(a, a.T, atol=1e-12):
        raise ValueError(f"gain {name} must be a symmetric ({n}, {n}) matrix")
    if np.linalg.eigvalsh(a).min() <= 0:
        raise ValueError(f"gain {name} must be positive definite")
    return a


@dataclass
class AdaptiveGains:
    """Gains ``beta`` (diagonal, a vector), ``A_d, A_p, A_a`` (positive definite: vectors of
    diagonals or symmetric matrices) and the Young constant ``eps`` in (0, 1)."""

    beta: np.ndarray
    A_d: np.ndarray
    A_p: np.ndarray
    A_a: np.ndarray
    eps: float = 0.9
    n: int = field(init=False)

    def __post_init__(self):
        n = int(np.size(self.beta)) if np.ndim(self.beta) else int(np.shape(self.A_d)[0])
        self.beta = _diag("beta", self.beta, n)
        for name in ("A_d", "A_p", "A_a"):
            setattr(self, name, _matrix(name, getattr(self, name), n))
        self.n = n
        check_gains(self)

    @classmethod
    def from_rates(
        cls, mass, beta, damping_rate, adaptation_rate, p_factor=1.0, eps=0.9
    ) -> AdaptiveGains:
        """Gains shaped by an inertia: ``mass`` is a vector (diagonal) or an ``(n, n)`` inertia
        matrix ``M0``. With ``S = diag(sqrt(damping_rate))``: ``A_d = S M0 S``,
        ``A_p = p_factor * sym(A_d beta)``, ``A_a = S_a M0 S_a`` (``S_a`` from
        ``adaptation_rate``). With a matrix ``M0`` the closed-loop sliding dynamics
        ``M s' = -A_d s`` are decoupled (rate ``damping_rate`` per mode when ``M ~ M0`` and the
        rates are equal within coupled blocks). ``p_factor = 1`` satisfies the condition for
        every ``eps > 1/2`` when ``beta`` is uniform within coupled blocks."""
        m = np.asarray(mass, dtype=float)
        m0 = np.diag(m) if m.ndim == 1 else m
        n = m0.shape[0]
        b = np.broadcast_to(np.asarray(beta, float), (n,)).copy()
        sd = np.sqrt(np.broadcast_to(np.asarray(damping_rate, float), (n,)))
        sa = np.sqrt(np.broadcast_to(np.asarray(adaptation_rate, float), (n,)))
        a_d = sd[:, None] * m0 * sd[None, :]
        a_p = p_factor * 0.5 * (a_d * b[None, :] + b[:, None] * a_d)
        a_a = sa[:, None] * m0 * sa[None, :]
        return cls(b, a_d, a_p, a_a, eps)


def check_gains(gains: AdaptiveGains) -> None:
    """Raise :class:`GainConditionError` unless ``0 < eps < 1`` and the paper's condition
    ``A_p > A_d beta / (2 eps)`` holds, in the form the proof uses:
    ``beta A_p - beta A_d beta / (2 eps)`` positive definite (its symmetric part); for
    diagonal gains this is ``A_p,ii > A_d,ii beta_i / (2 eps)`` on every coordinate."""
    eps = float(gains.eps)
    if not 0.0 < eps < 1.0:
        raise GainConditionError(f"eps must lie in (0, 1), got {eps!r}")
    b = np.diag(gains.beta)
    a_d = np.asarray(gains.A_d, float)
    a_p = np.asarray(gains.A_p, float)
    a_d = np.diag(a_d) if a_d.ndim == 1 else a_d
    a_p = np.diag(a_p) if a_p.ndim == 1 else a_p
    if (
        np.count_nonzero(a_d - np.diag(np.diag(a_d))) == 0
        and np.count_nonzero(a_p - np.diag(np.diag(a_p))) == 0
    ):
        bound = np.diag(a_d) * gains.beta / (2.0 * eps)
        bad = np.flatnonzero(np.diag(a_p) <= bound)
        if bad.size:
            rows = ", ".join(
                f"coordinate {i}: A_p = {np.diag(a_p)[i]:.4g} <= A_d beta / (2 eps) = "
                f"{bound[i]:.4g}"
                for i in bad
            )
            raise GainConditionError(
                "gains violate the stability condition A_p > A_d beta / (2 eps) "
                f"(eps = {eps}): {rows}. Increase A_p, or decrease A_d or beta."
            )
        return
    c = b @ a_p - b @ a_d @ b / (2.0 * eps)
    lam = float(np.linalg.eigvalsh(0.5 * (c + c.T)).min())
    if lam <= 0:
        raise GainConditionError(
            "gains violate the stability condition A_p > A_d beta / (2 eps) "
            f"(eps = {eps}): beta A_p - beta A_d beta / (2 eps) is not positive definite "
            f"(smallest eigenvalue {lam:.4g}). Increase A_p, or decrease A_d or beta."
        )


@dataclass(frozen=True)
class AdaptiveOutput:
    """One evaluation of the law."""

    tau: np.ndarray  # tau_a, generalized forces (n,)
    e: np.ndarray
    edot: np.ndarray
    s: np.ndarray
    qd_r: np.ndarray
    qdd_r: np.ndarray
    V: float  # Lyapunov function without the Delta_tilde term


@njit(cache=True)
def law_into(m, cd, k, e, edot, qd_d, qdd_d, beta, a_d, a_p, delta_hat, qd_r, qdd_r, s, tau):
    """The law (module docstring) in place, for the errors ``e = q - q_d`` and ``edot`` and
    ``cd = C + D``: ``qdot_r = qdot_d - beta e``, ``s = edot + beta e`` (written with
    ``qdd_r``), ``tau_a = M qdd_r + (C + D) qdot_r + K - A_d edot - A_p e + Delta_hat``
    (written); returns ``V`` without the ``Delta_tilde`` term. The batched engine's controller
    calls it too."""
    n = e.shape[0]
    for i in range(n):
        qd_r[i] = qd_d[i] - beta[i] * e[i]
        qdd_r[i] = qdd_d[i] - beta[i] * edot[i]
        s[i] = edot[i] + beta[i] * e[i]
    v = 0.0
    for i in range(n):
        acc = k[i] + delta_hat[i]
        ms = 0.0
        ve = 0.0
        for j in range(n):
            acc += m[i, j] * qdd_r[j] + cd[i, j] * qd_r[j]
            acc -= a_d[i, j] * edot[j] + a_p[i, j] * e[j]
            ms += m[i, j] * s[j]
            ve += (beta[i] * a_d[i, j] + a_p[i, j]) * e[j]
        tau[i] = acc
        v += 0.5 * (s[i] * ms + e[i] * ve)
    return v


@njit(cache=True)
def law_kernel(m, c, d, k, q, qd, q_d, qd_d, qdd_d, beta, a_d, a_p, delta_hat):
    """:func:`law_into` on fresh arrays from the state and the reference."""
    n = q.shape[0]
    e = q - q_d
    edot = qd - qd_d
    qd_r = np.empty(n)
    qdd_r = np.empty(n)
    s = np.empty(n)
    tau = np.empty(n)
    v = law_into(m, c + d, k, e, edot, qd_d, qdd_d, beta, a_d, a_p, delta_hat, qd_r, qdd_r, s, tau)
    return tau, e, edot, s, qd_r, qdd_r, v


class AdaptiveController:
    """The adaptive sliding-mode law on an :class:`EstimatedModel`.

    :meth:`law` evaluates ``tau_a`` (no state change); :meth:`adapt` integrates the adaptation
    law over ``dt`` (explicit Euler, as a 50 Hz digital controller does).
    """

    def __init__(self, model: EstimatedModel, gains: AdaptiveGains, delta0=None):
        if gains.n != model.n:
            raise ValueError(f"gains are for n = {gains.n}, the model has n = {model.n}")
        check_gains(gains)
        self.model = model
        self.gains = gains
        self.n = model.n
        self.delta_hat = np.zeros(self.n) if delta0 is None else np.asarray(delta0, float).copy()

    def reset(self, delta0=None):
        self.delta_hat = np.zeros(self.n) if delta0 is None else np.asarray(delta0, float).copy()

    def law(self, q, qd, q_d, qd_d, qdd_d, terms=None) -> AdaptiveOutput:
        """``tau_a`` and the sliding variables at ``(q, qdot)`` for the reference ``q_d``,
        ``qdot_d``, ``qddot_d`` (module docstring; :func:`law_kernel`)."""
        g = self.gains
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        t = self.model.terms(q, qd) if terms is None else terms
        tau, e, edot, s, qd_r, qdd_r, v = law_kernel(
            t.M, t.C, t.D, t.K, q, qd, np.asarray(q_d, float), np.asarray(qd_d, float),
            np.asarray(qdd_d, float), g.beta, g.A_d, g.A_p, self.delta_hat,
        )  # fmt: skip
        return AdaptiveOutput(tau, e, edot, s, qd_r, qdd_r, v)

    def adapt(self, s, dt: float) -> None:
        """``Delta_hat <- Delta_hat - A_a s dt``."""
        self.delta_hat = self.delta_hat - self.gains.A_a @ np.asarray(s, float) * float(dt)

    def lyapunov(self, out: AdaptiveOutput, delta_true=None) -> float:
        """``V`` of the stability analysis; the ``Delta_tilde`` term only if ``delta_true``
        (the true lumped uncertainty) is given."""
        if delta_true is None:
            return out.V
        dt = self.delta_hat - np.asarray(delta_true, float)
        return out.V + 0.5 * dt @ np.linalg.solve(self.gains.A_a, dt)
