"""Figures of a closed-loop run, like the paper's (PNG and vector PDF).

Simulation figures (paper, "Simulation Results"):

* ``state_errors``: the error to the *desired configuration* ``q - q*`` (paper: altitude 3 m,
  everything else 0), drone angles (deg), drone position (m) and rod strains (1/m) on separate
  axes;
* ``tracking_errors``: the low-level tracking error ``q - q_d(t)`` (roll/pitch against the drone
  loop's reference ``q_ref``), same layout;
* ``actuation``: rotor thrusts and tendon tensions (N);
* ``features``: the four points in the image plane of C_L (px; start, path, desired) and the
  normalized RMSE (log scale).

Experiment panels (paper, Tests A-C: (a)-(d)):

* ``feature_error``: the advanced-feature error ``p* - p*_d``, angular (rad) and translational
  (normalized image units) components;
* ``camera_twist``: the commanded local camera twist ``[w; v]`` (rad/s, m/s);
* ``strain_rates``: the time derivative of the rod's strain coordinates (1/(m s));
* ``snapshots``: four C_L frames at chosen times, re-rendered from the stored ``q``, with the
  detected (stored) and desired points.

State estimation (``estimation.source = "estimated"``, ``docs/estimation.md``):

* ``estimation``: true vs estimated rod strains and drone position with 2-sigma bands (written
  only when the log has a covariance).

Every figure marks the switch from recovery to IBVS with a legend entry and shades the recovery
phase. Functions read only the log keys they need and skip a figure whose keys are missing;
extra keys are ignored, so the figures survive new log fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..loop.data import PHASES
from ..sim.outputs import FIGURE_KINDS

#: Figure kinds, in the order :func:`plot_run` writes them (the run folder's layout).
KINDS = FIGURE_KINDS

_ANGLES = (r"$\phi$", r"$\theta$", r"$\psi$")
_POS = ("$x$", "$y$", "$z$")
_STYLE = {
    "font.family": "serif",
    "mathtext.fontset": "dejavuserif",
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.titlesize": 9,
    "legend.fontsize": 7.5,
    "legend.framealpha": 0.85,
    "lines.linewidth": 1.3,
}


@dataclass
class RunData:
    """What the figures read: the log ``arrays`` (see :data:`tdacm.loop.logger.LOG_KEYS`), the
    summary, and the scenario's facts."""

    arrays: dict
    summary: dict
    floating: bool
    q_star: np.ndarray | None = None
    desired_points: np.ndarray | None = None  # (4, 2) normalized (C_V floating, C_L fixed)
    geometry: object = None  # viz._scene.Geometry, for the snapshots
    title: str = ""
    camera: object = None  # C_L's intrinsics (default: the paper's LOCAL_CAMERA)

    @property
    def cam(self):
        if self.camera is not None:
            return self.camera
        from ..vision import LOCAL_CAMERA

        return LOCAL_CAMERA

    @property
    def t(self):
        return np.asarray(self.arrays["t"], float)

    def has(self, *keys) -> bool:
        return all(k in self.arrays and len(self.arrays[k]) == len(self.t) for k in keys)

    @property
    def n_base(self) -> int:
        return 6 if self.floating else 0

    @property
    def n_arms(self) -> int:
        """The robot's arms: the geometry's, else the width of the per-arm series, else 1."""
        if self.geometry is not None and getattr(self.geometry, "arms", ()):
            return len(self.geometry.arms)
        if "rmse_arms" in self.arrays:
            return int(np.asarray(self.arrays["rmse_arms"]).reshape(len(self.t), -1).shape[1])
        return 1

    def strain_names(self, n):
        """The strain coordinates' labels; with several arms, each arm's own (arm ``i``'s
        ``q_s1, q_s2, ...``; the arms share one basis in the shipped scenarios, else the
        coordinates are numbered over the robot)."""
        ns, k = n - self.n_base, self.n_arms
        if k > 1 and ns % k == 0:
            per = ns // k
            return [f"arm {i} $q_{{s{j + 1}}}$" for i in range(k) for j in range(per)]
        return [f"$q_{{s{i + 1}}}$" for i in range(ns)]

    def tension_names(self, n_a):
        """The tendons' labels (``T_1 ...``; with several arms, arm ``i``'s ``T_1 ...``)."""
        k = self.n_arms
        if k > 1 and n_a % k == 0:
            per = n_a // k
            return [f"arm {i} $T_{j + 1}$" for i in range(k) for j in range(per)]
        return [f"$T_{i + 1}$" for i in range(n_a)]

    def arm_series(self, key, shape):
        """Per-arm series ``key`` as (T, k, *shape), or ``None`` when the log lacks it."""
        if not self.has(key):
            return None
        return np.asarray(self.arrays[key], float).reshape(len(self.t), self.n_arms, *shape)

    def arm_desired(self, arm: int):
        """Arm ``arm``'s desired points in its servo camera (4, 2): the stored reference for
        arm 0, the true points at ``q*`` for the others (the geometry's); ``None`` when
        unknown."""
        if arm == 0 and self.desired_points is not None:
            return self.desired_points
        if self.geometry is not None and self.q_star is not None:
            return self.geometry.servo_points(self.q_star, arm)
        return None

    def switch_times(self):
        """Times where the mode goes from recovery (1) to IBVS (0)."""
        if "mode" in self.arrays and len(self.arrays["mode"]) == len(self.t):
            m = np.asarray(self.arrays["mode"])
            return [float(self.t[i]) for i in np.flatnonzero((m[:-1] == 1) & (m[1:] == 0)) + 1]
        sw = self.summary.get("mode_switch_time")
        return [float(sw)] if sw is not None else []


def _mark(ax, rd: RunData, legend=True, **legend_kw):
    """Shade the recovery phase, mark the switch to IBVS; then the legend (so both are in it)."""
    t = rd.t
    if "mode" in rd.arrays and len(rd.arrays["mode"]) == len(t):
        rec = np.asarray(rd.arrays["mode"]) == 1
        if rec.any():
            lo, hi = ax.get_ylim()
            ax.fill_between(
                t, lo, hi, where=rec, color="0.88", lw=0, label="recovery (C_G plan)", zorder=0
            )
            ax.set_ylim(lo, hi)
    for i, sw in enumerate(rd.switch_times()):
        ax.axvline(sw, color="k", ls=":", lw=1.1, label="switch to IBVS" if i == 0 else None)
    if legend:
        ax.legend(**legend_kw)


def _finish(fig, rd: RunData, what: str, out: Path, name: str, formats) -> list[Path]:
    import matplotlib.pyplot as plt

    fig.suptitle(f"{rd.title}: {what}" if rd.title else what, fontsize=10)
    fig.tight_layout()
    paths = []
    for ext in formats:
        p = out / f"{name}.{ext}"
        fig.savefig(p, dpi=110 if ext == "png" else None)
        paths.append(p)
    plt.close(fig)
    return paths


def _config_axes(plt, rd: RunData, err, ylabel_prefix, angle_labels=_ANGLES):
    """Three (floating) or one (fixed) axes of a configuration-space error ``err`` (T, n)."""
    t = rd.t
    n = err.shape[1]
    rows = 3 if rd.floating else 1
    fig, axes = plt.subplots(rows, 1, figsize=(6.4, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    if rd.floating:
        for i in range(3):
            axes[0].plot(t, np.degrees(err[:, i]), label=angle_labels[i])
        axes[0].set_ylabel(f"{ylabel_prefix} angle (deg)")
        for i in range(3):
            axes[1].plot(t, err[:, 3 + i], label=_POS[i])
        axes[1].set_ylabel(f"{ylabel_prefix} position (m)")
    ax = axes[-1]
    for i, name in enumerate(rd.strain_names(n)):
        ax.plot(t, err[:, rd.n_base + i], label=name)
    ax.set_ylabel(f"{ylabel_prefix} strain (1/m)")
    ax.set_xlabel("time (s)")
    for a in axes:
        a.axhline(0, color="0.5", lw=0.6)
        _mark(a, rd, ncol=4, loc="best")
    return fig


def fig_state_errors(rd: RunData, out, formats):
    if not rd.has("q") or rd.q_star is None:
        return []
    import matplotlib.pyplot as plt

    err = np.asarray(rd.arrays["q"]) - rd.q_star
    fig = _config_axes(plt, rd, err, "error")
    return _finish(
        fig, rd, "state error to the desired configuration $q - q^*$", out, "state_errors", formats
    )


def fig_tracking_errors(rd: RunData, out, formats):
    if not rd.has("q", "q_d"):
        return []
    import matplotlib.pyplot as plt

    q = np.asarray(rd.arrays["q"])
    err = q - np.asarray(rd.arrays["q_d"])
    labels = _ANGLES
    if rd.floating and rd.has("q_ref"):
        # roll and pitch are not commanded by the servo: the drone loop's reference instead
        err[:, :2] = q[:, :2] - np.asarray(rd.arrays["q_ref"])[:, :2]
        labels = (r"$\phi - \phi_{ref}$", r"$\theta - \theta_{ref}$", r"$\psi$")
    fig = _config_axes(plt, rd, err, "tracking", labels)
    return _finish(
        fig, rd, "low-level tracking error $q - q_d(t)$", out, "tracking_errors", formats
    )


def fig_actuation(rd: RunData, out, formats):
    if not rd.has("u"):
        return []
    import matplotlib.pyplot as plt

    u = np.asarray(rd.arrays["u"])
    t = rd.t
    rows = 2 if rd.floating else 1
    fig, axes = plt.subplots(rows, 1, figsize=(6.4, 2.1 * rows + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    n_f = min(4, u.shape[1]) if rd.floating else 0  # a malformed u draws what it has
    if rd.floating:
        for i in range(n_f):
            axes[0].plot(t, u[:, i], label=f"$f_{i + 1}$")
        axes[0].set_ylabel("rotor thrust (N)")
    n_a = u.shape[1] - n_f
    for i, name in enumerate(rd.tension_names(n_a)):
        axes[-1].plot(t, u[:, -n_a + i], label=name)
    axes[-1].set_ylabel("tendon tension (N)")
    axes[-1].set_xlabel("time (s)")
    for a in axes:
        _mark(a, rd, ncol=5, loc="best")
    return _finish(fig, rd, "input actuation", out, "actuation", formats)


def _to_px(xy, cam):
    xy = np.asarray(xy, float)
    return np.stack((cam.fx * xy[..., 0] + cam.cx, cam.fy * xy[..., 1] + cam.cy), axis=-1)


def _image_axes(ax, cam, title: str) -> None:
    """An image panel's frame: the camera's pixel area (v downward), equal axes, labels,
    ``title`` and the legend."""
    ax.set_xlim(0, cam.width)
    ax.set_ylim(cam.height, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(title)
    ax.legend(loc="lower right")


def _image_panel(ax, uv, desired_px, cam, title):
    """The four points' paths ``uv`` (T, 4, 2) px in an image of ``cam``, their start and the
    desired points."""
    for k in range(uv.shape[1]):
        ax.plot(uv[:, k, 0], uv[:, k, 1], lw=1.2, color=f"C{k}", label=f"point {k + 1}")
        good = np.flatnonzero(np.isfinite(uv[:, k, 0]))
        if good.size:
            ax.plot(*uv[good[0], k], "o", color=f"C{k}", mfc="none")
    if desired_px is not None:
        ax.plot(desired_px[:, 0], desired_px[:, 1], "x", color="k", ms=8, label="desired")
    ax.plot([], [], "o", color="0.3", mfc="none", label="start")
    _image_axes(ax, cam, title)


def _rmse_panel(ax, rd: RunData, curves):
    """Normalized RMSE curves ``[(values, label, style), ...]`` (log scale) with the 0.01 and
    0.001 lines."""
    fin = []
    for r, label, style in curves:
        r = np.asarray(r, float)
        ax.semilogy(rd.t, r, style, label=label)
        fin.append(r[np.isfinite(r) & (r > 0)])
    fin = np.concatenate(fin) if fin else np.zeros(0)
    ax.axhline(0.01, color="C3", ls="--", lw=0.9, label="0.01")
    ax.axhline(0.001, color="C2", ls="--", lw=0.9, label="0.001")
    ax.set_ylim(max(1e-5, fin.min() / 3) if fin.size else 1e-5, 2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("normalized RMSE (-)")
    ax.set_title("normalized image error")
    _mark(ax, rd, loc="best")


def _fig_features_arms(rd: RunData, out, formats):
    """:func:`fig_features` of several arms: each arm's points in its servo camera and each
    arm's normalized RMSE (the servo's and the true one)."""
    pts = rd.arm_series("points_arms", (4, 2))
    r = rd.arm_series("rmse_arms", ())
    if pts is None and r is None:
        return []
    import matplotlib.pyplot as plt

    k, cam = rd.n_arms, rd.cam
    fig, axes = plt.subplots(1, k + 1, figsize=(4.4 * (k + 1), 4.0), squeeze=False)
    where = "virtual camera $C_V$" if rd.floating else "$C_L$"
    for i in range(k):
        ax = axes[0, i]
        if pts is not None:
            d = rd.arm_desired(i)
            _image_panel(ax, _to_px(pts[:, i], cam), None if d is None else _to_px(d, cam), cam,
                         f"arm {i}: image features ({where})")  # fmt: skip
        else:
            ax.set_axis_off()
    curves = []
    if r is not None:
        rt = rd.arm_series("rmse_true_arms", ())
        for i in range(k):
            curves.append((r[:, i], f"arm {i} (servo)", f"C{i}-"))
            if rt is not None:
                curves.append((rt[:, i], f"arm {i} (true)", f"C{i}--"))
    _rmse_panel(axes[0, k], rd, curves)
    return _finish(fig, rd, "each arm's feature trajectories and normalized error", out,
                   "features", formats)  # fmt: skip


def fig_features(rd: RunData, out, formats):
    if rd.n_arms > 1:
        return _fig_features_arms(rd, out, formats)
    if not rd.has("points_virtual") and not rd.has("rmse"):
        return []
    import matplotlib.pyplot as plt

    cam = rd.cam
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9.6, 4.0))
    if rd.has("points_virtual"):
        uv = _to_px(rd.arrays["points_virtual"], cam)
        for k in range(uv.shape[1]):
            ax0.plot(uv[:, k, 0], uv[:, k, 1], lw=1.2, color=f"C{k}", label=f"point {k + 1}")
            good = np.flatnonzero(np.isfinite(uv[:, k, 0]))
            if good.size:
                ax0.plot(*uv[good[0], k], "o", color=f"C{k}", mfc="none")
        if rd.desired_points is not None:
            dp = _to_px(rd.desired_points, cam)
            ax0.plot(dp[:, 0], dp[:, 1], "x", color="k", ms=8, label="desired")
        ax0.plot([], [], "o", color="0.3", mfc="none", label="start")
    _image_axes(
        ax0, cam, "image features" + (" (virtual camera $C_V$)" if rd.floating else " ($C_L$)")
    )
    if rd.has("rmse"):
        r = np.asarray(rd.arrays["rmse"], float)
        ax1.semilogy(rd.t, r, color="C0", label="normalized RMSE")
        ax1.axhline(0.01, color="C3", ls="--", lw=0.9, label="0.01")
        ax1.axhline(0.001, color="C2", ls="--", lw=0.9, label="0.001")
        fin = r[np.isfinite(r) & (r > 0)]
        ax1.set_ylim(max(1e-5, fin.min() / 3) if fin.size else 1e-5, 2)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("normalized RMSE (-)")
    ax1.set_title("normalized image error")
    _mark(ax1, rd, loc="best")
    return _finish(fig, rd, "feature trajectories and normalized error", out, "features", formats)


def _arm_columns(plt, rd: RunData, series, top, bottom, labels, what, name, formats, out):
    """Two rows (the first three and the last three components of ``series`` (T, k, 6)), one
    column per arm."""
    k = series.shape[1]
    fig, axes = plt.subplots(2, k, figsize=(6.4 * (0.75 if k > 1 else 1) * k, 4.4),
                             sharex=True, squeeze=False)  # fmt: skip
    for c in range(k):
        for i in range(3):
            axes[0, c].plot(rd.t, series[:, c, i], label=labels[i])
            axes[1, c].plot(rd.t, series[:, c, 3 + i], label=labels[3 + i])
        axes[0, c].set_ylabel(top)
        axes[1, c].set_ylabel(bottom)
        axes[1, c].set_xlabel("time (s)")
        if k > 1:
            axes[0, c].set_title(f"arm {c}")
        for a in axes[:, c]:
            a.axhline(0, color="0.5", lw=0.6)
            _mark(a, rd, ncol=4, loc="best")
    return _finish(fig, rd, what, out, name, formats)


_FEATURE_LABELS = (
    *(rf"$e_{{p_\{n}}}$" for n in ("phi", "theta", "psi")),
    *(f"$e_{{p_{n}}}$" for n in "xyz"),
)


def fig_feature_error(rd: RunData, out, formats):
    """The advanced-feature error; with several arms each arm's, from the points its servo
    used and its desired points (:meth:`RunData.arm_desired`)."""
    if rd.n_arms > 1:
        pts = rd.arm_series("points_arms", (4, 2))
        desired = [rd.arm_desired(i) for i in range(rd.n_arms)]
        if pts is None or any(d is None for d in desired):
            return []
        from ..vision.features import advanced_features

        e = np.full((len(rd.t), rd.n_arms, 6), np.nan)
        for i, d in enumerate(desired):
            pd = advanced_features(np.asarray(d, float))
            for j in np.flatnonzero(np.all(np.isfinite(pts[:, i]), axis=(1, 2))):
                e[j, i] = advanced_features(pts[j, i]) - pd
    elif rd.has("feature_error"):
        e = np.asarray(rd.arrays["feature_error"], float)[:, None, :]
    else:
        return []
    import matplotlib.pyplot as plt

    return _arm_columns(plt, rd, e, "angular features (rad)",
                        "centroid / perimeter\n(normalized image units)", _FEATURE_LABELS,
                        "(a) advanced-feature error $p^* - p^*_d$", "feature_error", formats,
                        out)  # fmt: skip


def fig_camera_twist(rd: RunData, out, formats):
    """The commanded C_L twist; with several arms each arm's."""
    if rd.n_arms > 1:
        w = rd.arm_series("twist_arms", (6,))
        if w is None:
            return []
    elif rd.has("twist"):
        w = np.asarray(rd.arrays["twist"], float)[:, None, :]
    else:
        return []
    import matplotlib.pyplot as plt

    labels = (*(rf"$\omega_{n}$" for n in "xyz"), *(f"$v_{n}$" for n in "xyz"))
    return _arm_columns(plt, rd, w, "angular (rad/s)", "linear (m/s)", labels,
                        "(b) commanded local camera twist", "camera_twist", formats,
                        out)  # fmt: skip


def fig_strain_rates(rd: RunData, out, formats):
    if not rd.has("qd"):
        return []
    import matplotlib.pyplot as plt

    qd = np.asarray(rd.arrays["qd"], float)
    fig, ax = plt.subplots(figsize=(6.4, 2.8))
    names = rd.strain_names(qd.shape[1])
    for i, name in enumerate(names):
        ax.plot(rd.t, qd[:, rd.n_base + i], label=name.replace("$q_", r"$\dot{q}_"))
        if rd.has("qd_d"):
            ax.plot(
                rd.t,
                np.asarray(rd.arrays["qd_d"])[:, rd.n_base + i],
                "--",
                lw=0.9,
                color=f"C{i}",
                label=name.replace("$q_", r"$\dot{q}^d_"),
            )
    ax.set_ylabel("strain rate (1/(m s))")
    ax.set_xlabel("time (s)")
    ax.axhline(0, color="0.5", lw=0.6)
    _mark(ax, rd, ncol=3, loc="best")
    return _finish(
        fig, rd, "(c) time derivative of the rod's strain coordinates", out, "strain_rates", formats
    )


def snapshot_times(rd: RunData, count: int = 4) -> list[float]:
    """Default snapshot times: start, switch to IBVS (if any), and evenly to the end."""
    t = rd.t
    t0, t1 = float(t[0]), float(t[-1])
    sw = rd.switch_times()
    if sw and count >= 3:
        rest = np.linspace(sw[0], t1, count - 1)
        return [t0, *map(float, rest)]
    return [float(x) for x in np.linspace(t0, t1, count)]


def fig_snapshots(rd: RunData, out, formats, times=None):
    """Four C_L frames re-rendered from the stored ``q`` with the detected (stored) and
    desired points; with several arms one row per arm (its C_L, its marker)."""
    if rd.geometry is None or not rd.has("q") or len(rd.t) == 0:
        return []
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from ..vision import PlanarRenderer

    g = rd.geometry
    arms = g.arms or (None,)
    times = snapshot_times(rd) if times is None else list(times)
    local = rd.arm_series("points_local_arms", (4, 2)) if len(arms) > 1 else None
    if local is None and rd.has("points_local"):
        local = np.asarray(rd.arrays["points_local"], float).reshape(len(rd.t), 1, 4, 2)
    fig, axes = plt.subplots(len(arms), len(times), figsize=(2.5 * len(times),
                             2.9 * len(arms)), squeeze=False)  # fmt: skip
    for row, arm in enumerate(arms):
        cam = g.local_camera if arm is None else arm.local_camera
        renderer = PlanarRenderer(g.scene if arm is None else arm.scene)
        desired = g.desired_local_pixels(row)
        try:
            for ax, ti in zip(axes[row], times, strict=True):
                k = int(np.argmin(np.abs(rd.t - ti)))
                q = np.asarray(rd.arrays["q"])[k]
                img = renderer.render(cam, g.local_pose(q, row))
                if img.shape[1] > 512:  # a 2.5-inch panel needs no more (faster to draw, save)
                    import cv2

                    img = cv2.resize(np.ascontiguousarray(img[:, :, :3]), (512, 512),
                                     interpolation=cv2.INTER_AREA)  # fmt: skip
                ax.imshow(img, extent=(0, cam.width, cam.height, 0))
                ax.plot(*np.vstack([desired, desired[:1]]).T, "-", color="lime", lw=0.8)
                ax.plot(desired[:, 0], desired[:, 1], "x", color="lime", ms=7, mew=1.6)
                if local is not None and row < local.shape[1]:
                    p = _to_px(local[k, row], cam)
                    if np.all(np.isfinite(p)):
                        ax.plot(p[:, 0], p[:, 1], "o", color="red", ms=4, mfc="none", mew=1.4)
                mode = ""
                if rd.has("mode"):
                    mode = " (recovery)" if int(rd.arrays["mode"][k]) == 1 else " (IBVS)"
                who = f"arm {row}, " if len(arms) > 1 else ""
                ax.set_title(f"{who}t = {rd.t[k]:.2f} s{mode}")
                ax.set_xlim(0, cam.width)
                ax.set_ylim(cam.height, 0)
                ax.set_xticks([])
                ax.set_yticks([])
                ax.grid(False)
        finally:
            renderer.close()
    axes[0, 0].legend(
        handles=[
            Line2D([], [], ls="", marker="o", color="red", mfc="none", label="detected"),
            Line2D([], [], ls="", marker="x", color="lime", mew=1.6, label="desired"),
        ],
        loc="lower left",
    )
    return _finish(fig, rd, "(d) local camera $C_L$ snapshots", out, "snapshots", formats)


def fig_lyapunov(rd: RunData, out, formats):
    if not rd.has("V"):
        return []
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 2.6))
    ax.semilogy(rd.t, np.maximum(np.asarray(rd.arrays["V"], float), 1e-12), label="$V$")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("Lyapunov function\n(known part, J)")
    _mark(ax, rd, loc="best")
    return _finish(fig, rd, "Lyapunov function", out, "lyapunov", formats)


def fig_estimation(rd: RunData, out, formats):
    if not rd.has("q", "q_hat", "P_diag"):
        return []
    var = np.asarray(rd.arrays["P_diag"], float)
    if not np.isfinite(var).any():  # the true state: nothing to show
        return []
    import matplotlib.pyplot as plt

    q = np.asarray(rd.arrays["q"], float)
    qh = np.asarray(rd.arrays["q_hat"], float)
    n = q.shape[1]
    sd = np.sqrt(np.maximum(var[:, :n], 0.0))
    idx = list(range(rd.n_base, n)) + ([3, 4, 5] if rd.floating else [])
    names = rd.strain_names(n) + (list(_POS) if rd.floating else [])
    units = ["1/m"] * (n - rd.n_base) + (["m"] * 3 if rd.floating else [])
    fig, axes = plt.subplots(len(idx), 1, figsize=(6.4, 1.5 * len(idx) + 0.6), sharex=True,
                             squeeze=False)  # fmt: skip
    for ax, i, name, unit in zip(axes[:, 0], idx, names, units, strict=True):
        ax.fill_between(rd.t, qh[:, i] - 2 * sd[:, i], qh[:, i] + 2 * sd[:, i], color="C1",
                        alpha=0.3, lw=0, label=r"estimate $\pm 2\sigma$")  # fmt: skip
        ax.plot(rd.t, q[:, i], "k", lw=1.1, label="true")
        ax.plot(rd.t, qh[:, i], "C1--", lw=1.0, label="estimate")
        ax.set_ylabel(f"{name} ({unit})")
        _mark(ax, rd, legend=ax is axes[0, 0], loc="best", ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    s = rd.summary
    what = "state estimation"
    if s.get("strain_estimation_rms") is not None:
        what += f" (RMS after 1 s: strains {s['strain_estimation_rms']:.2g} 1/m"
        p = s.get("drone_position_estimation_rms")
        what += f", drone position {p:.2g} m)" if p is not None else ")"
    return _finish(fig, rd, what, out, "estimation", formats)


def fig_contact(rd: RunData, out, formats):
    """Servoing into contact: the true and estimated normal force (with the estimate's
    2 sigma band and the desired force; drawn from its tare as the contact phase starts), the
    image error, the tendon tensions and the drone's position over the whole run (from t = 0,
    as every figure), the hold shaded."""
    if not rd.has("touch_phase", "force_true", "force_hat", "rmse", "u", "q"):
        return []
    phase = np.asarray(rd.arrays["touch_phase"])
    contact = PHASES.index("contact")
    if not (phase >= contact).any():
        return []
    import matplotlib.pyplot as plt

    t = rd.t
    sl = slice(0, None)
    tt = t[sl]
    hold = phase[sl] == PHASES.index("hold")
    ft = np.asarray(rd.arrays["force_true"], float)[sl]
    fh = np.asarray(rd.arrays["force_hat"], float)[sl].copy()
    sg = np.asarray(rd.arrays["force_sigma"], float)[sl].copy()
    tared = phase[sl] >= contact  # the estimate is tared as the contact phase starts
    fh[~tared] = np.nan
    sg[~tared] = np.nan
    fig, axes = plt.subplots(4, 1, figsize=(6.4, 8.0), sharex=True)

    def shade(ax):
        if hold.any():
            ax.axvspan(tt[hold][0], tt[hold][-1], color="0.9", lw=0, zorder=0, label="hold")

    ax = axes[0]
    shade(ax)
    ax.fill_between(tt, fh - 2 * sg, fh + 2 * sg, color="C1", alpha=0.25, lw=0,
                    label=r"estimate $\pm 2\sigma$")  # fmt: skip
    ax.plot(tt, ft, "k", lw=1.1, label="true (simulator)")
    ax.plot(tt, fh, "C1--", lw=1.0, label="estimated (tendons, thrusts; from the tare)")
    fd = rd.summary.get("touch_force")
    if fd is not None:
        ax.axhline(fd, color="C3", ls=":", lw=1.0, label="desired")
    ax.set_ylabel("normal force (N)")
    top = np.nanmax(np.r_[ft, fh + 2 * sg, fd if fd is not None else 0.0, 1e-3])
    ax.set_ylim(top=1.7 * top)  # room above the curves for the legend
    ax.legend(loc="upper left", ncol=2, fontsize=7)
    ax = axes[1]
    shade(ax)
    r = np.asarray(rd.arrays["rmse"], float)[sl]
    ax.semilogy(tt, r, "C0", label="servo (to the active view)")
    if rd.has("rmse_local"):  # the task's: where the probe aims in C_L (the hold's rule)
        ax.semilogy(tt, np.asarray(rd.arrays["rmse_local"], float)[sl], "C3", lw=0.8,
                    label="task (C_L, detected)")  # fmt: skip
    if rd.has("rmse_local_true"):
        ax.semilogy(tt, np.asarray(rd.arrays["rmse_local_true"], float)[sl], "C2--", lw=1.0,
                    label="task (C_L, true)")  # fmt: skip
    elif rd.has("rmse_true"):
        ax.semilogy(tt, np.asarray(rd.arrays["rmse_true"], float)[sl], "C2--", lw=1.0,
                    label="true (to the contact view)")  # fmt: skip
    ax.axhline(0.01, color="k", ls=":", lw=0.8)
    ax.set_ylabel("normalized RMSE")
    ax.legend(loc="best")
    ax = axes[2]
    shade(ax)
    u = np.asarray(rd.arrays["u"], float)[sl]
    n_a = u.shape[1] - (4 if rd.floating else 0)
    for i in range(n_a):
        ax.plot(tt, u[:, -n_a + i], label=f"$T_{i + 1}$")
    ax.set_ylabel("tendon tension (N)")
    ax.legend(loc="best", ncol=4)
    ax = axes[3]
    shade(ax)
    if rd.floating:
        q = np.asarray(rd.arrays["q"], float)[sl]
        ref = q[hold][0] if hold.any() else q[0]
        for i, name in zip((3, 4, 5), _POS, strict=True):
            ax.plot(tt, 1e3 * (q[:, i] - ref[i]), label=name)
        ax.set_ylabel("drone position (mm,\nfrom the hold's start)")
        ax.legend(loc="best", ncol=3)
    ax.set_xlabel("time (s)")
    s = rd.summary
    what = "servoing into contact"
    if s.get("hold_force_rms_rel") is not None:
        img = s.get("hold_image_error_max")
        img = "-" if img is None else f"{img:.4f}"
        what += (f" (hold: force RMS error {100 * s['hold_force_rms_rel']:.1f} %, task image "
                 f"error max {img})")  # fmt: skip
    return _finish(fig, rd, what, out, "contact", formats)


def fig_arms(rd: RunData, out, formats):
    """Several arms (``[[robot.arms]]``): each arm's normalized image error (the servo's and the
    true one), its strains and its tendon tensions (``u`` after the thrusts, arm by arm)."""
    if not rd.has("rmse_arms", "q", "u"):
        return []
    import matplotlib.pyplot as plt

    t = rd.t
    r = np.asarray(rd.arrays["rmse_arms"], float)
    rt = np.asarray(rd.arrays.get("rmse_true_arms", np.full_like(r, np.nan)), float)
    k = r.shape[1]
    q, u = np.asarray(rd.arrays["q"], float), np.asarray(rd.arrays["u"], float)
    ns = (q.shape[1] - rd.n_base) // k  # the shipped arms share one basis
    na = (u.shape[1] - (4 if rd.floating else 0)) // k
    fig, axes = plt.subplots(3, 1, figsize=(6.4, 7.0), sharex=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i in range(k):
        c = colors[i % len(colors)]
        axes[0].semilogy(t, np.maximum(r[:, i], 1e-6), color=c, label=f"arm {i} (servo)")
        axes[0].semilogy(t, np.maximum(rt[:, i], 1e-6), color=c, ls="--", lw=0.9,
                         label=f"arm {i} (true)")  # fmt: skip
        qs = q[:, rd.n_base + i * ns : rd.n_base + (i + 1) * ns]
        for j in range(ns):
            axes[1].plot(t, qs[:, j], color=c, ls=("-", "--", ":", "-.")[j % 4],
                         label=f"arm {i} $q_{{s{j + 1}}}$")  # fmt: skip
        us = u[:, u.shape[1] - (k - i) * na : u.shape[1] - (k - i - 1) * na]
        for j in range(na):  # the arm's colour, one line style per tendon
            axes[2].plot(t, us[:, j], color=c, lw=0.9, ls=("-", "--", ":", "-.")[j % 4],
                         label=f"arm {i} $T_{{{j + 1}}}$")  # fmt: skip
    axes[0].axhline(0.01, color="k", lw=0.8, ls=":")
    axes[0].set_ylabel("normalized RMSE")
    axes[1].set_ylabel("strains (1/m)")
    axes[2].set_ylabel("tensions (N)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        _mark(ax, rd, fontsize=7, ncol=2, loc="best")
    return _finish(fig, rd, "arms", out, "arms", formats)


_FUNCS = {
    "state_errors": fig_state_errors,
    "tracking_errors": fig_tracking_errors,
    "actuation": fig_actuation,
    "features": fig_features,
    "feature_error": fig_feature_error,
    "camera_twist": fig_camera_twist,
    "strain_rates": fig_strain_rates,
    "snapshots": fig_snapshots,
    "lyapunov": fig_lyapunov,
    "estimation": fig_estimation,
    "contact": fig_contact,
    "arms": fig_arms,
}


def plot_run(
    out,
    arrays: dict,
    summary: dict,
    desired_pts=None,
    system=None,
    scenario=None,
    formats=("png", "pdf"),
    kinds=KINDS,
    snapshot_at=None,
) -> list[Path]:
    """Write the figures of one run to folder ``out`` (each kind as ``KIND.png`` and
    ``KIND.pdf``); returns the paths written.

    ``scenario`` (a :class:`~tdacm.sim.Scenario`) gives the desired configuration and, for the
    snapshots, the geometry to re-render C_L; without it ``state_errors`` uses the stored
    ``q_star`` if any and ``snapshots`` is skipped. ``system`` is only used for
    ``system.floating`` when no scenario is given. ``snapshot_at``: the four times (s).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if "t" not in arrays or len(arrays["t"]) == 0:
        return []
    if scenario is not None:
        floating = scenario.floating
    elif system is not None:
        floating = bool(system.floating)
    else:
        floating = np.asarray(arrays["q"]).shape[1] >= 8
    q_star = None
    geom = None
    if scenario is not None:
        from ._scene import geometry

        q_star = np.asarray(scenario.config.desired.q, float)
        geom = geometry(scenario)
    elif "q_star" in arrays:
        q_star = np.asarray(arrays["q_star"], float)
    if desired_pts is None and "desired_points" in arrays:
        desired_pts = arrays["desired_points"]
    rd = RunData(
        arrays=arrays,
        summary=summary or {},
        floating=floating,
        q_star=q_star,
        desired_points=None if desired_pts is None else np.asarray(desired_pts, float),
        geometry=geom,
        title=(summary or {}).get("scenario", ""),
        camera=geom.local_camera if geom is not None else None,
    )
    paths = []
    with plt.rc_context(_STYLE):
        for kind in kinds:
            if kind == "snapshots":
                paths += fig_snapshots(rd, out, formats, snapshot_at)
            else:
                paths += _FUNCS[kind](rd, out, formats)
    return paths


def plot_run_dir(
    run_dir, out=None, formats=("png", "pdf"), snapshot_at=None, kinds=KINDS
) -> list[Path]:
    """Regenerate the figures of a ``tdacm run`` folder from its stored time series
    (``timeseries.npz``, ``summary.json``, ``scenario.toml``); ``tdacm plot RUN_DIR``."""
    from ..sim.outputs import load_run

    arrays, summary, scenario = load_run(run_dir)
    desired = arrays.pop("desired_points", None)
    return plot_run(
        Path(run_dir) if out is None else Path(out),
        arrays,
        summary,
        desired,
        scenario=scenario,
        formats=formats,
        kinds=kinds,
        snapshot_at=snapshot_at,
    )
