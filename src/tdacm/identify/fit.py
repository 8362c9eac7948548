"""Fit the model's simulated motion to recordings: multiple shooting with least squares.

**Decision variables.** The chosen parameters, scaled (``log(value)`` for the positive ones,
``value / scale`` for the friction coefficients and the camera offset, see
:mod:`tdacm.identify.params`), and for every segment of every recording its initial state
``(q, qdot)``. Segments are windows of ``segment`` seconds; each starts from its own state,
initialized from the recording (strains by inverse kinematics of the measured tip pose, the
drone's coordinates from its measured pose, rates by central differences) and then fitted
with the parameters, so an error early in a recording does not carry over: a model 30 % off
stays near the data within a segment and the cost stays close to quadratic.

**Segment length.** Long enough that each segment's free initial state (``2 n`` unknowns)
takes a small share of the information: several hundred samples and at least one period of
the rod's first bending mode (1.25 s for the paper robot); short enough that a start 30 % off
does not drift by more than a fraction of a period (the phase error of a mode whose frequency
is 15 % off grows by ``0.15 * 2 pi`` per period). Defaults: 2 s for a clamped rod, 1 s with a
flying base (the drone's open-loop attitude, replayed from recorded thrusts, is unstable: its
error grows without a controller, so the windows must be short).

**Residuals** (each divided by its noise level, so the cost is a log-likelihood): per sample,
the tip's position (m) and rotation (``log(R_meas^T R_model)``, rad), the drone's, and the tip
camera's pixels when given. Motion capture alone: no strain is measured.

**Jacobian.** Forward differences (step 1e-6 on the scaled variables) with the structure of
multiple shooting: a parameter column re-simulates every segment; a state column perturbs the
same component of every segment's state at once (segments are independent), so a Jacobian
costs ``1 + p + 2 n`` simulations per recording. Solver: Levenberg-Marquardt with every
window's states eliminated block by block (:mod:`tdacm.identify.solve`; a window's state
moves only its window's residuals), so a step costs ``O(m (p + 2 n)^2)``, not the dense
factorization of the ``m x n_z`` Jacobian.

**Uncertainty.** Two estimates of the parameters' covariance, the larger variance of the two
reported per parameter (correlations from the first):

* the **stated noise model**: the motion capture's white noise (``F^-1``, the Fisher
  information with the window states eliminated) plus the load cells' noise propagated
  through the fitted model (:func:`input_noise_covariance`). The fit takes the measured
  tensions as exact inputs (errors in variables): their noise drives the model's lightly
  damped rod where the real one was not driven, a residual correlated over the mode's decay
  time that the white-noise formula ignores and that moves the damping most;
* the **sandwich** ``A S A`` (:func:`sandwich_covariance`), ``A = (J^T J)^-1`` and ``S`` the
  heteroskedasticity- and autocorrelation-consistent (Newey-West, Bartlett weights) long-run
  covariance of the per-sample scores ``J_t^T r_t`` of each recording: it needs no noise
  model, so it also covers a model error smooth in time, but its lag window (at most one
  shooting window, the correlation of an oscillation cut short) underestimates a long
  correlation.

The white-residual covariance ``s^2 (J^T J)^-1`` (``s^2 = |r|^2 / (m - n_z)``) is kept as
``std_iid``; the two above as ``std_noise`` and ``std_sandwich``. The parameter block accounts
for the unknown segment states (they are eliminated). A log-parameter's standard deviation is
relative.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .._compiling import compiling
from .data import Recording
from .experiments import NOISE, project_points
from .params import PARAMETERS, parse_params
from .solve import Blocks, levenberg_marquardt, parameter_rows

log = logging.getLogger(__name__)

FD_STEP = 1e-6
#: How far the fit may move a parameter from its start: a factor (log-parameters) or as many
#: scales (linear ones).
SEARCH_FACTOR = 3.0


def default_segment(rec: Recording) -> float:
    """The default segment length (s): 2 s for a clamped rod, 1 s for a flying base."""
    return 1.0 if rec.model.floating else 2.0


@dataclass
class Setup:
    """One recording's share of the fit: its segments and measurement blocks."""

    rec: Recording
    starts: np.ndarray
    ends: np.ndarray
    kdim: int  # residual entries per sample
    use_pose: bool
    use_pixels: bool
    offset: int = 0  # first decision variable of its segment states


def _segments(n: int, length: int):
    starts = np.arange(0, n, length)
    if len(starts) > 1 and n - starts[-1] < length // 2:
        starts = starts[:-1]  # the last short window joins the previous one
    ends = np.r_[starts[1:], n]
    return starts.astype(np.int64), ends.astype(np.int64)


def _rotvec_err(meas, pred):
    return Rotation.from_matrix(np.einsum("tji,tjk->tik", meas, pred)).as_rotvec()


class Problem:
    """The least-squares problem of :func:`identify` (exposed for the Fisher analysis)."""

    def __init__(
        self, recordings, names, sigma=None, segment=None, substeps=1, use="auto", fixed=None
    ):
        self.recs = list(recordings)
        self.fixed = dict(fixed or {})
        self.names = list(names)
        self.sigma = {**NOISE, **(sigma or {})}
        self.substeps = substeps
        # a parameter a recording's robot does not have (a drone's on a clamped rod) has a
        # zero column there: recordings of both bases share the rod's parameters
        self.setups = []
        off = len(self.names)
        for r in self.recs:
            seg = default_segment(r) if segment is None else float(segment)
            length = max(2, int(round(seg / r.dt)))
            starts, ends = _segments(len(r.t), length)
            use_pixels = r.pixels is not None and use in ("auto", "camera", "all")
            use_pose = r.tip is not None and use in ("auto", "mocap", "all")
            if use == "auto" and use_pose:
                use_pixels = False
            if not (use_pose or use_pixels):
                raise ValueError(f"{r.name}: nothing to fit with use={use!r}")
            for n in self.names:
                if PARAMETERS[n].camera_only and not use_pixels:
                    raise ValueError(f"{n} needs camera pixels (use='camera')")
            kdim = 0
            if use_pose:
                kdim += 6 + (6 if r.model.floating else 0)
            if use_pixels:
                kdim += r.pixels.shape[1] * 2
            s = Setup(r, starts, ends, kdim, use_pose, use_pixels, off)
            off += len(starts) * 2 * r.model.system.n
            self.setups.append(s)
        self.n_z = off
        self._last = (None, None)
        rows, cols, row = [], [], 0
        for s in self.setups:
            k2 = 2 * s.rec.model.system.n
            for g, (a, b) in enumerate(zip(s.starts, s.ends, strict=True)):
                rows.append((row + int(a) * s.kdim, row + int(b) * s.kdim))
                cols.append((s.offset + g * k2, s.offset + (g + 1) * k2))
            row += len(s.rec.t) * s.kdim
        #: the windows' rows and state columns of the Jacobian (:mod:`tdacm.identify.solve`)
        self.blocks = Blocks(len(self.names), rows, cols)

    # ---------------------------------------------------------------- variables
    def to_z(self, values: dict) -> np.ndarray:
        out = []
        for n in self.names:
            p = PARAMETERS[n]
            v = values[n]
            out.append(np.log(v) if p.log else v / p.scale)
        return np.array(out)

    def from_z(self, zp: np.ndarray) -> dict:
        out = dict(self.fixed)
        for n, x in zip(self.names, zp, strict=True):
            p = PARAMETERS[n]
            out[n] = float(np.exp(x)) if p.log else float(x * p.scale)
        return out

    def initial(self, values: dict) -> np.ndarray:
        """Decision vector: scaled parameters and every segment's state from the data."""
        z = np.zeros(self.n_z)
        z[: len(self.names)] = self.to_z(values)
        for s in self.setups:
            x0 = initial_states(
                s.rec, s.starts, {**s.rec.model.nominal, **self.fixed, **values}, self
            )
            z[s.offset : s.offset + x0.size] = x0.ravel()
        return z

    def _states(self, z, s: Setup):
        n = s.rec.model.system.n
        x = z[s.offset : s.offset + len(s.starts) * 2 * n].reshape(len(s.starts), 2 * n)
        return x[:, :n], x[:, n:]

    # ---------------------------------------------------------------- residuals
    def predict(self, z, s: Setup, values=None):
        values = self.from_z(z[: len(self.names)]) if values is None else values
        q0, qd0 = self._states(z, s)
        r = s.rec
        return r.model.simulate(r.values(values), q0, qd0, s.starts, s.ends, r.u, r.dt,
                                self.substeps)  # fmt: skip

    def measurement_residual(self, pred, s: Setup, values) -> np.ndarray:
        """(T, kdim) normalized residuals of one recording (``(R T, kdim)`` for a prediction of
        ``R`` runs of it one after another, as :meth:`state_differences` makes)."""
        r = s.rec
        reps = len(pred.tip) // len(r.t)  # several runs of the recording, one after another

        def meas(a):
            return a if reps == 1 else np.tile(a, (reps,) + (1,) * (a.ndim - 1))

        sp, sr = self.sigma["position"], np.radians(self.sigma["rotation_deg"])
        blocks = []
        if s.use_pose:
            tip = meas(r.tip)
            blocks += [(pred.tip[:, :3, 3] - tip[:, :3, 3]) / sp,
                       _rotvec_err(tip[:, :3, :3], pred.tip[:, :3, :3]) / sr]  # fmt: skip
            if r.model.floating:
                drone = meas(r.drone)
                blocks += [(pred.base[:, :3, 3] - drone[:, :3, 3]) / sp,
                           _rotvec_err(drone[:, :3, :3], pred.base[:, :3, :3]) / sr]  # fmt: skip
        if s.use_pixels:
            mount = r.model.camera_mount(values.get("camera_offset"))
            px = project_points(pred.tip, mount, r.camera, r.target_points)
            d = (px - meas(r.pixels)) / self.sigma["pixel"]
            blocks.append(np.nan_to_num(d.reshape(len(px), -1), nan=0.0))
        return np.hstack(blocks)

    def residual(self, z) -> np.ndarray:
        key = z.tobytes()
        if self._last[0] == key:
            return self._last[1]
        values = self.from_z(z[: len(self.names)])
        out = np.concatenate(
            [
                self.measurement_residual(self.predict(z, s, values), s, values).ravel()
                for s in self.setups
            ]  # fmt: skip
        )
        self._last = (key, out)
        return out

    def jacobian(self, z) -> np.ndarray:
        r0 = self.residual(z)
        jac = np.zeros((r0.size, self.n_z))
        npar = len(self.names)
        for i in range(npar):
            zi = z.copy()
            zi[i] += FD_STEP
            jac[:, i] = (self._raw_residual(zi) - r0) / FD_STEP
        row = 0
        values = self.from_z(z[:npar])
        for s in self.setups:
            nt = len(s.rec.t)
            nrow = nt * s.kdim
            k2 = 2 * s.rec.model.system.n
            d = self.state_differences(z, s, values, r0[row : row + nrow].reshape(nt, s.kdim))
            for j in range(k2):
                for g, (a, b) in enumerate(zip(s.starts, s.ends, strict=True)):
                    jac[row + a * s.kdim : row + b * s.kdim, s.offset + g * k2 + j] = d[
                        j, a:b
                    ].ravel()
            row += nrow
        return jac

    def state_differences(self, z, s: Setup, values, base) -> np.ndarray:
        """(2n, T, kdim) forward differences of one recording's residuals in each window-state
        component (step :data:`FD_STEP`; the same component of every window at once: windows
        are independent). The ``2 n`` perturbed runs of every window go to the cores in one
        call (:meth:`~tdacm.identify.model.IdentModel.simulate_many`)."""
        r = s.rec
        n = r.model.system.n
        nt, nseg, k2 = len(r.t), len(s.starts), 2 * n
        x = z[s.offset : s.offset + nseg * k2].reshape(nseg, k2)
        xs = np.repeat(x[None], k2, axis=0)
        for j in range(k2):
            xs[j, :, j] += FD_STEP
        xs = xs.reshape(k2 * nseg, k2)
        out0 = (np.arange(k2)[:, None] * nt + s.starts[None, :]).ravel()
        pred = r.model.simulate_many(r.values(values), xs[:, :n], xs[:, n:], np.tile(s.starts, k2),
                                     np.tile(s.ends - s.starts, k2), out0, k2 * nt, r.u, r.dt,
                                     self.substeps)  # fmt: skip
        res = self.measurement_residual(pred, s, values).reshape(k2, nt, s.kdim)
        return (res - base[None]) / FD_STEP

    def _raw_residual(self, z):
        values = self.from_z(z[: len(self.names)])
        return np.concatenate(
            [
                self.measurement_residual(self.predict(z, s, values), s, values).ravel()
                for s in self.setups
            ]  # fmt: skip
        )

    def fisher(self, jac) -> np.ndarray:
        """The parameters' Fisher information (scaled variables) with the segment states
        eliminated (Schur complement of ``J^T J``)."""
        npar = len(self.names)
        jp, js = jac[:, :npar], jac[:, npar:]
        a = jp.T @ jp
        if js.shape[1] == 0:
            return a
        b = jp.T @ js
        c = js.T @ js
        return a - b @ np.linalg.solve(c + 1e-12 * np.eye(len(c)) * np.trace(c) / len(c), b.T)


def sandwich_covariance(prob: Problem, jac: np.ndarray, r: np.ndarray, npar: int,
                        lags: int | None = None) -> tuple[np.ndarray, int]:  # fmt: skip
    """The parameters' (scaled) covariance ``A S A`` robust to correlated residuals, and the
    lag window used.

    ``A = (J^T J)^-1``; the parameter rows of ``A J^T`` (:func:`~tdacm.identify.solve.parameter_rows`,
    the window states eliminated block by block) map the residuals to the estimate, so
    the estimate's error is ``sum_t h_t`` with ``h_t = (A J^T)_{p, rows t} r_t`` the score of
    sample ``t``. ``S = sum_l w_l sum_t h_t h_{t-l}^T`` (both signs of ``l``) with Bartlett
    weights ``w_l = 1 - |l| / (L + 1)`` within each recording (recordings independent); the
    lag window ``L`` is Andrews' AR(1) plug-in rule on the scores (Andrews 1991, eq. 6.4),
    at least 1 and at most one shooting window. ``m / (m - n_z)`` corrects for the fitted
    variables' share of the residuals."""
    m, nz = jac.shape
    h, _ = parameter_rows(jac, prob.blocks)
    cov = np.zeros((npar, npar))
    row = 0
    used = 0
    for s in prob.setups:
        nt, k = len(s.rec.t), s.kdim
        g = np.einsum("ptk,tk->tp", h[:, row : row + nt * k].reshape(npar, nt, k),
                      r[row : row + nt * k].reshape(nt, k))  # fmt: skip
        row += nt * k
        cap = int(max(np.max(s.ends - s.starts), 2))
        if lags is None:
            num = den = 0.0
            for j in range(npar):
                x = g[:, j]
                rho = float(np.clip(x[1:] @ x[:-1] / max(x[:-1] @ x[:-1], 1e-300), -0.99, 0.99))
                var = float(np.mean(x**2)) * (1 - rho**2)
                w = (x @ x) ** 2
                num += w * 4 * rho**2 * var**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
                den += w * var**2 / (1 - rho) ** 4
            alpha = num / max(den, 1e-300)
            lag = int(np.clip(np.ceil(1.1447 * (alpha * nt) ** (1 / 3)), 1, cap))
        else:
            lag = int(lags)
        used = max(used, lag)
        c = g.T @ g
        for lag_i in range(1, min(lag, nt - 1) + 1):
            x = g[lag_i:].T @ g[:-lag_i]
            c += (1 - lag_i / (lag + 1)) * (x + x.T)
        cov += c
    return cov * m / max(m - nz, 1), used


#: Draws of the load cells' noise propagated through the fitted model
#: (:func:`input_noise_covariance`; each draw gives every shooting window an independent
#: sample, so the covariance averages draws x windows outer products: 8 x 20 on the shipped
#: steps, a sampling error near 6 % on the standard deviations).
INPUT_DRAWS = 8


def input_noise_covariance(prob: Problem, z: np.ndarray, h: np.ndarray, decimate: int = 1,
                           draws: int = INPUT_DRAWS, seed: int = 0) -> np.ndarray:  # fmt: skip
    """The parameters' (scaled) covariance due to the noise of the measured tensions.

    The fit replays the measured tensions as exact inputs (errors in variables): a load cell's
    noise drives the model's rod where the real one was not driven, a residual correlated over
    the rod's slow, lightly damped response that moves the damping most. To first order the
    estimate moves by ``h dr`` (``h`` the parameter rows of ``(J^T J)^-1 J^T``,
    :func:`~tdacm.identify.solve.parameter_rows`) with ``dr`` the residuals' response to the
    input noise. ``draws`` draws of that noise at its stated level (``sigma["tension"]``,
    relative, white per sample; averaged over the ``decimate`` samples of a fitted step) are
    simulated through the fitted model from the fitted window states. A window's residuals
    respond only to its own inputs, so the windows' shares ``c_w = h_w dr_w`` are independent
    and zero-mean: the covariance is ``sum_w E[c_w c_w^T]``, estimated by the mean over the
    draws (``seed``: the draws' generator)."""
    npar = len(prob.names)
    rel = float(prob.sigma.get("tension", 0.0))
    cov = np.zeros((npar, npar))
    if rel == 0.0 or npar == 0:
        return cov
    rng = np.random.default_rng(seed)
    values = prob.from_z(z[:npar])
    row = 0
    for s in prob.setups:
        r = s.rec
        na = r.model.system.n_a
        nrow = len(r.t) * s.kdim
        if na == 0:  # no tendon: no load cell
            row += nrow
            continue
        base = prob.measurement_residual(prob.predict(z, s, values), s, values)
        q0, qd0 = prob._states(z, s)
        hs = h[:, row : row + nrow].reshape(npar, len(r.t), s.kdim)
        nt = len(r.t)
        us = []
        for _ in range(draws):
            u = np.array(r.u, dtype=float, copy=True)
            u[:, -na:] *= 1.0 + rel / np.sqrt(decimate) * rng.standard_normal((nt, na))
            us.append(u)
        # every draw's windows in one parallel call
        first = (np.arange(draws)[:, None] * nt + s.starts[None, :]).ravel()
        pred = r.model.simulate_many(r.values(values), np.tile(q0, (draws, 1)),
                                     np.tile(qd0, (draws, 1)), first,
                                     np.tile(s.ends - s.starts, draws), first, draws * nt,
                                     np.vstack(us), r.dt, prob.substeps)  # fmt: skip
        drs = prob.measurement_residual(pred, s, values).reshape(draws, nt, s.kdim) - base
        for dr in drs:
            for a, b in zip(s.starts, s.ends, strict=True):
                c = np.einsum("ptk,tk->p", hs[:, a:b], dr[a:b])
                cov += np.outer(c, c)
        row += nrow
    return cov / draws


def basis_map(old_model, new_model) -> np.ndarray:
    """(n_new, n_old) matrix taking a state of ``old_model`` to the nearest of ``new_model``
    (the strain field projected on the new basis in L2 over the rod; the drone's coordinates
    unchanged): exact when the new basis contains the old one (``bending:0`` in ``bending:2``)."""
    x = np.linspace(0.0, 1.0, 64)
    bo = old_model.system.rod.basis(x).reshape(-1, old_model.system.rod.basis.n)
    bn = new_model.system.rod.basis(x).reshape(-1, new_model.system.rod.basis.n)
    ts = np.linalg.lstsq(bn, bo, rcond=None)[0]
    off = 6 if new_model.floating else 0
    out = np.zeros((new_model.system.n, old_model.system.n))
    out[:off, :off] = np.eye(off)
    out[off:, off:] = ts
    return out


def _warm_states(prob: Problem, z0: np.ndarray, warm) -> np.ndarray:
    """``z0`` with every recording's window states replaced by ``warm``'s (an earlier fit of
    the same recordings and windows on another basis, mapped by :func:`basis_map`) where that
    explains its measurements better than the inverse kinematics does (the tip pose alone
    leaves a richer basis's higher coefficients to the noise)."""
    wp = warm.problem
    npar = len(prob.names)
    for s in prob.setups:
        sw = next((w for w in wp.setups if w.rec.name == s.rec.name), None)
        if sw is None or len(sw.starts) != len(s.starts) or np.any(sw.starts != s.starts):
            continue
        no = sw.rec.model.system.n
        tm = basis_map(sw.rec.model, s.rec.model)
        xo = warm.z[sw.offset : sw.offset + len(sw.starts) * 2 * no].reshape(-1, 2 * no)
        xn = np.hstack([xo[:, :no] @ tm.T, xo[:, no:] @ tm.T])
        z1 = z0.copy()
        z1[s.offset : s.offset + xn.size] = xn.ravel()
        values = prob.from_z(z0[:npar])
        costs = [
            float(np.sum(prob.measurement_residual(prob.predict(z, s, values), s, values) ** 2))
            for z in (z0, z1)
        ]
        if costs[1] < costs[0]:
            z0 = z1
    return z0


def _ik(rec: Recording, k: int, values: dict, q_guess, problem: Problem):
    """The state at sample ``k`` that best explains its measurements (nominal model)."""
    model = rec.model
    sysm = model.build(rec.values(values))
    n = sysm.n
    floating = model.floating
    q_guess = np.array(q_guess, float)
    if floating:
        from ..lie.euler import euler_from_rotation

        g = rec.drone[k]
        q_guess[:3] = euler_from_rotation(g[:3, :3])
        q_guess[3:6] = g[:3, 3]
    off = 6 if floating else 0
    sp, sr = problem.sigma["position"], np.radians(problem.sigma["rotation_deg"])

    def res(qs):
        q = q_guess.copy()
        q[off:] = qs
        base, tip = model.poses(sysm, q[None])
        out = []
        if rec.tip is not None:
            out += [(tip[0, :3, 3] - rec.tip[k, :3, 3]) / sp,
                    _rotvec_err(rec.tip[k : k + 1, :3, :3], tip[:, :3, :3])[0] / sr]  # fmt: skip
        elif rec.pixels is not None:
            px = project_points(tip, model.camera_mount(values.get("camera_offset")),
                                rec.camera, rec.target_points)  # fmt: skip
            out.append(np.nan_to_num((px[0] - rec.pixels[k]).ravel(), nan=0.0))
        return np.concatenate(out)

    best = None
    for x0 in (q_guess[off:], np.zeros(n - off)):  # the previous state, and straight
        sol = least_squares(res, x0, method="lm", xtol=1e-12, ftol=1e-12)
        if best is None or sol.cost < best.cost:
            best = sol
    q = q_guess.copy()
    q[off:] = best.x
    return q


def initial_states(rec: Recording, starts, values: dict, problem: Problem) -> np.ndarray:
    """(S, 2n) segment states from the recording (inverse kinematics, central differences)."""
    n = rec.model.system.n
    out = np.zeros((len(starts), 2 * n))
    guess = np.zeros(n)
    nt = len(rec.t)
    for i, k in enumerate(starts):
        a, b = max(k - 1, 0), min(k + 1, nt - 1)
        qa = _ik(rec, a, values, guess, problem)
        qk = _ik(rec, k, values, qa, problem) if k != a else qa
        qb = _ik(rec, b, values, qk, problem)
        out[i, :n] = qk
        out[i, n:] = (qb - qa) / ((b - a) * rec.dt)
        guess = qk
    return out


@dataclass
class Identification:
    """The result of :func:`identify`."""

    names: list
    values: dict
    std: dict  # absolute standard deviations
    rel_std: dict  # relative (std / value)
    corr: np.ndarray
    start: dict
    nominal: dict
    cost: float
    residual_variance: float
    n_residuals: int
    nfev: int
    seconds: float
    success: bool
    message: str
    rms: dict = field(default_factory=dict)  # per recording: tip/drone position RMS (m)
    problem: Problem | None = None
    z: np.ndarray | None = None
    stages: list = field(default_factory=list)
    std_iid: dict = field(default_factory=dict)  # white-residual std (s^2 (J^T J)^-1)
    std_sandwich: dict = field(default_factory=dict)  # the sandwich's (residuals' correlation)
    std_noise: dict = field(default_factory=dict)  # the stated noise's (mocap and load cells)
    n_free: int = 0  # fitted variables: parameters and segment states
    lags: int = 0  # the sandwich's lag window (samples)
    rod_basis: str = ""  # the rod's strain basis fitted
    misfit: dict = field(default_factory=dict)  # see tdacm.identify.misfit
    selection: list = field(default_factory=list)  # the bases compared (select_basis)
    #: parameters stopped at their search bound (a factor SEARCH_FACTOR from the start): their
    #: standard deviation is not an uncertainty (the bound, not the data, holds them)
    at_bound: list = field(default_factory=list)

    def table(self) -> str:
        lines = [f"{'parameter':<14}{'estimate':>14}{'std':>12}{'rel std':>10}{'start':>14}"]
        for n in self.names:
            if n in self.at_bound:  # the bound holds it: no standard deviation to give
                spread = f"{'-':>12}{'at bound':>10}"
            else:
                spread = f"{self.std[n]:>12.3g}{100 * self.rel_std[n]:>9.2f}%"
            lines.append(f"{n:<14}{self.values[n]:>14.6g}{spread}{self.start[n]:>14.6g}")
        if self.at_bound:
            lines.append(
                f"at bound: {', '.join(self.at_bound)} stopped at the search bound (a factor "
                f"{SEARCH_FACTOR:g} from the start): give a --start nearer the value"
            )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "parameters": {
                n: {
                    "estimate": self.values[n],
                    "std": self.std[n],
                    "relative_std": self.rel_std[n],
                    "std_white_residuals": self.std_iid.get(n),
                    "std_sandwich": self.std_sandwich.get(n),
                    "std_noise_model": self.std_noise.get(n),
                    "start": self.start[n],
                    "unit": PARAMETERS[n].unit,
                    "at_search_bound": n in self.at_bound,
                }
                for n in self.names
            },
            "correlation": {"names": self.names, "matrix": self.corr.tolist()},
            "cost": self.cost,
            "residual_variance": self.residual_variance,
            "n_residuals": self.n_residuals,
            "nfev": self.nfev,
            "seconds": self.seconds,
            "success": self.success,
            "message": self.message,
            "rms": self.rms,
            "basis": self.rod_basis,
            "n_free": self.n_free,
            "sandwich_lags": self.lags,
            "misfit": self.misfit,
            "basis_selection": self.selection,
        }

    def predictions(self):
        """Per recording ``(recording, Prediction)`` at the estimates."""
        if self.stages:
            return [x for st in self.stages for x in st.predictions()]
        p = self.problem
        return [(s.rec, p.predict(self.z, s)) for s in p.setups]


@compiling("identify")
def identify(
    recordings,
    params,
    start: dict | None = None,
    segment: float | None = None,
    sigma: dict | None = None,
    use: str = "auto",
    max_nfev: int = 40,
    substeps: int = 1,
    fixed: dict | None = None,
    decimate: int = 1,
    stage: str | None = None,
    warm: Identification | None = None,
) -> Identification:
    """Estimate ``params`` (names of :data:`~tdacm.identify.params.PARAMETERS`) from
    ``recordings`` (one :class:`~tdacm.identify.data.Recording` or several of the same robot).

    ``start``: starting values (default the recordings' nominal, i.e. their scenario's robot);
    ``segment``: the multiple-shooting window (s; default :func:`default_segment`); ``sigma``:
    noise levels weighting the residuals (default :data:`~tdacm.identify.experiments.NOISE`);
    ``use``: ``"mocap"`` (poses), ``"camera"`` (tip camera pixels only), ``"all"`` or
    ``"auto"`` (poses when the recording has them); ``fixed``: values of parameters not
    fitted that replace the nominal ones (e.g. an earlier stage's estimates); ``decimate``:
    fit every k-th sample with RK4 steps of k sample periods (halves the cost at k = 2 and
    100 Hz: 20 ms steps keep the paper robot's RK4 error near 2e-5 m, far below the motion
    capture's noise; the inputs are averaged over each step). Progress (the parameters, then
    each iteration's cost) is logged at INFO (stderr with ``tdacm identify``, hidden by
    ``-q``), each line starting with ``stage`` when given. ``warm``: an earlier fit of the
    same recordings (e.g. on a simpler strain basis) whose window states start this one's
    where they explain the data better than the inverse kinematics."""
    t0 = time.perf_counter()
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    if not recs:
        raise ValueError("no recording given")
    if not (isinstance(decimate, int) and decimate >= 1):
        raise ValueError(f"decimate must be an integer >= 1, got {decimate!r}")
    recs = [r.decimated(decimate) for r in recs]
    names = parse_params(params)
    nominal = {}
    for n in names:
        carriers = [r for r in recs if n in r.model.nominal]
        if not carriers:
            raise ValueError(f"{n} needs a flying-base recording")
        nominal[n] = carriers[0].model.nominal[n]
    merged = {**nominal, **(start or {})}
    start = {n: merged[n] for n in names}
    prob = Problem(recs, names, sigma, segment, substeps, use, fixed)
    z0 = prob.initial(start)
    if warm is not None and warm.problem is not None:
        z0 = _warm_states(prob, z0, warm)
    lb, ub = np.full(z0.size, -np.inf), np.full(z0.size, np.inf)
    npar = len(names)
    # a log-parameter stays within a factor SEARCH_FACTOR of its start, a linear one within
    # SEARCH_FACTOR scales (a solver's first steps can otherwise leave the stable models)
    lb[:npar] = z0[:npar] - np.log(SEARCH_FACTOR)
    ub[:npar] = z0[:npar] + np.log(SEARCH_FACTOR)
    for i, n in enumerate(names):
        if not PARAMETERS[n].log:
            lb[i], ub[i] = z0[i] - SEARCH_FACTOR, z0[i] + SEARCH_FACTOR
            if PARAMETERS[n].nonnegative:
                lb[i] = max(lb[i], 0.0)  # friction only dissipates
    label = f"identify ({stage})" if stage else "identify"
    log.info("%s: fitting %s to %d recording%s (at most %d evaluations)", label,
             ", ".join(names), len(recs), "s" if len(recs) != 1 else "", max_nfev)  # fmt: skip
    iterations = 0

    def jacobian(z):  # once per iteration of the solver: its progress
        nonlocal iterations
        iterations += 1
        r = prob.residual(z)
        log.info("%s: iteration %d, cost %.6g (%.0f s)", label, iterations, float(r @ r),
                 time.perf_counter() - t0)  # fmt: skip
        return prob.jacobian(z)

    sol = levenberg_marquardt(prob.residual, jacobian, z0, prob.blocks, lb, ub, ftol=1e-7,
                              xtol=1e-7, max_nfev=max_nfev)  # fmt: skip
    jac = sol.jac
    m, nz = jac.shape
    cost = float(2 * sol.cost)
    s2 = cost / max(m - nz, 1)
    npar = len(names)
    h, f_inv = parameter_rows(jac, prob.blocks)
    cov_iid = s2 * f_inv
    cov_sw, lags = sandwich_covariance(prob, jac, sol.fun, npar)
    # the stated noise model: the motion capture's (white, F^-1) and the load cells'
    cov_noise = f_inv + input_noise_covariance(prob, sol.x, h, decimate)
    var = np.maximum(np.diag(cov_noise), np.diag(cov_sw))
    dn = np.sqrt(np.clip(np.diag(cov_noise), 1e-300, None))
    cp = cov_noise / np.outer(dn, dn) * np.sqrt(np.outer(var, var))
    at_bound = [n for i, n in enumerate(names) if min(sol.x[i] - lb[i], ub[i] - sol.x[i]) < 1e-6]
    if at_bound:
        log.warning("estimates at the search bound (factor %g from the start): %s",
                    SEARCH_FACTOR, ", ".join(at_bound))  # fmt: skip
    sd = np.sqrt(np.clip(np.diag(cp), 0, None))
    corr = cp / np.outer(sd, sd) if np.all(sd > 0) else np.full_like(cp, np.nan)
    values = {n: v for n, v in prob.from_z(sol.x[:npar]).items() if n in names}
    sd_iid = np.sqrt(np.clip(np.diag(cov_iid), 0, None))
    sd_sw = np.sqrt(np.clip(np.diag(cov_sw), 0, None))
    sd_noise = np.sqrt(np.clip(np.diag(cov_noise), 0, None))
    std, rel, std_iid, std_sw, std_noise = {}, {}, {}, {}, {}
    for i, n in enumerate(names):
        p = PARAMETERS[n]
        std[n] = float(values[n] * sd[i]) if p.log else float(p.scale * sd[i])
        rel[n] = float(sd[i]) if p.log else float(std[n] / max(abs(values[n]), 1e-300))
        std_iid[n] = float(values[n] * sd_iid[i]) if p.log else float(p.scale * sd_iid[i])
        std_sw[n] = float(values[n] * sd_sw[i]) if p.log else float(p.scale * sd_sw[i])
        std_noise[n] = float(values[n] * sd_noise[i]) if p.log else float(p.scale * sd_noise[i])
    res = Identification(
        names, values, std, rel, corr, start, nominal, cost, s2, m, int(sol.nfev),
        time.perf_counter() - t0, bool(sol.success), str(sol.message), {}, prob, sol.x,
        std_iid=std_iid, n_free=nz, lags=lags, rod_basis=recs[0].model.basis,
        std_sandwich=std_sw, std_noise=std_noise, at_bound=at_bound,
    )  # fmt: skip
    for rec, pred in res.predictions():
        key = rec.name
        rms = {"tip_m": float(np.sqrt(np.mean((pred.tip[:, :3, 3] - rec.tip[:, :3, 3]) ** 2)))
               if rec.tip is not None else None}  # fmt: skip
        if rec.drone is not None:
            e = pred.base[:, :3, 3] - rec.drone[:, :3, 3]
            rms["drone_m"] = float(np.sqrt(np.mean(e**2)))
        res.rms[key] = rms
    log.info("%s: identified %s in %.1f s (%d evaluations)", label, ", ".join(names),
             res.seconds, res.nfev)  # fmt: skip
    return res


def identify_staged(recordings, params, start=None, **kw) -> Identification:
    """Identify in two stages, as a lab does: the rod's parameters from the clamped-rod
    recordings, then the drone's from the flying ones with the rod's estimates held (a joint
    fit gives the same estimates at several times the cost: the flying recordings carry 16
    segment states per window). Returns one :class:`Identification` (the stages' estimates,
    standard deviations and a block-diagonal correlation; ``seconds`` and ``nfev`` summed)."""
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    clamped = [r for r in recs if not r.model.floating]
    flying = [r for r in recs if r.model.floating]
    params = parse_params(params)
    drone = [n for n in params if PARAMETERS[n].floating_only]
    rod = [n for n in params if n not in drone]
    warm = kw.pop("warm", None)
    if not (clamped and flying and rod and drone):
        if warm is not None and warm.stages:
            warm = warm.stages[0]
        return identify(recs, params, start, warm=warm, **kw)
    wa, wb = warm.stages if warm is not None and warm.stages else (warm, None)
    a = identify(clamped, rod, start, stage="stage 1/2, the rod, clamped recordings", warm=wa,
                 **kw)  # fmt: skip
    b = identify(flying, drone, start, fixed=a.values,
                 stage="stage 2/2, the drone, flying recordings", warm=wb, **kw)  # fmt: skip
    names = rod + drone
    corr = np.zeros((len(names), len(names)))
    corr[: len(rod), : len(rod)] = a.corr
    corr[len(rod) :, len(rod) :] = b.corr
    return Identification(
        names, {**a.values, **b.values}, {**a.std, **b.std}, {**a.rel_std, **b.rel_std}, corr,
        {**a.start, **b.start}, {**a.nominal, **b.nominal}, a.cost + b.cost,
        max(a.residual_variance, b.residual_variance), a.n_residuals + b.n_residuals,
        a.nfev + b.nfev, a.seconds + b.seconds, a.success and b.success,
        f"rod: {a.message}; drone: {b.message}", {**a.rms, **b.rms}, None, None,
        stages=[a, b], std_iid={**a.std_iid, **b.std_iid}, n_free=a.n_free + b.n_free,
        std_sandwich={**a.std_sandwich, **b.std_sandwich}, std_noise={**a.std_noise, **b.std_noise},
        lags=max(a.lags, b.lags), rod_basis=a.rod_basis, at_bound=a.at_bound + b.at_bound,
    )  # fmt: skip
