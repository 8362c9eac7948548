"""Run folder: ``timeseries.npz``, ``timeseries.csv``, ``summary.json``, figures like the
paper's (``state_errors.png``, ``actuation.png``, ``features.png``) and optionally
``video.mp4`` (C_L and C_G side by side)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

Q_NAMES = ["phi", "theta", "psi", "x", "y", "z", "q_s1", "q_s2"]

#: One value per control step (written as single CSV columns).
SCALAR_SERIES = (
    "rmse",
    "rmse_raw",
    "rmse_measured",
    "rmse_true",
    "target_error_deg",
    "mode",
    "V",
    "detected_local",
    "detected_global",
    "thrust_saturated",
    "tension_saturated",
)
#: Vector series (one CSV column per component), then the scalar ones: what the runner logs.
VECTOR_SERIES = (
    "t",
    "q",
    "qd",
    "q_d",
    "qd_d",
    "u",
    "tau",
    "q_ref",
    "features",
    "feature_error",
    "points_local",
    "points_virtual",
    "twist",
    "delta_hat",
)
LOG_KEYS = VECTOR_SERIES + SCALAR_SERIES


def _columns(a: dict, system):
    n = system.n
    qn = Q_NAMES if system.floating else Q_NAMES[6:]
    un = ([f"f{i + 1}" for i in range(4)] if system.floating else []) + [
        f"T{i + 1}" for i in range(system.n_a)
    ]
    cols, names = [a["t"][:, None]], ["t"]
    for key, labels in (
        ("q", qn),
        ("qd", [f"d{x}" for x in qn]),
        ("q_d", [f"{x}_d" for x in qn]),
        ("tau", [f"tau_{x}" for x in qn]),
        ("u", un),
        ("features", ["p_phi", "p_theta", "p_psi", "p_x", "p_y", "p_z"]),
        ("feature_error", [f"e_{x}" for x in ("phi", "theta", "psi", "x", "y", "z")]),
        ("twist", ["w_x", "w_y", "w_z", "v_x", "v_y", "v_z"]),
    ):
        cols.append(a[key].reshape(len(a["t"]), -1))
        names += labels
    pts = a["points_virtual"].reshape(len(a["t"]), 8)
    cols.append(pts)
    names += [f"{c}{k + 1}" for k in range(4) for c in ("x", "y")]
    for key in SCALAR_SERIES:
        cols.append(a[key].astype(float)[:, None])
        names.append(key)
    assert len(names) == sum(c.shape[1] for c in cols), (n, names)
    return np.hstack(cols), names


def write_all(out: Path, a: dict, summary: dict, desired_pts, frames, system) -> None:
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out / "timeseries.npz", desired_points=np.asarray(desired_pts), **a)
    if len(a["t"]):
        table, names = _columns(a, system)
        np.savetxt(
            out / "timeseries.csv",
            table,
            delimiter=",",
            header=",".join(names),
            comments="",
            fmt="%.8g",
        )
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if len(a["t"]):
        plot_all(out, a, summary, desired_pts, system)
    if frames:
        write_video(out / "video.mp4", frames)


def write_video(path: Path, frames, fps: int = 50) -> None:
    import cv2

    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for f in frames:
        vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    vw.release()


def plot_all(out: Path, a: dict, summary: dict, desired_pts, system) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = a["t"]
    qn = Q_NAMES if system.floating else Q_NAMES[6:]
    mode = a["mode"]
    sw = summary.get("mode_switch_time")

    def mark(ax):
        if sw is not None:
            ax.axvline(sw, color="k", ls=":", lw=1, label="switch to IBVS")

    # state errors
    e = a["q"] - a["q_d"]
    fig, axes = plt.subplots(
        2 if system.floating else 1, 1, figsize=(8, 6 if system.floating else 3.5), squeeze=False
    )
    if system.floating:
        ax = axes[0, 0]
        for i in range(2, 6):
            ax.plot(t, a["q"][:, i] - (3.0 if i == 5 else 0.0) * 0 - a["q_d"][:, i], label=qn[i])
        for i in range(2):
            ax.plot(t, a["q"][:, i] - a["q_ref"][:, i], "--", label=f"{qn[i]} - {qn[i]}_d")
        ax.set_ylabel("drone error")
        ax.legend(ncol=3, fontsize=8)
        mark(ax)
        ax = axes[1, 0]
    else:
        ax = axes[0, 0]
    off = system.n - system.n_s
    for i in range(system.n_s):
        ax.plot(t, e[:, off + i], label=qn[off + i])
    ax.set_ylabel("rod error")
    ax.set_xlabel("t (s)")
    ax.legend(fontsize=8)
    mark(ax)
    fig.suptitle(f"{summary['scenario']}: state errors q - q_d")
    fig.tight_layout()
    fig.savefig(out / "state_errors.png", dpi=110)
    plt.close(fig)

    # actuation
    u = a["u"]
    fig, axes = plt.subplots(
        2 if system.floating else 1, 1, figsize=(8, 6 if system.floating else 3.5), squeeze=False
    )
    row = 0
    if system.floating:
        for i in range(4):
            axes[0, 0].plot(t, u[:, i], label=f"f{i + 1}")
        axes[0, 0].set_ylabel("thrust (N)")
        axes[0, 0].legend(ncol=4, fontsize=8)
        mark(axes[0, 0])
        row = 1
    for i in range(system.n_a):
        axes[row, 0].plot(t, u[:, -system.n_a + i], label=f"T{i + 1}")
    axes[row, 0].set_ylabel("tension (N)")
    axes[row, 0].set_xlabel("t (s)")
    axes[row, 0].legend(ncol=4, fontsize=8)
    mark(axes[row, 0])
    fig.suptitle(f"{summary['scenario']}: actuation")
    fig.tight_layout()
    fig.savefig(out / "actuation.png", dpi=110)
    plt.close(fig)

    # features in the image plane + RMSE
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.8))
    pts = a["points_virtual"]
    from ..vision import LOCAL_CAMERA

    cam = LOCAL_CAMERA
    for k in range(4):
        uv = np.column_stack((cam.fx * pts[:, k, 0] + cam.cx, cam.fy * pts[:, k, 1] + cam.cy))
        ax0.plot(uv[:, 0], uv[:, 1], lw=1.2, label=f"point {k + 1}")
        good = np.flatnonzero(np.isfinite(uv[:, 0]))
        if good.size:
            ax0.plot(*uv[good[0]], "o", color=f"C{k}")
        dp = np.asarray(desired_pts)[k]
        ax0.plot(cam.fx * dp[0] + cam.cx, cam.fy * dp[1] + cam.cy, "x", color=f"C{k}", ms=10)
    ax0.set_xlim(0, cam.width)
    ax0.set_ylim(cam.height, 0)
    ax0.set_aspect("equal")
    ax0.set_xlabel("u (px)")
    ax0.set_ylabel("v (px)")
    ax0.set_title("features (o start, x desired)")
    ax0.legend(fontsize=8)
    ax1.semilogy(t, a["rmse"], label="normalized RMSE")
    ax1.axhline(0.01, color="r", ls="--", lw=1, label="0.01")
    ax1.axhline(0.001, color="g", ls=":", lw=1, label="0.001")
    rec = mode == 1
    if rec.any():
        ax1.fill_between(t, 1e-5, 10, where=rec, color="0.9", label="recovery")
    ax1.set_ylim(max(1e-5, np.nanmin(a["rmse"]) / 3) if np.isfinite(a["rmse"]).any() else 1e-5, 2)
    ax1.set_xlabel("t (s)")
    ax1.set_title("normalized RMSE")
    ax1.legend(fontsize=8)
    fig.suptitle(f"{summary['scenario']}: feature trajectories")
    fig.tight_layout()
    fig.savefig(out / "features.png", dpi=110)
    plt.close(fig)

    # Lyapunov function
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.semilogy(t, np.maximum(a["V"], 1e-12))
    ax.set_xlabel("t (s)")
    ax.set_ylabel("V (known part)")
    mark(ax)
    fig.tight_layout()
    fig.savefig(out / "lyapunov.png", dpi=110)
    plt.close(fig)
