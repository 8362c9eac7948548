"""Drag of the air on the rod, the tip body and the drone.

Rod (per metre, at every Gauss point, in the section frame ``O_s`` whose x axis is the rod's
axis): with ``v`` the air velocity relative to the section split into its axial part ``v_a``
and its cross-flow part ``v_n`` (the independence principle of yawed cylinders, Hoerner 1965,
ch. 3),

* cross-flow drag ``f_n = 1/2 rho C_d d |v_n| v_n``, ``C_d = 1 + 10 Re^(-2/3)``,
  ``Re = rho |v_n| d / mu`` (White, *Viscous Fluid Flow*, 3rd ed. 2006, ch. 3: a fit of the
  circular-cylinder data within about 10 % for 1 < Re < 2e5), or a given constant ``C_d``;
* axial skin friction ``f_a = 1/2 rho C_f (pi d) |v_a| v_a``, ``C_f = 0.074 Re_L^(-1/5)``
  on the rod length ``L`` (turbulent flat plate, Prandtl's 1/7 law), or a given constant.

Tip body: ``F = -1/2 rho |v| (C_D A) * v`` per axis of the tip frame (``v`` the section's velocity
relative to the air).  Drone: rotor drag linear in the body-frame air velocity,
``F = -D v`` (Faessler, Franchi & Scaramuzza 2018), plus the body's quadratic drag.

Every force here opposes the velocity relative to the air, so in still air its power is never
positive.
"""

from __future__ import annotations

import math

from .._jit import kernel


@kernel
def cylinder_cd(re):
    """Circular-cylinder cross-flow drag coefficient ``1 + 10 Re^(-2/3)`` (White 2006)."""
    return 1.0 + 10.0 * re ** (-2.0 / 3.0)


@kernel
def rod_force(va, vy, vz, d, length, rho, mu, cd, cf):
    """Force density (N/m) on a section of diameter ``d`` from the air velocity relative to it,
    ``(va, vy, vz)`` in the section frame (x along the rod); ``cd`` / ``cf`` <= 0 select the
    correlations (module docstring).  Returns ``(fx, fy, fz)``."""
    fx = fy = fz = 0.0
    if d <= 0.0:
        return fx, fy, fz
    vn = math.sqrt(vy * vy + vz * vz)
    if vn > 0.0:
        c = cd if cd > 0.0 else cylinder_cd(rho * vn * d / mu)
        k = 0.5 * rho * c * d * vn
        fy = k * vy
        fz = k * vz
    aa = abs(va)
    if aa > 0.0:
        c = cf if cf > 0.0 else 0.074 * (mu / (rho * aa * length)) ** 0.2
        fx = 0.5 * rho * c * math.pi * d * aa * va
    return fx, fy, fz


@kernel
def quadratic_drag(v0, v1, v2, cda0, cda1, cda2, rho):
    """``1/2 rho |v| (C_D A) * v``: the force on a body from the air velocity ``v`` relative to
    it (per axis drag areas)."""
    k = 0.5 * rho * math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    return k * cda0 * v0, k * cda1 * v1, k * cda2 * v2
