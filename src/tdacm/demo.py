"""``tdacm demo``: the paper's TD-ACM hovering while a tendon is stepped.

A small PD stabilizer (attitude and altitude, through ``Gamma^-1``) keeps the drone near hover;
at ``t = 0.5 s`` tendon 0 is pulled to 1 N and the rod bends, dragging the drone with it: the
coupled response the model exists for.  Writes a figure, the time series (NPZ and CSV) and a
summary to ``out``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .system import paper_system, simulate


def hover_stabilizer(system, z_ref=3.0, step_time=0.5, tension=1.0):
    """``u(t, q, qd)``: PD attitude/altitude hover control plus a tendon step (a demo aid, not
    the paper's controller)."""
    gamma = system.base.gamma[[0, 1, 2, 5]]
    gamma_inv = np.linalg.inv(gamma)
    weight = system.total_mass * 9.81
    kp_att, kd_att = 2.0, 0.6
    kp_z, kd_z = 4.0, 3.0

    def u(t, q, qd):
        tau = -kp_att * q[:3] - kd_att * qd[:3]
        thrust = (weight + kp_z * (z_ref - q[5]) - kd_z * qd[5]) / max(
            np.cos(q[0]) * np.cos(q[1]), 0.5
        )
        motors = gamma_inv @ np.array([tau[0], tau[1], tau[2], thrust])
        tendons = np.zeros(system.n_a)
        if t >= step_time:
            tendons[0] = tension
        return np.concatenate([motors, tendons])

    return u


def static_strains(system, q0, tension: float) -> np.ndarray:
    """The rod's static strains with tendon 1 pulled to ``tension`` (N) and the drone held at
    ``q0``'s pose: the rod's weight and the camera's pull it back toward straight, so this is
    below the weightless ``tension * offset / EI``. The demo's strains oscillate about it."""
    from .system.statics import solve_equilibrium

    u = np.zeros(system.n_u)
    u[4 if system.floating else 0] = tension
    base = q0[:6] if system.floating else None
    return np.asarray(solve_equilibrium(system, u=u, base_q=base))[system.n - system.n_s :]


def run_demo(out: str | Path = "out/demo", duration: float = 4.0, dt: float = 2e-3) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    system = paper_system()
    q0 = np.zeros(system.n)
    q0[5] = 3.0
    ufun = hover_stabilizer(system)
    t0 = time.perf_counter()
    res = simulate(
        system, q0, None, duration=duration, dt=dt, u=ufun, record_dt=0.01, progress=True
    )
    wall = time.perf_counter() - t0
    tips = np.array([system.tip_pose(q)[:3, 3] for q in res.q])
    np.savez(out / "hover_tendon_step.npz", t=res.t, q=res.q, qd=res.qd, u=res.u, tip=tips)
    header = (
        "t," + ",".join(["phi", "theta", "psi", "x", "y", "z", "k_y", "k_z"]) + ",tip_x,tip_y,tip_z"
    )
    np.savetxt(
        out / "hover_tendon_step.csv",
        np.column_stack([res.t, res.q, tips]),
        delimiter=",",
        header=header,
        comments="",
    )

    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    axes[0, 0].plot(res.t, res.q[:, 6], label=r"$q_{s1}$ ($k_y$)")
    axes[0, 0].plot(res.t, res.q[:, 7], label=r"$q_{s2}$ ($k_z$)")
    axes[0, 0].set_ylabel("rod strain (1/m)")
    axes[0, 1].plot(res.t, np.degrees(res.q[:, :3]), label=[r"$\phi$", r"$\theta$", r"$\psi$"])
    axes[0, 1].set_ylabel("drone attitude (deg)")
    axes[1, 0].plot(res.t, res.q[:, 3:6] - q0[3:6], label=["x", "y", "z - 3"])
    axes[1, 0].set_ylabel("drone position change (m)")
    axes[1, 1].plot(res.t, tips - tips[0], label=["x", "y", "z"])
    axes[1, 1].set_ylabel("tip displacement (m)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.axvline(0.5, color="k", lw=0.6, ls="--")
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Paper TD-ACM hovering, tendon 0 stepped to 1 N at t = 0.5 s")
    fig.tight_layout()
    fig.savefig(out / "hover_tendon_step.png", dpi=130)
    plt.close(fig)
    summary = {
        "duration_s": duration,
        "dt_s": dt,
        "wall_time_s": wall,
        "real_time_factor": duration / wall,
        # the strains oscillate about the static equilibrium: the last sample is a snapshot
        "final_q_s": res.q[-1, 6:].tolist(),
        "static_q_s_drone_held": static_strains(system, q0, 1.0).tolist(),
        "tip_displacement_m": (tips[-1] - tips[0]).tolist(),
        "completed": res.completed,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
