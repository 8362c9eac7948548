"""Outputs of an identification: the ``[robot]`` TOML block, the report figure, the files."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from .fit import Identification
from .params import PARAMETERS

log = logging.getLogger(__name__)


def robot_toml(result: Identification) -> str:
    """A ``[robot]`` block with the estimates, ready to paste into a scenario.

    Keys are those of the scenario's ``[robot]`` section (``[robot.rod] youngs_modulus,
    damping, tip_mass``, ``[robot.tendons] radius``, ``[robot.drone] mass, inertia``,
    ``[robot.cameras.local] offset``). Estimates without a scenario key (the tendon friction,
    the thrust constant) are written as comments: the thrust constant ``k_T`` rescales the
    lab's thrust commands (the model's inputs are thrusts in newtons)."""
    import tomli_w

    v = result.values
    data: dict = {}
    comments = []
    inertia = {}
    for n in result.names:
        p = PARAMETERS[n]
        sec, key = p.toml[0], p.toml[1]
        if n in ("friction", "viscous", "thrust"):
            comments.append(
                f"# {n} = {v[n]:.6g} +- {result.std[n]:.2g} {p.unit}: {p.doc} (no scenario key)"
            )
            continue
        if key == "inertia":
            inertia[p.toml[2]] = v[n]
            continue
        if sec == "cameras":
            data.setdefault("cameras", {}).setdefault("local", {})[p.toml[2]] = float(v[n])
            continue
        data.setdefault(sec, {})[key] = float(f"{v[n]:.6g}")
    if inertia:
        base = [result.nominal.get(f"inertia_{a}") for a in "xyz"]
        vals = [float(f"{inertia.get(i, base[i]):.6g}") for i in range(3)]
        data.setdefault("drone", {})["inertia"] = vals
    if result.rod_basis and _parses(result.rod_basis):
        data.setdefault("rod", {})["basis"] = result.rod_basis
    body = tomli_w.dumps({"robot": data}) if data else ""
    head = "# identified by tdacm identify (estimate +- 1 sigma in the report)\n"
    if result.misfit.get("detected"):
        head += (
            f"# WARNING: misfit: the residuals are {result.misfit['variance_ratio']:.3g} x the "
            "measurement noise; these values absorb a model error (identification.json, "
            "misfit)\n"
        )
    return head + body + ("\n".join(comments) + "\n" if comments else "")


def _parses(basis: str) -> bool:
    from ..sim.robot import parse_basis

    try:
        parse_basis(basis)
    except ValueError:
        return False
    return True


def correlation_text(result: Identification) -> str:
    names = result.names
    w = max(8, max(len(n) for n in names) + 1)
    lines = [" " * w + "".join(f"{n:>{w}}" for n in names)]
    for i, n in enumerate(names):
        lines.append(f"{n:<{w}}" + "".join(f"{c:>{w}.3f}" for c in result.corr[i]))
    return "\n".join(lines)


def report_figure(result: Identification, path) -> Path:
    """Fit vs data and residuals of every recording (tip position; drone position when
    flying): one row per recording, PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    preds = result.predictions()
    fig, axes = plt.subplots(len(preds), 2, figsize=(12, 3.2 * len(preds)), squeeze=False)
    for row, (rec, pred) in enumerate(preds):
        ax, axr = axes[row]
        which = [("tip", rec.tip, pred.tip)]
        if rec.drone is not None:
            which.append(("drone", rec.drone, pred.base))
        for label, meas, model in which:
            if meas is None:
                continue
            for i, c in enumerate("xyz"):
                ax.plot(rec.t, meas[:, i, 3], ".", ms=1.5, color=f"C{i}", alpha=0.5)
                ax.plot(rec.t, model[:, i, 3], "-", lw=0.8, color=f"C{i}",
                        label=f"{label} {c}" + (" (model)" if i == 0 else ""))  # fmt: skip
                axr.plot(rec.t, 1e3 * (model[:, i, 3] - meas[:, i, 3]), lw=0.6, color=f"C{i}",
                         label=f"{label} {c}")  # fmt: skip
        p = result.problem
        setups = p.setups if p is not None else []
        for s in setups:
            if s.rec is rec:
                for k in s.starts[1:]:
                    ax.axvline(rec.t[k], color="0.85", lw=0.6, zorder=0)
        ax.set_title(f"{rec.name}: measured (dots) and fitted model (lines)")
        ax.set_ylabel("position (m)")
        axr.set_title(f"{rec.name}: residuals (model - measured)")
        axr.set_ylabel("mm")
        ax.legend(fontsize=7, ncol=3, loc="upper right")
        axr.legend(fontsize=7, ncol=3, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_outputs(result: Identification, out) -> list[Path]:
    """``identification.json`` (estimates, standard deviations, correlations, fit data),
    ``robot.toml`` (the ``[robot]`` block), ``identification.png`` (fit and residuals) in
    folder ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "identification.json", out / "robot.toml"]
    paths[0].write_text(json.dumps(result.to_dict(), indent=2))
    paths[1].write_text(robot_toml(result))
    paths.append(report_figure(result, out / "identification.png"))
    log.info("identification written to %s", out)
    return paths


def truth_errors(result: Identification, truth: dict) -> dict:
    """Relative error of every estimate against a synthetic recording's hidden value."""
    return {
        n: float((result.values[n] - truth[n]) / truth[n])
        for n in result.names
        if n in truth and truth[n] != 0
    }


__all__ = ["correlation_text", "report_figure", "robot_toml", "truth_errors", "write_outputs"]
