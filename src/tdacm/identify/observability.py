"""Which parameters an experiment identifies: the Fisher information of the fit.

At given parameter values (a synthetic recording's truth), the Jacobian of the normalized
residuals (:class:`~tdacm.identify.fit.Problem`) gives the Fisher information ``J^T J``; the
segment states are eliminated (Schur complement), leaving the information about the scaled
parameters (``log`` of the positive ones). Its eigenvalues say which combinations the data
pin down: the rank (eigenvalues above ``rtol`` times the largest), the condition number, and
the Cramer-Rao bound of each parameter's relative standard deviation, ``sqrt(diag(F^-1))``.
"""

from __future__ import annotations

import numpy as np

from .fit import Problem
from .params import PARAMETERS


def fisher_report(recordings, params, values: dict | None = None, rtol: float = 1e-8, **kw):
    """``{"eigenvalues", "rank", "condition", "crlb"}`` of ``params`` from ``recordings`` at
    ``values`` (default: the recordings' truth, else their nominal values); ``crlb`` maps
    each parameter to the bound on its relative (log-parameters) or scaled standard
    deviation, infinite when the information is singular."""
    recs = list(recordings) if not hasattr(recordings, "model") else [recordings]
    names = list(params)
    if values is None:
        values = {}
        for r in recs:
            values.update({k: v for k, v in r.model.nominal.items() if k in names})
            values.update({k: v for k, v in r.truth.items() if k in names})
    prob = Problem(recs, names, **kw)
    z = prob.initial(values)
    # segment states at the truth: the true states when the recording has them
    for s in prob.setups:
        if s.rec.q is not None:
            qd = np.gradient(s.rec.q, s.rec.dt, axis=0)
            x = np.hstack([s.rec.q[s.starts], qd[s.starts]])
            z[s.offset : s.offset + x.size] = x.ravel()
    f = prob.fisher(prob.jacobian(z))
    ev = np.linalg.eigvalsh(f)
    top = max(float(ev.max()), 1e-300)
    rank = int(np.sum(ev > rtol * top))
    cond = float(top / ev.min()) if ev.min() > 0 else float("inf")
    try:
        crlb_v = (
            np.sqrt(np.clip(np.diag(np.linalg.inv(f)), 0, None)) if rank == len(names) else None
        )
    except np.linalg.LinAlgError:
        crlb_v = None
    crlb = {
        n: (float(crlb_v[i]) if crlb_v is not None else float("inf")) for i, n in enumerate(names)
    }
    return {"eigenvalues": ev, "rank": rank, "condition": cond, "crlb": crlb, "fisher": f}


#: The study of ``docs/identify.md``: (experiment, measurements, parameters).
STUDY = (
    ("tendon-steps", "mocap", ("E", "damping", "tip_mass", "radius")),
    ("tendon-steps+tendon-steps-loaded", "mocap", ("E", "damping", "tip_mass", "radius")),
    ("tendon-chirp", "mocap", ("E", "damping", "tip_mass", "radius")),
    ("tendon-steps", "mocap", ("E", "damping", "tip_mass", "radius", "friction", "viscous")),
    ("hover", "mocap", ("drone_mass",)),
    ("hover", "mocap", ("drone_mass", "inertia_x", "inertia_y", "inertia_z")),
    ("hover", "mocap", ("drone_mass", "thrust")),
    ("camera-chirp", "mocap", ("E", "damping", "tip_mass", "radius")),
    ("camera-chirp", "camera", ("E", "damping", "tip_mass", "radius")),
    ("camera-chirp", "camera", ("E", "damping", "tip_mass", "radius", "camera_offset")),
    ("camera-chirp", "camera", ("E", "damping", "radius")),
)


def observability_table(seed: int = 0, study=STUDY) -> str:
    """The markdown table of ``docs/identify.md``: per experiment and measurement set, the
    rank and condition of the Fisher information and each parameter's Cramer-Rao bound (at
    the synthetic truth, with the documented noise)."""
    from .experiments import synthesize

    cache = {}
    rows = [
        "| experiment | measured | parameters | rank | condition | Cramer-Rao bound (1 sigma) |",
        "|---|---|---|---|---|---|",
    ]
    for exp, use, names in study:
        key = (exp, use)
        if key not in cache:
            cache[key] = [synthesize(e, seed=seed, pixels=use == "camera") for e in exp.split("+")]
        recs = cache[key]
        rec = recs[0]
        rep = fisher_report(recs, list(names), values={**rec.model.nominal, **rec.truth,
                            "camera_offset": 0.0}, use=use)  # fmt: skip
        bounds = ", ".join(_bound(n, rep["crlb"][n]) for n in names)
        rows.append(
            f"| {exp} | {'motion capture' if use == 'mocap' else 'tip camera (1 px)'} | "
            f"{', '.join(names)} | {rep['rank']}/{len(names)} | {rep['condition']:.2g} | {bounds} |"
        )
    return "\n".join(rows)


def _bound(name: str, b: float) -> str:
    p = PARAMETERS[name]
    if not np.isfinite(b):
        return f"{name} -"
    if p.log:
        return f"{name} {100 * b:.2g} %"
    return f"{name} {b * p.scale:.2g} {p.unit}"
