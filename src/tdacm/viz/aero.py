"""Figure of the rotor wake around the drone and the arm, with the air's force along the arm.

:func:`wake_figure` draws, for the paper's TD-ACM hovering (each rotor at a quarter of the
weight), the merged wake speed of the four rotors (:func:`tdacm.aero.wake_field`) in the vertical
plane through rotors 0 and 2 (body x-z), the rod and its tip camera, and the force density the
air puts on the rod (:func:`tdacm.system.aero.section_air_loads`), for the hanging rod and a
bent one; a second row gives the force density along the arm (cross-flow and axial parts).

Regenerate docs/figures/aero_wake.png with ``python -m tdacm.viz.aero docs/figures/aero_wake.png``.
"""

from __future__ import annotations

import numpy as np

from ._main import figure_main

#: the two configurations drawn: the hanging rod and the rod bent toward body +x
DEFAULT_BENDS = ((0.0, 0.0), (-1.0, 0.0))


def _hover(system, q_s):
    """``(q, qdot, u, aero)``: the drone hovering level at 3 m, rod strains ``q_s``, rotors at
    a quarter of the weight each, tendons slack; the default aerodynamics in still air."""
    from ..aero import Aerodynamics
    from ..system.aero import aero_array

    q = np.zeros(system.n)
    q[5] = 3.0
    q[6:] = q_s
    u = np.zeros(system.n_u)
    u[:4] = 9.81 * system.total_mass / 4.0
    return q, np.zeros(system.n), u, aero_array(system, Aerodynamics())


def wake_figure(path=None, bends=DEFAULT_BENDS, system=None, grid: int = 161):
    """The figure (matplotlib ``Figure``), saved to ``path`` when given. ``bends``: the rod
    strains ``q_s`` of each column; ``system``: a floating TD-ACM (default: the paper's)."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import PowerNorm

    from .. import paper_system
    from ..aero import layout as AL
    from ..aero import wake_field
    from ..system.aero import section_air_loads

    s = paper_system() if system is None else system
    if not s.floating:
        raise ValueError("wake_figure needs a floating TD-ACM (the drone makes the wake)")
    fig, axes = plt.subplots(
        2, len(bends), figsize=(5.2 * len(bends), 8.4), gridspec_kw={"height_ratios": [2.2, 1]}
    )
    axes = np.atleast_2d(axes).reshape(2, len(bends))
    x = np.linspace(-0.7, 0.7, grid)
    z = np.linspace(3.15, 1.55, grid)
    xx, zz = np.meshgrid(x, z)
    pts = np.column_stack([xx.ravel(), np.zeros(xx.size), zz.ravel()])
    image = None
    for col, q_s in enumerate(bends):
        q, qd, u, aero = _hover(s, q_s)
        gb = s.base_pose(q)
        speed = -wake_field(pts, gb, u[:4], aero)[:, 2].reshape(xx.shape)
        ax = axes[0, col]
        image = ax.pcolormesh(
            xx, zz, speed, cmap="Blues", norm=PowerNorm(0.5, 0.0, 5.5), shading="auto"
        )
        rotors = aero[AL.ROTORS : AL.ROTORS + 12].reshape(4, 3) @ gb[:3, :3].T + gb[:3, 3]
        r = aero[AL.RADIUS]
        for c in rotors:
            if abs(c[1]) < 1e-9:
                ax.plot([c[0] - r, c[0] + r], [c[2], c[2]], color="k", lw=3)
        ax.plot([rotors[0, 0], rotors[2, 0]], [gb[2, 3], gb[2, 3]], color="0.3", lw=1)
        backbone = s.backbone(q, 60)[:, :3, 3]
        ax.plot(backbone[:, 0], backbone[:, 2], color="C3", lw=2, label="rod")
        p, f, tip = section_air_loads(s, q, qd, u, aero)
        scale = 20.0  # m of arrow per N/m
        ax.quiver(p[:, 0], p[:, 2], f[:, 0], f[:, 2], color="C1", angles="xy",
                  scale_units="xy", scale=1.0 / scale, width=0.006,
                  label=f"force density ({scale:g} m per N/m)")  # fmt: skip
        ax.plot(backbone[-1, 0], backbone[-1, 2], "s", color="k", ms=6, label="tip camera")
        ax.quiver(backbone[-1, 0], backbone[-1, 2], tip[0], tip[2], color="C2", angles="xy",
                  scale_units="xy", scale=1.0 / scale, width=0.006,
                  label=f"force on the camera ({scale:g} m per N)")  # fmt: skip
        fn = np.linalg.norm(tip)
        ax.set_title(
            f"q_s = [{q_s[0]:g}, {q_s[1]:g}]: rod {1e3 * _total(s, p, f):.2g} mN, "
            f"camera {1e3 * fn:.2g} mN"
        )
        ax.set_aspect("equal")
        ax.set_xlabel("x (m), body x through rotors 0 and 2")
        ax.set_ylabel("z (m)")
        ax.legend(loc="lower left", fontsize=7)
        # the force density along the arm, cross-flow and axial parts
        sax = axes[1, col]
        arc, t = _along(s, q, p)
        axial = np.sum(f * t, axis=1)
        cross = np.linalg.norm(f - axial[:, None] * t, axis=1)
        sax.plot(arc, 1e3 * cross, "o-", label="cross-flow |f_n|")
        sax.plot(arc, 1e3 * axial, "s-", label="axial f_a (toward the tip > 0)")
        sax.set_xlabel("arc length along the rod (m)")
        sax.set_ylabel("force density (mN/m)")
        sax.grid(alpha=0.3)
        sax.legend(fontsize=7)
    fig.colorbar(image, ax=axes[0, :].tolist(), label="merged wake speed (m/s)", shrink=0.8)
    fig.suptitle("Rotor wake of the hovering paper drone (0.763 kg) and the air's force on the arm")
    if path is not None:
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
    return fig


def _total(system, p, f) -> float:
    """|integral of the force density| over the rod, for the title: the trapezoid over the
    Gauss points, stretched to the rod's length (the kernels use the Gauss weights)."""
    if len(p) < 2:
        return 0.0
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(ds)]
    return float(np.linalg.norm(np.trapezoid(f, s, axis=0) * system.arms[0].length / s[-1]))


def _along(system, q, p):
    """Arc length (m from the rod's base) and unit tangent of the backbone at the points ``p``
    (the nearest of 1001 backbone samples: within 1 mm)."""
    n = 1001
    bb = system.backbone(q, n)[:, :3, 3]
    tang = np.gradient(bb, axis=0)
    tang /= np.linalg.norm(tang, axis=1)[:, None]
    idx = np.array([int(np.argmin(np.linalg.norm(bb - x, axis=1))) for x in p], dtype=int)
    return idx * system.arms[0].length / (n - 1), tang[idx]


def main(argv=None) -> int:
    return figure_main(wake_figure, "aero_wake.png", argv)


if __name__ == "__main__":
    raise SystemExit(main())
