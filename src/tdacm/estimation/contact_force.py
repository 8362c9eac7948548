"""The tip contact force from the tendons: no force sensor, the model's balance.

A contact force ``F`` (inertial) on the tip sphere enters the dynamics (paper eq. (9)) as the
generalized force ``J_v^T R^T F`` (eq. (16), ``J_v`` the linear rows of the tip Jacobian in
the tip frame, ``R`` the tip orientation; at a point ``o`` of the tip frame, a probe's end,
``(J_v + [o]x^T J_w)^T R^T F``).  With the controller's model
(:class:`~tdacm.control.model.EstimatedModel`: ``M_hat, C_hat, D_hat`` and ``K_hat``, elastic
and estimated gravity), the applied inputs ``u`` (the rotor thrusts and the tendon
tensions), and the (estimated) state and acceleration, the residual

    r = M_hat qdd + (C_hat + D_hat) qd + K_hat - B(q) u  =  A F,   A = J_v^T R^T   (n x 3)

is what the model cannot explain; :class:`TipForceEstimator` solves it for ``F`` by weighted
least squares over the chosen rows (the strain rows: the tendons against the rod's bending;
all rows: the drone's thrust and motion too) and propagates the covariance of ``u`` and of the
state to that of ``F``.  The model errors that do not come from contact (a 10 % stiffness or
weight error) bias ``r``: :meth:`TipForceEstimator.tare` stores the residual of a contact-free
moment (before touching) and subtracts it.  A force along the rod's axis bends an
inextensible rod only through its curvature: along a known direction (the contact normal),
:meth:`TipForceEstimator.normal_force` estimates the one component instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..control.model import EstimatedModel


@dataclass(frozen=True)
class ForceEstimate:
    """``force`` (3,) inertial (N) and its covariance (3 x 3) (N^2)."""

    force: np.ndarray
    covariance: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


class TipForceEstimator:
    """Tip contact force from the tensions, the strains and the controller's model.

    model : the controller's :class:`~tdacm.control.model.EstimatedModel`
    rows : ``"strain"`` (the rod's balance only, the drone's rows left out: no thrust or
        drone acceleration needed) or ``"all"``
    input_sigma : standard deviation of each applied input (N): the tension and thrust errors
        (scalar or one per input)
    offset : (3,) m, where the force acts in the tip frame (a probe ahead of the tip,
        :func:`tdacm.system.contact.probe_offset`); zero: at the tip
    rod : the arm whose tip the force acts on (a system with several rods; 0: the first)
    """

    def __init__(
        self, model: EstimatedModel, rows: str = "strain", *, input_sigma, offset=None, rod=0
    ):
        if not isinstance(model, EstimatedModel):
            raise ValueError(f"model must be an EstimatedModel, got {model!r}")
        if rows not in ("strain", "all"):
            raise ValueError(f"rows must be 'strain' or 'all', got {rows!r}")
        self.model = model
        s = model.system
        self.system = s
        self.rod = int(rod)
        if not 0 <= self.rod < s.n_rods:
            raise ValueError(f"rod must be in [0, {s.n_rods}), got {rod!r}")
        off = 6 if s.floating else 0
        self.rows = np.arange(off if rows == "strain" else 0, s.n)
        self.input_sigma = np.broadcast_to(np.asarray(input_sigma, float), (s.n_u,)).copy()
        self.bias = np.zeros(s.n)
        o = np.zeros(3) if offset is None else np.asarray(offset, float)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"offset must be a finite 3-vector (m), got {offset!r}")
        # [o]x: a force f (tip frame) at o is the wrench [o x f; f] on the tip (eq. (16))
        self.offset_skew = (
            None
            if not o.any()
            else np.array([[0, -o[2], o[1]], [o[2], 0, -o[0]], [-o[1], o[0], 0]])
        )

    def residual(self, q, qd, u, qdd=None) -> np.ndarray:
        """``r = M_hat qdd + (C_hat + D_hat) qd + K_hat - B u`` (n,)."""
        q, qd, u = (np.asarray(x, float) for x in (q, qd, u))
        t = self.model.terms(q, qd)
        r = (t.C + t.D) @ qd + t.K - self.system.input_matrix(q) @ u
        if qdd is not None:
            r = r + t.M @ np.asarray(qdd, float)
        return r

    def tare(self, q, qd, u, qdd=None) -> None:
        """Store the residual of a contact-free state as the model's bias."""
        self.bias = self.residual(q, qd, u, qdd)

    def clear_tare(self) -> None:
        """Forget the stored bias (as built: no tare)."""
        self.bias = np.zeros(self.system.n)

    def _a(self, q) -> np.ndarray:
        s = self.system
        g = s.tip_pose(q, self.rod)
        j = s.tip_jacobian(q, self.rod)
        if self.offset_skew is None:
            return j[3:6].T @ g[:3, :3].T
        return (j[3:6].T + j[0:3].T @ self.offset_skew) @ g[:3, :3].T

    def residual_covariance(self, q, qd, u, qdd, state_cov) -> np.ndarray:
        """Covariance of ``r`` from the inputs and, if given, the state ``[q, qd]``."""
        cov = self.input_cov(q)
        if state_cov is not None:
            n = self.system.n
            x = np.r_[q, qd]
            r0 = self.residual(q, qd, u, qdd)
            g = np.empty((n, 2 * n))
            for i in range(2 * n):
                e = 1e-7 * max(1.0, abs(x[i]))
                xp = x.copy()
                xp[i] += e
                g[:, i] = (self.residual(xp[:n], xp[n:], u, qdd) - r0) / e
            cov = cov + g @ np.asarray(state_cov, float) @ g.T
        return cov

    def estimate(self, q, qd, u, qdd=None, state_cov=None) -> ForceEstimate:
        """The tip force (least squares over the rows; the minimum-norm solution where the
        rows do not determine all three components) and its covariance."""
        r = (self.residual(q, qd, u, qdd) - self.bias)[self.rows]
        a = self._a(q)[self.rows]
        pinv = np.linalg.pinv(a)
        cov = self.residual_covariance(q, qd, u, qdd, state_cov)[np.ix_(self.rows, self.rows)]
        return ForceEstimate(pinv @ r, pinv @ cov @ pinv.T)

    def normal_force(self, q, qd, u, normal, qdd=None, state_cov=None):
        """``(f, sigma)``: the force along the unit ``normal`` (inertial), the only unknown,
        and its standard deviation."""
        r = self.residual(q, qd, u, qdd)
        return self.normal_force_of(
            q, r, normal, self.residual_covariance(q, qd, u, qdd, state_cov)
        )

    def normal_force_of(self, q, residual, normal, residual_cov):
        """``(f, sigma)`` along the unit ``normal`` from a given residual (n,) (the tare
        subtracted here), e.g. a :class:`MomentumObserver`'s, and its covariance (n x n)."""
        n = np.asarray(normal, float)
        n = n / np.linalg.norm(n)
        r = (np.asarray(residual, float) - self.bias)[self.rows]
        a = self._a(q)[self.rows] @ n
        aa = a @ a
        if aa == 0.0:
            raise ValueError("the chosen rows do not see a force along this normal")
        cov = np.asarray(residual_cov, float)[np.ix_(self.rows, self.rows)]
        return float(a @ r / aa), float(np.sqrt(a @ cov @ a) / aa)

    def normal_column(self, q, normal) -> np.ndarray:
        """``A n`` over the estimator's rows: the residual of a unit force along the unit
        ``normal`` (inertial) on this estimator's tip point."""
        n = np.asarray(normal, float)
        return self._a(q)[self.rows] @ (n / np.linalg.norm(n))

    def input_cov(self, q) -> np.ndarray:
        """Covariance of ``B(q) u`` from the inputs' (n x n)."""
        b = self.system.input_matrix(np.asarray(q, float))
        return (b * self.input_sigma**2) @ b.T


class MomentumObserver:
    """Generalized-momentum disturbance observer (De Luca & Mattone 2005): the external
    generalized force from the state and the inputs, no acceleration needed.

    With ``p = M_hat(q) qd`` and the model's property ``Mdot_hat = C_hat + C_hat^T``
    (:class:`~tdacm.control.model.EstimatedModel` keeps ``Mdot_hat - 2 C_hat`` skew), the
    dynamics ``M qdd + (C + D) qd + K = B u + tau_e`` (paper eq. (9)) read
    ``pdot = B u + C^T qd - D qd - K + tau_e``; the residual

        r(t) = K_o (p(t) - p(0) - int_0^t (B u + C^T qd - D qd - K + r) ds)

    obeys ``rdot = K_o (tau_e - r)``: a first-order lag of the unknown ``tau_e`` (the model's
    errors and the contact) with time constant ``1 / K_o``. Discretely, over a period ``h``
    with the input held, the integrand at the period's mid-point (mean of its two ends):
    ``r_k = (1 - K_o h) r_{k-1} + K_o (p_k - p_{k-1} - h beta_k)``, stable for
    ``0 < K_o h < 2`` (docs/contact.md, "Contact on estimates").

    model : the controller's :class:`~tdacm.control.model.EstimatedModel`; ``gain``: ``K_o``
    (1/s, scalar).
    """

    def __init__(self, model: EstimatedModel, gain: float):
        if not isinstance(model, EstimatedModel):
            raise ValueError(f"model must be an EstimatedModel, got {model!r}")
        gain = float(gain)
        if not (np.isfinite(gain) and gain > 0.0):
            raise ValueError(f"gain must be positive (1/s), got {gain!r}")
        self.model = model
        self.system = model.system
        self.gain = gain
        self.reset()

    def reset(self) -> None:
        """Start over: the next :meth:`step` sets ``p(0)`` and returns ``r = 0``."""
        self._prev = None
        self.r = np.zeros(self.system.n)

    @property
    def started(self) -> bool:
        """Whether ``p(0)`` is set (a first :meth:`step` was taken)."""
        return self._prev is not None

    def _beta(self, q, qd, u) -> np.ndarray:
        t = self.model.terms(q, qd)
        return self.system.input_matrix(q) @ u + t.C.T @ qd - t.D @ qd - t.K, t.M @ qd

    def step(self, q, qd, u, dt: float) -> np.ndarray:
        """Advance one period of ``dt`` s to the state ``(q, qd)``, ``u`` the input applied
        over the period; returns ``r`` (n,), the estimate of ``tau_e``."""
        q, qd, u = (np.asarray(x, float) for x in (q, qd, u))
        beta, p = self._beta(q, qd, u)
        if self._prev is not None:
            beta_prev, p_prev = self._prev
            # the previous end's beta with this period's input (the input held over it)
            beta_prev = beta_prev + self.system.input_matrix(self._q_prev) @ (u - self._u_prev)
            k = self.gain * dt
            if not 0.0 < k < 2.0:
                raise ValueError(f"observer gain x period must be in (0, 2), got {k!r}")
            self.r = (1.0 - k) * self.r + self.gain * (p - p_prev - 0.5 * dt * (beta + beta_prev))
        self._prev = (beta, p)
        self._q_prev, self._u_prev = q, u
        return self.r.copy()


def normal_forces_of(estimators, q, residual, normals, residual_cov):
    """``(f, sigma)`` (k,) the forces along the unit ``normals[i]`` on the tip points of
    ``estimators[i]`` (one :class:`TipForceEstimator` per arm of one system, the same rows and
    tare), solved together from one residual: ``r - bias = sum_i A_i n_i f_i`` by least
    squares, with the standard deviations from ``residual_cov`` (n x n). The arms share the
    drone's rows, which see every arm's force: one arm's estimate alone would count the
    other's there. With one estimator this is :meth:`TipForceEstimator.normal_force_of`."""
    first = estimators[0]
    rows = first.rows
    a = np.column_stack([e.normal_column(q, n) for e, n in zip(estimators, normals, strict=True)])
    r = (np.asarray(residual, float) - first.bias)[rows]
    pinv = np.linalg.pinv(a)
    cov = pinv @ np.asarray(residual_cov, float)[np.ix_(rows, rows)] @ pinv.T
    return pinv @ r, np.sqrt(np.clip(np.diag(cov), 0.0, None))
