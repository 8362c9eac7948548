"""Is the fitted model adequate? Its residuals against the stated measurement noise.

A least-squares fit always returns estimates; whether they mean anything depends on the model
explaining the data down to the noise. :func:`diagnose` compares, after a fit:

* the **residual variance ratio** ``s^2 = |r|^2 / (m - n_z)`` of the noise-normalized
  residuals: 1 when the model and the stated noise are right (the tension noise, which
  drives the rod and is treated as residual, gives 1.1-1.3 on the shipped experiments);
* the **whiteness** of the residuals: their lag-1 autocorrelation ``rho_1`` pooled over the
  measured channels within each shooting window (0 for white noise, within
  ``2 / sqrt(m)``; near 1 when a smooth model error dominates);
* the **held-out prediction**: the residual variance ratio of held-out recordings predicted
  with the fitted parameters held (:func:`held_out_ratio`: only the window states fitted);
* the **integration step** against the model's fastest mode (eigenvalues of the linearized
  dynamics at the first sample): RK4 at ``|lambda| h`` near its stability limit (2.8)
  misrepresents the fast modes a richer basis brings (the shooting switches to the L-stable
  ROS34PW2 beyond ``RK4_LIMIT`` at the nominal values; a fitted model far from them can still
  cross it).

When one is beyond its limit the fit is flagged ``misfit.detected`` with the likely causes and
remedies (a richer strain basis, tendon friction, the sample rate / step, the stated noise).
``tdacm identify --strict`` then exits with :data:`EXIT_MISFIT`.
"""

from __future__ import annotations

import numpy as np

from ..system import kernels as K
from .fit import Problem
from .model import RK4_LIMIT
from .solve import levenberg_marquardt

#: Exit code of ``tdacm identify --strict`` when the misfit is detected (1: failure, 2: usage).
EXIT_MISFIT = 3
#: Residual variance ratio above which the model does not explain the data to the noise.
VARIANCE_LIMIT = 3.0
#: Lag-1 autocorrelation of the residuals above which they are far from white.
WHITENESS_LIMIT = 0.5
#: Held-out residual variance ratio above which the prediction is beyond the noise.
HELD_OUT_LIMIT = 3.0
#: ``|lambda|_max h`` above which the RK4 step is too coarse for the fastest mode.
STEP_LIMIT = 2.0


def _stages(res):
    return res.stages if res.stages else [res]


def residual_statistics(res) -> dict:
    """Per recording: ``variance_ratio`` (mean square of the normalized residuals) and
    ``lag1`` (their lag-1 autocorrelation within the shooting windows)."""
    out = {}
    for st in _stages(res):
        p = st.problem
        values = p.from_z(st.z[: len(p.names)])
        for s in p.setups:
            r = p.measurement_residual(p.predict(st.z, s, values), s, values)
            num = den = 0.0
            for a, b in zip(s.starts, s.ends, strict=True):
                x = r[a:b]
                num += float(np.sum(x[1:] * x[:-1]))
                den += float(np.sum(x * x))
            out[s.rec.name] = {
                "variance_ratio": float(np.mean(r * r)),
                "lag1": num / max(den, 1e-300),
                "samples": int(len(r)),
            }
    return out


def fastest_mode(res) -> dict:
    """The largest ``|lambda|`` (1/s) of the fitted model's dynamics linearized at each
    recording's first sample (finite differences of eq. (17)'s forward dynamics), and
    ``|lambda| h`` with ``h`` the fit's RK4 step (the recordings' sample period, decimated)."""
    out = {}
    for st in _stages(res):
        p = st.problem
        values = p.from_z(st.z[: len(p.names)])
        for s in p.setups:
            rec = s.rec
            sysm = rec.model.build(rec.values(values))
            m, loads = sysm.model_arrays, sysm.loads.packed()
            pred = p.predict(st.z, s, values)
            q, qd, u = pred.q[0].copy(), pred.qd[0].copy(), rec.u[0].copy()
            n = len(q)
            a0, _ = K.forward_dynamics(q, qd, u, m, loads)
            jac = np.zeros((2 * n, 2 * n))
            jac[:n, n:] = np.eye(n)
            eps = 1e-6
            for j in range(2 * n):
                qj, qdj = q.copy(), qd.copy()
                if j < n:
                    qj[j] += eps
                else:
                    qdj[j - n] += eps
                aj, _ = K.forward_dynamics(qj, qdj, u, m, loads)
                jac[n:, j] = (aj - a0) / eps
            lam = float(np.max(np.abs(np.linalg.eigvals(jac))))
            stiff = rec.model.fastest_rate() * rec.dt > RK4_LIMIT
            out[rec.name] = {"lambda_max": lam, "step": rec.dt, "lambda_h": lam * rec.dt,
                             "integrator": "ros34pw2" if stiff else "rk4"}  # fmt: skip
    return out


def held_out_ratio(values: dict, recording, segment=None, sigma=None, max_nfev: int = 15):
    """Residual variance ratio of ``recording`` (not used by the fit) predicted with the
    parameters ``values`` held: the windows' initial states (the same shooting windows as a
    fit) are fitted, nothing else. 1 for a model right to the noise."""
    prob = Problem([recording], [], sigma=sigma, segment=segment, fixed=values)
    z0 = prob.initial({})
    sol = levenberg_marquardt(prob.residual, prob.jacobian, z0, prob.blocks, ftol=1e-6,
                              xtol=1e-8, max_nfev=max_nfev)  # fmt: skip
    return float(2 * sol.cost / max(len(sol.fun) - len(z0), 1))


def diagnose(res, held_out: dict | None = None, fitted=()) -> dict:
    """The ``misfit`` section of ``identification.json``: the statistics above, their limits,
    ``detected``, and ``causes`` (each ``{"cause", "evidence", "remedy"}``, likeliest first).
    ``held_out``: recording name -> :func:`held_out_ratio`; ``fitted``: the parameter names
    (tendon friction is suggested only when it was not fitted)."""
    stats = residual_statistics(res)
    modes = fastest_mode(res)
    ratio = float(res.residual_variance)
    m = sum(v["samples"] for v in stats.values())
    lag1 = max((v["lag1"] for v in stats.values()), default=0.0)
    # the L-stable ROS34PW2 step (a stiff model, see IdentModel.simulate) has no such limit
    worst_step = max((v["lambda_h"] for v in modes.values() if v["integrator"] == "rk4"),
                     default=0.0)  # fmt: skip
    held = dict(held_out or {})
    held_worst = max(held.values(), default=None)
    flags = {
        "variance": ratio > VARIANCE_LIMIT,
        "whiteness": lag1 > WHITENESS_LIMIT,
        "held_out": held_worst is not None and held_worst > HELD_OUT_LIMIT,
        "step": worst_step > STEP_LIMIT,
    }
    detected = flags["variance"] or flags["held_out"] or flags["step"]
    causes = []
    if detected and (flags["whiteness"] or flags["held_out"]):
        causes.append({
            "cause": f"the model's structure: the strain basis {res.rod_basis or 'of the scenario'} "
                     "cannot take the backbone's shape (its sag under gravity and the tip load, "
                     "uneven bending near the clamp)",
            "evidence": f"residual variance {ratio:.3g} x the noise, lag-1 autocorrelation "
                        f"{lag1:.2f} (white: 0)",
            "remedy": "compare richer bases: tdacm identify ... --bases "
                      "bending:0,bending:1,bending:2 --held-out HELD_OUT_RECORDING",
        })  # fmt: skip
        if not ({"friction", "viscous"} & set(fitted)):
            causes.append({
                "cause": "tendon friction (the guides' capstan loss: the tension delivered "
                         "differs from the one measured, by the direction of motion)",
                "evidence": "correlated residuals; friction not fitted",
                "remedy": "add friction,viscous to --params",
            })  # fmt: skip
    if flags["step"]:
        causes.append({
            "cause": "the sample rate: the fit's RK4 step is coarse for the model's fastest mode",
            "evidence": f"|lambda|_max h = {worst_step:.2g} (limit {STEP_LIMIT:g})",
            "remedy": "fit with --decimate 1, or record at a higher rate",
        })  # fmt: skip
    if flags["variance"] and not flags["whiteness"] and not flags["held_out"]:
        causes.append({
            "cause": "the stated measurement noise: the residuals are nearly white but larger",
            "evidence": f"residual variance {ratio:.3g} x the noise, lag-1 autocorrelation "
                        f"{lag1:.2f}",
            "remedy": "give the motion capture's real noise level (NOISE / sigma)",
        })  # fmt: skip
    return {
        "detected": bool(detected),
        "variance_ratio": ratio,
        "variance_limit": VARIANCE_LIMIT,
        "lag1_autocorrelation": lag1,
        "lag1_white_bound": 2.0 / np.sqrt(max(m, 1)),
        "whiteness_limit": WHITENESS_LIMIT,
        "held_out_variance_ratio": held,
        "held_out_limit": HELD_OUT_LIMIT,
        "fastest_mode": modes,
        "step_limit": STEP_LIMIT,
        "flags": flags,
        "per_recording": stats,
        "causes": causes,
    }


def summary(misfit: dict) -> str:
    """One stderr paragraph: what is off and what to do."""
    if not misfit.get("detected"):
        return ""
    lines = [
        f"MISFIT: the model does not explain the data to the measurement noise (residual "
        f"variance {misfit['variance_ratio']:.3g} x the noise, limit {VARIANCE_LIMIT:g}; lag-1 "
        f"autocorrelation {misfit['lag1_autocorrelation']:.2f})"
        + (
            f"; held-out prediction {max(misfit['held_out_variance_ratio'].values()):.3g} x "
            f"the noise"
            if misfit["held_out_variance_ratio"]
            else ""
        )
        + ": the estimates absorb the model error and their standard deviations do not cover it."
    ]
    for c in misfit["causes"]:
        lines.append(f"  likely cause: {c['cause']} ({c['evidence']}); remedy: {c['remedy']}")
    return "\n".join(lines)
