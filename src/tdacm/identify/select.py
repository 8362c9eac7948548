"""The rod's strain basis from the data: fit each candidate, compare, choose.

:func:`select_basis` fits the same parameters on every candidate basis (``"bending:0"``, the
paper's constant curvature, ``"bending:1"``, ...; any ``robot.rod.basis`` spelling), each
with the fit of :func:`~tdacm.identify.fit.identify_staged`, and compares them

* by the **Bayesian information criterion** ``BIC = chi^2 + k ln m`` (``chi^2`` the sum of
  the noise-normalized squared residuals, i.e. ``-2 log L`` up to a constant with the stated
  noise; ``k`` the fitted variables: the parameters and every window's state, ``2 n`` per
  window, so a richer basis pays for its extra strain coordinates; ``m`` the residuals), with
  the AIC ``chi^2 + 2 k`` reported beside it;
* on **held-out recordings** when given (not used by any fit): the residual variance ratio of
  their prediction (:func:`~tdacm.identify.misfit.held_out_ratio`).

The choice: with held-out recordings, the basis with the fewest strain coordinates whose
held-out ratio is within :data:`HELD_OUT_TOLERANCE` of the best (a richer basis that predicts
no better is not chosen); without, the smallest BIC. Every candidate gets its misfit
diagnosis (:func:`~tdacm.identify.misfit.diagnose`): a basis flagged there is inadequate.
"""

from __future__ import annotations

import logging
import math

from .fit import identify_staged
from .misfit import diagnose, held_out_ratio

log = logging.getLogger(__name__)

#: A candidate predicting the held-out data within this factor of the best counts as as good.
HELD_OUT_TOLERANCE = 0.10


def select_basis(recordings, params, bases, held_out=(), start=None, decimate=1, **kw):
    """Fit ``params`` on each of ``bases`` and return the chosen fit (an
    :class:`~tdacm.identify.fit.Identification` whose ``selection`` lists every candidate:
    basis, strain coordinates, chi^2, k, m, BIC, AIC, held-out ratio, misfit, estimates,
    seconds; and whose ``misfit`` is the chosen one's). A richer basis starts from the
    previous candidate's estimates and window states (mapped onto it)."""
    recs = list(recordings)
    held = list(held_out)
    bases = list(dict.fromkeys(bases))
    if not bases:
        raise ValueError("no basis given")
    rows, fits = [], []
    prev = None
    for b in bases:
        rb = [r.with_basis(b) for r in recs]
        st = dict(start or {})
        if prev is not None and prev.success:
            st.update(prev.values)
        log.info("basis %s: %d strain coordinates", b, rb[0].model.system.n - (
            6 if rb[0].model.floating else 0))  # fmt: skip
        res = identify_staged(rb, params, st, decimate=decimate, warm=prev, **kw)
        ho = {}
        for h in held:
            hb = h.with_basis(b).decimated(decimate)
            ho[h.name] = held_out_ratio(res.values, hb, kw.get("segment"), kw.get("sigma"))
        res.misfit = diagnose(res, ho, fitted=res.names)
        k, m = res.n_free, res.n_residuals
        rows.append({
            "basis": b,
            "strain_coordinates": int(rb[0].model.system.rod.basis.n),
            "chi2": res.cost,
            "k": int(k),
            "m": int(m),
            "bic": res.cost + k * math.log(m),
            "aic": res.cost + 2 * k,
            "held_out_variance_ratio": (max(ho.values()) if ho else None),
            "residual_variance": res.residual_variance,
            "misfit": res.misfit["detected"],
            "estimates": dict(res.values),
            "relative_std": dict(res.rel_std),
            "seconds": res.seconds,
        })  # fmt: skip
        fits.append(res)
        prev = res
    best_bic = min(range(len(rows)), key=lambda i: rows[i]["bic"])
    if held:
        best = min(r["held_out_variance_ratio"] for r in rows)
        ok = [i for i, r in enumerate(rows)
              if r["held_out_variance_ratio"] <= best * (1 + HELD_OUT_TOLERANCE)]  # fmt: skip
        chosen = min(ok, key=lambda i: (rows[i]["strain_coordinates"], i))
        rule = "held-out prediction (the fewest strain coordinates within 10 % of the best)"
    else:
        chosen = best_bic
        rule = "BIC (no held-out recording)"
    for i, r in enumerate(rows):
        r["chosen"] = i == chosen
        r["bic_best"] = i == best_bic
        r["rule"] = rule
    res = fits[chosen]
    res.selection = rows
    return res


def selection_table(rows) -> str:
    """The candidates as a text table (stdout of ``tdacm identify --bases``)."""
    lines = [
        f"{'basis':<12}{'n_s':>4}{'chi2/m':>10}{'BIC':>14}{'AIC':>14}{'held-out':>10}"
        f"{'misfit':>8}{'s':>7}"
    ]
    for r in rows:
        ho = r["held_out_variance_ratio"]
        lines.append(
            f"{r['basis']:<12}{r['strain_coordinates']:>4}{r['chi2'] / r['m']:>10.3g}"
            f"{r['bic']:>14.6g}{r['aic']:>14.6g}{(f'{ho:.3g}' if ho is not None else '-'):>10}"
            f"{('YES' if r['misfit'] else 'no'):>8}{r['seconds']:>7.0f}"
            + ("  <- chosen" if r["chosen"] else "")
        )
    lines.append(f"chosen by {rows[0]['rule']}")
    return "\n".join(lines)
