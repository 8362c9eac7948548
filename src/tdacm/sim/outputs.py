"""The run folder: its layout, and the data a run writes into it (``run_scenario(out=...)``).

This module writes the data (summary, resolved scenario, time series); the figures and the
video are drawn from them by :mod:`tdacm.viz` (``tdacm run`` does both, ``tdacm plot`` redraws
the figures of a folder).

=====================  ===================================================================
``summary.json``       the run's metrics (RMSE, times to 0.01/0.001, switch time, ...)
``scenario.toml``      the resolved scenario (defaults filled in): the folder is self-contained
``timeseries.npz``     every logged series (:data:`LOG_KEYS`, one row per control step) and
                       ``desired_points`` (4, 2) and ``q_star`` (the desired configuration)
``timeseries.csv``     the same series, one column per component (names in the header)
``timeseries.json``    the CSV's columns: name, source series, unit, meaning
``KIND.png/.pdf``      figures (:data:`FIGURE_KINDS`, drawn by :mod:`tdacm.viz.figures`)
``scene.png``          C_L at the start and at the desired pose, C_G at the start
``video.mp4``          with ``--video``: C_L | C_G with captions (H.264)
=====================  ===================================================================

Rewriting into a folder first removes the files a previous run left there
(:func:`clear_run_outputs`), so a folder never mixes two runs.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from .._validate import npz_problem
from ..loop.logger import LOG_KEYS, SCALAR_SERIES, SERIES_INFO, VECTOR_SERIES  # noqa: F401
from .scenario import ScenarioError, load_scenario, scenario_to_toml

Q_NAMES = ["phi", "theta", "psi", "x", "y", "z", "q_s1", "q_s2"]

#: Files a run writes (removed before a new run writes into the same folder).
RUN_FILES = (
    "summary.json",
    "scenario.toml",
    "timeseries.npz",
    "timeseries.csv",
    "timeseries.json",
    "video.mp4",
    "replay.gif",
    "replay.mp4",
    "run.rrd",
)


#: The figures of a run folder, ``KIND.png`` and ``KIND.pdf``, in the order they are drawn.
FIGURE_KINDS = (
    "state_errors",
    "tracking_errors",
    "actuation",
    "features",
    "feature_error",
    "camera_twist",
    "strain_rates",
    "snapshots",
    "lyapunov",
    "estimation",
    "contact",  # servoing into contact ([touch]): forces, image error, tensions, drone
    "arms",  # several arms ([[robot.arms]]): each arm's image error, strains and tensions
)


def _figure_files():
    return [f"{k}.{e}" for k in FIGURE_KINDS for e in ("png", "pdf", "svg")]


def clear_run_outputs(out, keep=("scene.png",)) -> list[str]:
    """Remove the outputs of a previous run from folder ``out`` (only the files a run writes;
    anything else is left alone). Returns the names removed."""
    out = Path(out)
    removed = []
    if not out.is_dir():
        return removed
    for name in (*RUN_FILES, *_figure_files(), "scene.png"):
        p = out / name
        if name not in keep and p.is_file():
            p.unlink()
            removed.append(name)
    return removed


def _unit(kind: str, coord: str) -> str:
    ang = coord in ("phi", "theta", "psi")
    pos = coord in ("x", "y", "z")
    if kind == "q":
        return "rad" if ang else "m" if pos else "1/m"
    if kind == "qd":
        return "rad/s" if ang else "m/s" if pos else "1/(m s)"
    if kind == "tau":
        return "N m" if ang else "N" if pos else "N m^2"
    return kind


def columns(a: dict, floating: bool, n_a: int | None = None):
    """CSV table and column descriptions of the log ``a`` (every series, known or not)."""
    t = np.asarray(a["t"], float)
    T = len(t)
    qn = Q_NAMES if floating else Q_NAMES[6:]
    nq = np.asarray(a["q"]).reshape(T, -1).shape[1] if "q" in a else len(qn)
    if nq != len(qn):  # richer rods: q_s1 .. q_sN
        qn = (Q_NAMES[:6] if floating else []) + [
            f"q_s{i + 1}" for i in range(nq - (6 if floating else 0))
        ]
    feat = ["p_phi", "p_theta", "p_psi", "p_x", "p_y", "p_z"]
    feat_units = ["rad"] * 3 + ["-"] * 3
    tw = ["w_x", "w_y", "w_z", "v_x", "v_y", "v_z"]
    tw_units = ["rad/s"] * 3 + ["m/s"] * 3
    cols, info = [], []

    def add(key, values, names, units):
        values = np.asarray(values, dtype=float).reshape(T, -1)
        if len(names) != values.shape[1]:
            names = [f"{key}[{i}]" for i in range(values.shape[1])]
            units = [units[0] if len(set(units)) == 1 else "?"] * values.shape[1]
        cols.append(values)
        meaning = SERIES_INFO.get(key, ("?", "(not documented)"))[1]
        for j, (nm, un) in enumerate(zip(names, units, strict=True)):
            info.append({"name": nm, "series": key, "index": j, "unit": un, "meaning": meaning})

    for key in a:
        if key in ("desired_points", "q_star"):
            continue
        v = np.asarray(a[key])
        if v.shape[:1] != (T,):
            continue
        width = int(np.prod(v.shape[1:])) if v.ndim > 1 else 1
        kind = SERIES_INFO.get(key, ("-", ""))[0]
        if key == "t":
            add(key, v, ["t"], ["s"])
        elif kind in ("q", "qd", "tau"):
            suffix = {"q": "", "qd": "", "q_d": "_d", "qd_d": "_d", "q_ref": "_ref",
                      "tau": "", "delta_hat": "", "q_hat": "_hat",
                      "qd_hat": "_hat"}.get(key, "")  # fmt: skip
            prefix = {"qd": "d", "qd_d": "d", "tau": "tau_", "delta_hat": "delta_",
                      "qd_hat": "d"}.get(key, "")  # fmt: skip
            add(key, v, [f"{prefix}{c}{suffix}" for c in qn], [_unit(kind, c) for c in qn])
        elif key == "P_diag" and width == 2 * len(qn):
            names = [f"var_{c}" for c in qn] + [f"var_d{c}" for c in qn]
            units = [f"({_unit('q', c)})^2" for c in qn] + [f"({_unit('qd', c)})^2" for c in qn]
            add(key, v, names, units)
        elif key == "u":
            m = 4 if floating else 0
            names = [f"f{i + 1}" for i in range(m)] + [f"T{i + 1}" for i in range(width - m)]
            add(key, v, names, ["N"] * width)
        elif key in ("features", "feature_error"):
            pre = "" if key == "features" else "e_"
            add(key, v, [pre + f for f in feat], feat_units)
        elif key == "twist":
            add(key, v, tw, tw_units)
        elif key in ("points_local", "points_virtual"):
            tag = "L" if key == "points_local" else "V"
            names = [f"{c}{k + 1}_{tag}" for k in range(width // 2) for c in ("x", "y")]
            add(key, v, names, ["-"] * width)
        elif key in ("rmse_arms", "rmse_true_arms", "detected_arms"):  # several arms
            add(key, v, [f"{key.removesuffix('_arms')}_arm{i}" for i in range(width)],
                ["-"] * width)  # fmt: skip
        elif key in ("points_arms", "points_local_arms"):  # (T, k, 4, 2): arm i's point j
            k, tag = width // 8, "V" if key == "points_arms" else "L"
            add(key, v, [f"{c}{j + 1}_{tag}_arm{i}" for i in range(k) for j in range(4)
                         for c in ("x", "y")], ["-"] * width)  # fmt: skip
        elif key == "twist_arms":  # (T, k, 6)
            k = width // 6
            add(key, v, [f"{c}_arm{i}" for i in range(k) for c in tw],
                [u for _ in range(k) for u in tw_units])  # fmt: skip
        elif key in ("contact_tip", "contact_rod"):
            add(key, v, [f"{key}_{c}" for c in "xyz"], ["N"] * 3)
        elif width == 1:
            add(key, v, [key], [SERIES_INFO.get(key, ("-",))[0]])
        else:
            add(key, v, [f"{key}[{i}]" for i in range(width)], ["?"] * width)
    table = np.hstack(cols) if cols else np.zeros((T, 0))
    return table, info


def write_timeseries(out: Path, a: dict, floating: bool, n_a=None) -> None:
    """``timeseries.csv`` (every series, one column per component) and its sidecar
    ``timeseries.json`` (per column: name, series, index, unit, meaning)."""
    table, info = columns(a, floating, n_a)
    names = [c["name"] for c in info]
    np.savetxt(out / "timeseries.csv", table, delimiter=",", header=",".join(names),
               comments="", fmt="%.8g")  # fmt: skip
    side = {
        "file": "timeseries.csv",
        "rows": "one per control step",
        "missing": "NaN (e.g. points when the target is not detected)",
        "unit_legend": {
            "-": "dimensionless (normalized image coordinates: pixels / focal length)",
            "1/m": "rod strain coordinate (curvature amplitude)",
            "N m^2": "generalized force conjugate to a strain coordinate",
        },
        "columns": info,
    }
    (out / "timeseries.json").write_text(json.dumps(side, indent=1))


def write_run(
    out: Path, a: dict, summary: dict, desired_pts, system=None, *, scenario=None
) -> None:
    """Write the data of a run folder (see the module docstring): ``scenario.toml`` (the
    resolved :class:`~tdacm.sim.Scenario`, when given; it also gives ``q_star``),
    ``timeseries.npz`` / ``.csv`` / ``.json`` and ``summary.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clear_run_outputs(out)
    extra = {}
    if scenario is not None:
        (out / "scenario.toml").write_text(scenario_to_toml(scenario))
        extra["q_star"] = np.asarray(scenario.config.desired.q, float)
    np.savez_compressed(
        out / "timeseries.npz", desired_points=np.asarray(desired_pts), **extra, **a
    )
    floating = bool(system.floating) if system is not None else scenario.floating
    n_a = getattr(system, "n_a", None)
    if len(a.get("t", ())):
        write_timeseries(out, a, floating, n_a)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))


class RunDirError(ValueError):
    """A folder that is not a complete ``tdacm run`` output (the message names it)."""


def load_run(run_dir):
    """``(arrays, summary, scenario)`` of a run folder; the scenario from its
    ``scenario.toml`` (self-contained folder), else by the name in ``summary.json``."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunDirError(f"RUN_DIR {run_dir} does not exist or is not a folder")
    npz = run_dir / "timeseries.npz"
    if not npz.is_file():
        raise RunDirError(f"{npz} not found: is {run_dir} a `tdacm run` output folder?")
    try:
        with np.load(npz) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as exc:
        raise RunDirError(
            f"{npz} cannot be read, not written by `tdacm run` ({npz_problem(exc)})"
        ) from None
    missing = [k for k in ("t", "q") if k not in arrays]
    if missing:
        raise RunDirError(f"{npz} has no {', '.join(missing)} array: not written by `tdacm run`")
    if len(arrays["q"]) != len(arrays["t"]):
        raise RunDirError(f"{npz}: q has {len(arrays['q'])} rows for {len(arrays['t'])} times")
    sj = run_dir / "summary.json"
    try:
        summary = json.loads(sj.read_text()) if sj.is_file() else {}
    except (OSError, ValueError) as exc:
        raise RunDirError(f"{sj} cannot be read: {exc}") from None
    toml = run_dir / "scenario.toml"
    try:
        if toml.is_file():
            scenario = load_scenario(toml)
        elif "scenario" in summary:
            scenario = load_scenario(summary["scenario"])
        else:
            raise RunDirError(f"{run_dir} has neither scenario.toml nor summary.json")
    except ScenarioError as exc:
        raise RunDirError(f"{run_dir}: cannot load its scenario: {exc}") from None
    return arrays, summary, scenario
