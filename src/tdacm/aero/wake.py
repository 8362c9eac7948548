"""Rotor wake: momentum theory near the disc, a round turbulent jet downstream.

Each rotor of disc area ``A = pi R^2`` and thrust ``T`` is an actuator disc (Leishman,
*Principles of Helicopter Aerodynamics*, 2nd ed. 2006, ch. 2):

* induced velocity in hover ``v_h = sqrt(T / (2 rho A))``; in axial climb at ``V_c > 0``
  ``v_i = -V_c/2 + sqrt((V_c/2)^2 + v_h^2)``; in descent faster than ``2 v_h`` (windmill brake
  state) ``v_i = -V_c/2 - sqrt((V_c/2)^2 - v_h^2)``; in between (vortex-ring state, where
  momentum theory fails) Leishman's empirical fit
  ``v_i / v_h = 1 - 1.125 x - 1.372 x^2 - 1.718 x^3 - 0.655 x^4``, ``x = V_c / v_h``;
* near wake (``0 <= z <= z_j`` below the disc): a top-hat slipstream whose velocity (relative to
  the air far away) follows the axis of the semi-infinite vortex cylinder,
  ``w(z) = v_i (1 + z / sqrt(z^2 + R^2))`` (``v_i`` at the disc, ``2 v_i`` far down), and whose
  radius conserves the mass flow through the disc, ``R_w = R sqrt((V_c + v_i) / (V_c + w))``
  (``R / sqrt(2)`` far down in hover);
* far wake (``z > z_j``): the contracted slipstream of velocity ``U_J = w(z_j)`` and diameter
  ``d_J = 2 R_w(z_j)`` becomes a self-similar round turbulent jet,
  ``U_c = U_J B d_J / (z - z_0)``, ``u = U_c exp(-ln 2 r^2 / b^2)``, ``b = S (z - z_0)``,
  with the virtual origin ``z_0 = z_j - B d_J`` (``U_c = U_J`` at ``z_j``) and the constants
  ``B = 5.8``, ``S = 0.094`` measured on round jets by Hussein, Capp & George (1994, J. Fluid
  Mech. 258) as tabulated by Pope (*Turbulent Flows*, 2000, Table 5.1).

Bauersfeld, Muller, Ziegler, Coletti & Scaramuzza (2025, IEEE RA-L; arXiv:2403.13321) measured
the downwash below quadrotors of several sizes in flight and found that the merged flow of the
four rotors is a round turbulent jet a few drone sizes below the vehicle.  The four rotor jets
are therefore merged by adding their momentum fluxes, ``|u| = sqrt(sum_k u_k^2)``: where the
jets do not overlap this is each jet alone; far down (four equal, overlapping jets) it is twice
one jet, the round jet of the total momentum flux (``U_c`` grows as its square root).

The air crossing a rotor sideways (wind, forward flight) skews its wake downwind as a straight
centreline at Glauert's skew angle (:func:`rotor_states`).

Limits: quasi-steady (the wake follows the rotors at once); a straight skewed centreline (no
wake curvature, no roll-up); no inflow above the disc; no ground effect; no interference of
the rod with the rotors.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .layout import CORE, DECAY, RADIUS, RHO, ROTOR_STATE, ROTORS, SPREAD, WIND

LN2 = math.log(2.0)


@kernel
def induced_velocity(thrust, rho, area, v_climb):
    """Momentum-theory induced velocity (m/s) of a rotor of ``area`` at axial climb ``v_climb``
    (positive up, relative to the air); 0 for a non-positive thrust."""
    if thrust <= 0.0:
        return 0.0
    vh = math.sqrt(thrust / (2.0 * rho * area))
    x = v_climb / vh
    if x >= 0.0:
        return vh * (-0.5 * x + math.sqrt(0.25 * x * x + 1.0))
    if x <= -2.0:
        return vh * (-0.5 * x - math.sqrt(0.25 * x * x - 1.0))
    return vh * (1.0 - 1.125 * x - 1.372 * x * x - 1.718 * x**3 - 0.655 * x**4)


@kernel
def jet_speed(r, z, v_i, v_climb, radius, spread, decay, core):
    """Wake speed (m/s, along the rotor axis, relative to the far air) of one rotor at radial
    distance ``r`` from its axis and ``z`` below its disc (module docstring)."""
    if z < 0.0 or v_i <= 0.0:
        return 0.0
    vc = max(v_climb, 0.0)  # the contraction of a descending rotor is taken as in hover
    if vc + v_i <= 0.0:
        return 0.0
    zz = min(z, core)
    w = v_i * (1.0 + zz / math.sqrt(zz * zz + radius * radius))
    rw = radius * math.sqrt((vc + v_i) / (vc + w))
    if z <= core:
        return w if r <= rw else 0.0
    dj = 2.0 * rw
    x = z - core + decay * dj  # z - z_0
    b = spread * x
    return w * decay * dj / x * math.exp(-LN2 * (r * r) / (b * b))


@kernel
def rotor_states(gb, vb, thrusts, aero, out):
    """Per rotor ``k``: ``out[k] = [cx, cy, cz, v_i, v_climb, sx, sy, sz]``, its centre
    (inertial), induced velocity, axial climb speed and the unit direction of its skewed wake
    centreline; returns the rotor axis ``-R_b e_z`` (the direction of the induced velocity).

    ``gb`` drone pose, ``vb`` its inertial velocity, ``aero`` the packed array (rotor centres in
    the body frame at ``ROTORS``, wind at ``WIND``).  The air crossing the rotor sideways
    (wind minus the drone's velocity) skews the wake: its centreline leans downwind at
    ``tan chi = |v_perp| / (V_c + v_i)`` (Glauert's skewed actuator disc, Leishman 2006, ch. 2)."""
    radius, rho = aero[RADIUS], aero[RHO]
    area = math.pi * radius * radius
    ax = -gb[0, 2]
    ay = -gb[1, 2]
    az = -gb[2, 2]
    # air velocity relative to the drone; its part along the wake is the climb speed
    wx, wy, wz = aero[WIND] - vb[0], aero[WIND + 1] - vb[1], aero[WIND + 2] - vb[2]
    vc = wx * ax + wy * ay + wz * az
    px, py, pz = wx - vc * ax, wy - vc * ay, wz - vc * az
    cross = math.sqrt(px * px + py * py + pz * pz)
    for k in range(4):
        for i in range(3):
            acc = gb[i, 3]
            for c in range(3):
                acc += gb[i, c] * aero[ROTORS + 3 * k + c]
            out[k, i] = acc
        vi = induced_velocity(thrusts[k], rho, area, vc)
        out[k, 3] = vi
        out[k, 4] = vc
        along = max(vc, 0.0) + vi
        if cross > 0.0 and along > 0.0:
            sx, sy, sz = along * ax + px, along * ay + py, along * az + pz
            n = math.sqrt(sx * sx + sy * sy + sz * sz)
            out[k, 5], out[k, 6], out[k, 7] = sx / n, sy / n, sz / n
        else:
            out[k, 5], out[k, 6], out[k, 7] = ax, ay, az
    return ax, ay, az


@kernel
def wake_at(px, py, pz, rot, ax, ay, az, aero):
    """Merged wake speed of the rotors ``rot`` (from :func:`rotor_states`) at an inertial point,
    each jet laid along its skewed centreline; the velocity is that speed along the rotor axis
    ``(ax, ay, az)``."""
    radius, spread, decay, core = aero[RADIUS], aero[SPREAD], aero[DECAY], aero[CORE]
    acc = 0.0
    for k in range(rot.shape[0]):
        dx = px - rot[k, 0]
        dy = py - rot[k, 1]
        dz = pz - rot[k, 2]
        sx, sy, sz = rot[k, 5], rot[k, 6], rot[k, 7]
        z = dx * sx + dy * sy + dz * sz
        rx = dx - z * sx
        ry = dy - z * sy
        rz = dz - z * sz
        r = math.sqrt(rx * rx + ry * ry + rz * rz)
        u = jet_speed(r, z, rot[k, 3], rot[k, 4], radius, spread, decay, core)
        acc += u * u
    return math.sqrt(acc)


def wake_field(points, pose, thrusts, aero, velocity=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Wake velocity (n, 3) at inertial ``points`` (n, 3) of a drone at ``pose`` (4x4) moving at
    ``velocity`` with rotor ``thrusts`` (4,), for a packed ``aero`` array (its wind skews the
    wake and sets the climb speed, but is not added to the result)."""
    pts = np.atleast_2d(np.asarray(points, float))
    gb = np.ascontiguousarray(pose, dtype=float)
    rot = np.empty((4, ROTOR_STATE))
    ax, ay, az = rotor_states(
        gb, np.asarray(velocity, float), np.asarray(thrusts, float), aero, rot
    )
    sp = np.array([wake_at(p[0], p[1], p[2], rot, ax, ay, az, aero) for p in pts])
    return sp[:, None] * np.array([ax, ay, az])[None, :]
