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
from typing import NamedTuple

import numpy as np
from numba import njit

from ..control.model import EstimatedModel, ModelParams, model_params, model_terms_into
from ..system.kernels import input_matrix
from ..vision.mounts import camera_chain, mul4


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
        self._record, self._revision = None, None
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
        """``r = M_hat qdd + (C_hat + D_hat) qd + K_hat - B u`` (n,) (the compiled
        :func:`_residual` the force block runs)."""
        c = np.ascontiguousarray
        q, qd, u = c(q, dtype=float), c(qd, dtype=float), c(u, dtype=float)
        has = qdd is not None
        qdd = c(qdd, dtype=float) if has else np.zeros_like(q)
        out = np.empty(self.system.n)
        _residual(self._params(), self.system.model_arrays, q, qd, u, qdd, has, out)
        return out

    def _params(self) -> ForceParams:
        """The model's record (:func:`force_params`), taken again after a ``reseed``."""
        if self._record is None or self._revision != self.model.revision:
            self._record = force_params(self.model, np.eye(4), None, self.input_sigma,
                                        "differenced", 0.0)  # fmt: skip
            self._revision = self.model.revision
        return self._record

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
        out = np.empty((self.system.n, self.system.n))
        _input_cov(self._params(), self.system.model_arrays, np.ascontiguousarray(q, float), out)
        return out


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
        self._record, self._revision = None, None
        self._state = ForceState.initial(self.system.n, self.system.n_u)
        self.reset()

    def reset(self) -> None:
        """Start over: the next :meth:`step` sets ``p(0)`` and returns ``r = 0``."""
        self._state.started[0] = False
        self._state.r[:] = 0.0

    @property
    def r(self) -> np.ndarray:
        """The residual, the estimate of ``tau_e`` (n,)."""
        return self._state.r

    @property
    def started(self) -> bool:
        """Whether ``p(0)`` is set (a first :meth:`step` was taken)."""
        return bool(self._state.started[0])

    def step(self, q, qd, u, dt: float) -> np.ndarray:
        """Advance one period of ``dt`` s to the state ``(q, qd)``, ``u`` the input applied
        over the period; returns ``r`` (n,), the estimate of ``tau_e`` (the compiled
        :func:`_observer_update` the force block runs)."""
        k = self.gain * dt
        if not 0.0 < k < 2.0:
            raise ValueError(f"observer gain x period must be in (0, 2), got {k!r}")
        if self._record is None or self._revision != self.model.revision:
            self._record = force_params(self.model, np.eye(4), None, 0.0, "momentum", self.gain)
            self._revision = self.model.revision
        c = np.ascontiguousarray
        _observer_update(self._record, self._state, self.system.model_arrays, c(q, dtype=float),
                         c(qd, dtype=float), c(u, dtype=float), float(dt))  # fmt: skip
        return self._state.r.copy()


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


# --- The force block's compiled step: the estimate of every arm's normal force, one period ---

#: ``ForceParams.kind``: the residual from a :class:`MomentumObserver` (no accelerations) or
#: from the model's balance with differenced velocities
MOMENTUM, DIFFERENCED = 0, 1
FORCE_ESTIMATORS = {"momentum": MOMENTUM, "differenced": DIFFERENCED}


class ForceParams(NamedTuple):
    """The tip force estimate's parameters (the record of :func:`force_step`), for the ``k``
    arms of one system: ``kind`` (:data:`MOMENTUM` or :data:`DIFFERENCED`), the observer's
    ``gain`` ``K_o`` (1/s), ``input_var`` (n_u,) each input's variance (N^2), ``offset_skew``
    (3, 3) ``[o]x`` of the force's point ``o`` in the tip frame (zeros: the tip), the first row
    of the balance used (``first_row``: 0, all rows), each arm's rod as its Magnus steps
    ``rods`` (k, 2) and its tip camera's mount ``g_{C_L}^L`` ``mounts`` (k, 4, 4) (the normal is
    minus the camera's axis), and the controller's estimated model ``model``
    (:class:`~tdacm.control.model.ModelParams`)."""

    kind: int
    gain: float
    input_var: np.ndarray
    offset_skew: np.ndarray
    first_row: int
    rods: np.ndarray
    mounts: np.ndarray
    model: ModelParams


class ForceState(NamedTuple):
    """The estimate's state (one-element arrays for its scalars): the observer's residual
    ``r`` (n,), its previous end's ``beta_prev`` and momentum ``p_prev`` (n,), at ``q_prev``
    (n,) with ``u_prev`` (n_u,), ``started`` (``p(0)`` set); the differenced estimate's last
    velocity ``qd_prev`` (``has_qd``); the tare ``bias`` (n,) and the last period's residual
    ``last`` (``has_last``), which :func:`force_tare` takes as the bias."""

    r: np.ndarray
    beta_prev: np.ndarray
    p_prev: np.ndarray
    q_prev: np.ndarray
    u_prev: np.ndarray
    started: np.ndarray
    qd_prev: np.ndarray
    has_qd: np.ndarray
    bias: np.ndarray
    last: np.ndarray
    has_last: np.ndarray

    @classmethod
    def initial(cls, n: int, n_u: int) -> ForceState:
        b1 = lambda: np.zeros(1, np.bool_)  # noqa: E731
        return cls(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n_u), b1(),
                   np.zeros(n), b1(), np.zeros(n), np.zeros(n), b1())  # fmt: skip


class ForceOut(NamedTuple):
    """A period's estimate (written by :func:`force_step`): each arm's normal force ``force``
    (k,) (N) along ``normals`` (k, 3) (unit, inertial: minus its camera's axis), its standard
    deviation ``sigma`` (k,), and ``valid`` (1,) (False before the first applied input, while
    the observer starts, and where the rows do not see a force along a normal)."""

    force: np.ndarray
    sigma: np.ndarray
    normals: np.ndarray
    valid: np.ndarray

    @classmethod
    def empty(cls, k: int) -> ForceOut:
        return cls(np.full(k, np.nan), np.full(k, np.nan), np.zeros((k, 3)), np.zeros(1, np.bool_))


def force_params(model: EstimatedModel, mounts, offset, input_sigma, kind: str, gain: float,
                 rows: str = "all") -> ForceParams:  # fmt: skip
    """The record of the estimate of the normal forces on the probes of the arms whose tip
    cameras are mounted at ``mounts`` (one ``g_{C_L}^L`` per arm, arm ``k`` on rod ``k``), the
    force at ``offset`` in the tip frame, with the controller's ``model``; validated here."""
    if kind not in FORCE_ESTIMATORS:
        raise ValueError(f"kind must be 'momentum' or 'differenced', got {kind!r}")
    if rows not in ("strain", "all"):
        raise ValueError(f"rows must be 'strain' or 'all', got {rows!r}")
    gain = float(gain)
    if kind == "momentum" and not (np.isfinite(gain) and gain > 0.0):
        raise ValueError(f"gain must be positive (1/s), got {gain!r}")
    s = model.system
    mounts = np.ascontiguousarray(np.asarray(mounts, float).reshape(-1, 4, 4))
    if not 1 <= mounts.shape[0] <= s.n_rods:
        raise ValueError(f"one mount per arm (1 to {s.n_rods}), got {mounts.shape[0]}")
    o = np.zeros(3) if offset is None else np.asarray(offset, float)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValueError(f"offset must be a finite 3-vector (m), got {offset!r}")
    sigma = np.broadcast_to(np.asarray(input_sigma, float), (s.n_u,))
    steps = s.model_arrays.rod_steps
    rods = np.array([[steps[k], steps[k + 1]] for k in range(mounts.shape[0])], np.int64)
    skew = np.array([[0, -o[2], o[1]], [o[2], 0, -o[0]], [-o[1], o[0], 0]], float)
    first = (6 if s.floating else 0) if rows == "strain" else 0
    return ForceParams(FORCE_ESTIMATORS[kind], gain, np.ascontiguousarray(sigma**2), skew, first,
                       rods, mounts, model_params(model))  # fmt: skip


@njit(cache=True)
def _residual(p, m, q, qd, u, qdd, has_qdd, out):
    """``r = M_hat qdd + (C_hat + D_hat) qd + K_hat - B u`` (n,) into ``out``
    (:meth:`TipForceEstimator.residual`; without ``qdd`` when ``has_qdd`` is false)."""
    n = q.shape[0]
    mh, ch, dh, kh = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n)
    model_terms_into(p.model, m, q, qd, mh, ch, dh, kh)
    b = input_matrix(q, m)
    for i in range(n):
        acc = kh[i]
        for j in range(n):
            acc += (ch[i, j] + dh[i, j]) * qd[j]
            if has_qdd:
                acc += mh[i, j] * qdd[j]
        for c in range(u.shape[0]):
            acc -= b[i, c] * u[c]
        out[i] = acc


@njit(cache=True)
def _input_cov(p, m, q, out):
    """Covariance of ``B(q) u`` from the inputs' (n x n) into ``out``."""
    b = input_matrix(q, m)
    n = q.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for c in range(b.shape[1]):
                acc += b[i, c] * p.input_var[c] * b[j, c]
            out[i, j] = acc


@njit(cache=True)
def _observer_update(p, s, m, q, qd, u, dt):
    """One period of the momentum observer (:meth:`MomentumObserver.step`) on ``s``."""
    n = q.shape[0]
    mh, ch, dh, kh = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n)
    model_terms_into(p.model, m, q, qd, mh, ch, dh, kh)
    b = input_matrix(q, m)
    beta, mom = np.empty(n), np.empty(n)
    for i in range(n):
        acc = -kh[i]
        pm = 0.0
        for j in range(n):
            acc += (ch[j, i] - dh[i, j]) * qd[j]
            pm += mh[i, j] * qd[j]
        for c in range(u.shape[0]):
            acc += b[i, c] * u[c]
        beta[i] = acc
        mom[i] = pm
    if s.started[0]:
        # the previous end's beta with this period's input (the input held over the period)
        bp = input_matrix(s.q_prev, m)
        k = p.gain * dt
        for i in range(n):
            acc = s.beta_prev[i]
            for c in range(u.shape[0]):
                acc += bp[i, c] * (u[c] - s.u_prev[c])
            s.r[i] = (1.0 - k) * s.r[i] + p.gain * (
                mom[i] - s.p_prev[i] - 0.5 * dt * (beta[i] + acc)
            )
    s.beta_prev[:] = beta
    s.p_prev[:] = mom
    s.q_prev[:] = q
    s.u_prev[:] = u
    s.started[0] = True


@njit(cache=True)
def _normal_forces(p, m, q, residual, cov, out):
    """Every arm's force along its normal from one residual (n,) less the bias, solved
    together by least squares over the rows (:func:`normal_forces_of`; one arm:
    :meth:`TipForceEstimator.normal_force_of`), with their standard deviations from ``cov``
    (n x n), into ``out``; ``out.valid`` False where the rows do not determine them."""
    n = q.shape[0]
    k = p.rods.shape[0]
    r0 = p.first_row
    nr = n - r0
    a = np.empty((nr, k))
    g = np.empty((4, 4))
    jac = np.empty((6, n))
    gc = np.empty((4, 4))
    for arm in range(k):
        camera_chain(q, m, p.rods[arm], bool(1), g, jac)
        mul4(g, p.mounts[arm], gc)
        nn = 0.0
        for i in range(3):
            nn += gc[i, 2] * gc[i, 2]
        nn = np.sqrt(nn)
        for i in range(3):
            out.normals[arm, i] = -gc[i, 2] / nn
        # the normal in the tip frame, R^T n, and A n = J_v^T R^T n + J_w^T [o]x R^T n
        nt = np.zeros(3)
        for i in range(3):
            for c in range(3):
                nt[i] += g[c, i] * out.normals[arm, c]
        w = np.zeros(3)  # [o]x R^T n: what the angular rows see
        for i in range(3):
            for c in range(3):
                w[i] += p.offset_skew[i, c] * nt[c]
        for row in range(nr):
            col = r0 + row
            acc = 0.0
            for i in range(3):
                acc += jac[3 + i, col] * nt[i] + jac[i, col] * w[i]
            a[row, arm] = acc
    # normal equations of the k columns: f = (A^T A)^-1 A^T r, cov_f = G A^T C A G
    gram = np.zeros((k, k))
    for i in range(k):
        for j in range(k):
            acc = 0.0
            for row in range(nr):
                acc += a[row, i] * a[row, j]
            gram[i, j] = acc
    if k == 1:
        if gram[0, 0] == 0.0:
            out.valid[0] = False
            return
        gi = np.empty((1, 1))
        gi[0, 0] = 1.0 / gram[0, 0]
    else:
        if abs(np.linalg.det(gram)) <= 1e-300:
            out.valid[0] = False
            return
        gi = np.linalg.inv(gram)
    atr = np.zeros(k)
    for i in range(k):
        for row in range(nr):
            atr[i] += a[row, i] * residual[r0 + row]
    ca = np.zeros((nr, k))  # C A over the rows
    for row in range(nr):
        for i in range(k):
            acc = 0.0
            for c in range(nr):
                acc += cov[r0 + row, r0 + c] * a[c, i]
            ca[row, i] = acc
    aca = np.zeros((k, k))
    for i in range(k):
        for j in range(k):
            for row in range(nr):
                aca[i, j] += a[row, i] * ca[row, j]
    for i in range(k):
        f = 0.0
        var = 0.0
        for j in range(k):
            f += gi[i, j] * atr[j]
            for c in range(k):
                var += gi[i, j] * aca[j, c] * gi[c, i]
        out.force[i] = f
        out.sigma[i] = np.sqrt(max(var, 0.0))
    out.valid[0] = True


@njit(cache=True)
def force_reset(s):
    """Start over (as built: no tare, the observer restarts, no last velocity)."""
    s.r[:] = 0.0
    s.started[0] = False
    s.has_qd[0] = False
    s.bias[:] = 0.0
    s.has_last[0] = False


@njit(cache=True)
def force_tare(s):
    """Take the last period's residual as the model's bias (contact-free: before touching);
    nothing without one."""
    if s.has_last[0]:
        s.bias[:] = s.last


@njit(cache=True)
def force_step(p, s, m, q, qd, u, has_u, state_cov, dt, out):
    """One period of the tip force estimate (module docstring; the block
    :class:`~tdacm.loop.touch.TipForceBlock`): the residual of the controller's model
    ``m`` at the estimate ``(q, qd)`` with the input ``u`` applied over the period
    (``has_u`` False: none yet), the momentum observer's (its covariance the inputs' through the
    observer's lag) or the balance with differenced velocities (with the state covariance
    ``state_cov`` (2n, 2n), or (0, 0) for none, by finite differences), less the tare, solved
    for every arm's normal force into ``out``."""
    n = q.shape[0]
    out.valid[0] = False
    cov = np.empty((n, n))
    if p.kind == MOMENTUM:
        if not has_u:  # the observer restarts
            s.r[:] = 0.0
            s.started[0] = False
            s.has_last[0] = False
            return
        was = s.started[0]
        _observer_update(p, s, m, q, qd, u, dt)
        s.last[:] = s.r
        s.has_last[0] = True
        if not was:
            return
        # the inputs' white noise through the observer's first-order lag: the steady variance
        # of x_k = (1 - k) x_{k-1} + k w_k is k / (2 - k) that of w (k = K_o dt)
        kk = p.gain * dt
        _input_cov(p, m, q, cov)
        for i in range(n):
            for j in range(n):
                cov[i, j] *= kk / (2.0 - kk)
        r = s.r
    else:
        qdd = np.empty(n)
        had = s.has_qd[0]
        if had:
            for i in range(n):
                qdd[i] = (qd[i] - s.qd_prev[i]) / dt
        s.qd_prev[:] = qd
        s.has_qd[0] = True
        if not has_u or not had:
            s.has_last[0] = False
            return
        r = np.empty(n)
        _residual(p, m, q, qd, u, qdd, True, r)
        s.last[:] = r
        s.has_last[0] = True
        _input_cov(p, m, q, cov)
        if state_cov.shape[0] == 2 * n:  # the state's covariance through the residual
            x = np.empty(2 * n)
            x[:n] = q
            x[n:] = qd
            gr = np.empty((n, 2 * n))
            rp = np.empty(n)
            for i in range(2 * n):
                e = 1e-7 * max(1.0, abs(x[i]))
                xp = x.copy()
                xp[i] += e
                _residual(p, m, xp[:n], xp[n:], u, qdd, True, rp)
                for j in range(n):
                    gr[j, i] = (rp[j] - r[j]) / e
            for i in range(n):
                for j in range(n):
                    acc = 0.0
                    for a in range(2 * n):
                        for b in range(2 * n):
                            acc += gr[i, a] * state_cov[a, b] * gr[j, b]
                    cov[i, j] += acc
    rb = np.empty(n)
    for i in range(n):
        rb[i] = r[i] - s.bias[i]
    _normal_forces(p, m, q, rb, cov, out)
