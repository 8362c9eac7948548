"""Numba geometry and contact laws of the packed contact array (:mod:`tdacm.contact.layout`).

* :func:`sdf`: signed distance of a point to an obstacle and its outward normal (the gradient
  of the distance); negative inside.  The distance to a convex set is convex along a segment,
  which :func:`segment_contact` uses to find the deepest point of a capsule exactly (golden
  section search) so that a rod segment cannot pass through an edge or a corner between nodes.
* :func:`contact_law`: the normal force of the compliant Hunt-Crossley law
  ``F_n = max(0, k delta (1 + c delta_dot))`` (Hunt & Crossley, J. Appl. Mech. 42 (1975);
  exponent 1, a linear penalty spring whose damping vanishes with the penetration, so no
  force jump at impact and no pull at separation) and the regularized Coulomb friction
  ``F_t = -mu(|v_t|) F_n v_t / sqrt(|v_t|^2 + v_s^2)`` with
  ``mu(v) = mu_k + (mu_s - mu_k) exp(-(v / v_St)^2)`` (static to kinetic, Stribeck).
"""

from __future__ import annotations

import math

from numba import njit

from .._jit import kernel
from . import layout as CL

_GOLDEN = 0.6180339887498949
_SEARCH_ITERS = 30  # interval 0.618^30 = 5e-7 of the segment


@kernel
def sdf(c, base, x, y, z):
    """Signed distance of the point ``(x, y, z)`` to the obstacle whose row starts at
    ``c[base]`` and the outward unit normal ``(d, nx, ny, nz)`` (inertial frame)."""
    kind = c[base + CL.KIND]
    r = base + CL.ROT
    px = x - c[base + CL.POS]
    py = y - c[base + CL.POS + 1]
    pz = z - c[base + CL.POS + 2]
    if kind == CL.PLANE:
        nx, ny, nz = c[r + 2], c[r + 5], c[r + 8]
        return nx * px + ny * py + nz * pz, nx, ny, nz
    if kind == CL.SPHERE:
        dist = math.sqrt(px * px + py * py + pz * pz)
        if dist == 0.0:
            return -c[base + CL.SIZE], 0.0, 0.0, 1.0
        return dist - c[base + CL.SIZE], px / dist, py / dist, pz / dist
    # local coordinates u = R^T p
    u0 = c[r] * px + c[r + 3] * py + c[r + 6] * pz
    u1 = c[r + 1] * px + c[r + 4] * py + c[r + 7] * pz
    u2 = c[r + 2] * px + c[r + 5] * py + c[r + 8] * pz
    g0 = g1 = g2 = 0.0
    if kind == CL.BOX:
        q0 = abs(u0) - c[base + CL.SIZE]
        q1 = abs(u1) - c[base + CL.SIZE + 1]
        q2 = abs(u2) - c[base + CL.SIZE + 2]
        if q0 > 0.0 or q1 > 0.0 or q2 > 0.0:
            e0, e1, e2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
            d = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            g0 = math.copysign(e0 / d, u0)
            g1 = math.copysign(e1 / d, u1)
            g2 = math.copysign(e2 / d, u2)
        else:
            if q0 >= q1 and q0 >= q2:
                d = q0
                g0 = math.copysign(1.0, u0)
            elif q1 >= q2:
                d = q1
                g1 = math.copysign(1.0, u1)
            else:
                d = q2
                g2 = math.copysign(1.0, u2)
    else:  # CYLINDER: radius a, half length b along local z
        rho = math.sqrt(u0 * u0 + u1 * u1)
        ex, ey = 1.0, 0.0
        if rho > 0.0:
            ex, ey = u0 / rho, u1 / rho
        q0 = rho - c[base + CL.SIZE]
        q1 = abs(u2) - c[base + CL.SIZE + 1]
        if q0 > 0.0 or q1 > 0.0:
            e0, e1 = max(q0, 0.0), max(q1, 0.0)
            d = math.sqrt(e0 * e0 + e1 * e1)
            g0, g1 = e0 / d * ex, e0 / d * ey
            g2 = math.copysign(e1 / d, u2)
        elif q0 >= q1:
            d = q0
            g0, g1 = ex, ey
        else:
            d = q1
            g2 = math.copysign(1.0, u2)
    nx = c[r] * g0 + c[r + 1] * g1 + c[r + 2] * g2
    ny = c[r + 3] * g0 + c[r + 4] * g1 + c[r + 5] * g2
    nz = c[r + 6] * g0 + c[r + 7] * g1 + c[r + 8] * g2
    return d, nx, ny, nz


@kernel
def contact_law(c, k, delta, nx, ny, nz, vx, vy, vz):
    """Contact force ``(fx, fy, fz, f_n)`` on a body point of velocity ``v`` penetrating an
    obstacle by ``delta`` (m) along the outward normal ``n``, with normal stiffness ``k``
    (Hunt-Crossley normal force and regularized Coulomb friction, module docstring)."""
    vn = vx * nx + vy * ny + vz * nz
    fn = k * delta * (1.0 + c[CL.DAMPING] * (-vn))
    if fn <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    tx, ty, tz = vx - vn * nx, vy - vn * ny, vz - vn * nz
    s2 = tx * tx + ty * ty + tz * tz
    vst = c[CL.V_STRIBECK]
    mu = c[CL.MU_K] + (c[CL.MU_S] - c[CL.MU_K]) * math.exp(-s2 / (vst * vst))
    vs = c[CL.V_SLIP]
    ft = -mu * fn / math.sqrt(s2 + vs * vs)
    return fn * nx + ft * tx, fn * ny + ft * ty, fn * nz + ft * tz, fn


@kernel
def point_contact(c, radius, x, y, z, vx, vy, vz):
    """Total contact force ``(fx, fy, fz)`` on a sphere of ``radius`` centred at ``(x, y, z)``
    moving at ``v`` (the tip body), summed over the obstacles."""
    fx = fy = fz = 0.0
    for i in range(int(c[CL.N_SHAPES])):
        base = c.shape[0] - (int(c[CL.N_SHAPES]) - i) * CL.SHAPE_SIZE
        d, nx, ny, nz = sdf(c, base, x, y, z)
        if d >= radius:
            continue
        a0, a1, a2, _ = contact_law(c, c[CL.K_TIP], radius - d, nx, ny, nz, vx, vy, vz)
        fx += a0
        fy += a1
        fz += a2
    return fx, fy, fz


@kernel
def _piece(t0, p0, t1, p1):
    """``(int max(0, p), int max(0, p) t)`` over ``[t0, t1]`` of the linear ``p`` through
    ``(t0, p0)``, ``(t1, p1)``."""
    if p0 <= 0.0 and p1 <= 0.0:
        return 0.0, 0.0
    if p0 < 0.0:
        t0 = t0 + (t1 - t0) * p0 / (p0 - p1)
        p0 = 0.0
    elif p1 < 0.0:
        t1 = t0 + (t1 - t0) * p0 / (p0 - p1)
        p1 = 0.0
    w = t1 - t0
    return 0.5 * (p0 + p1) * w, w * (p0 * (2.0 * t0 + t1) + p1 * (t0 + 2.0 * t1)) / 6.0


@kernel
def segment_contact(c, radius, ax, ay, az, bx, by, bz, va, vb, out):
    """Contact of the capsule of ``radius`` from node ``a`` to node ``b`` (velocities ``va``,
    ``vb``) with every obstacle; adds the forces on the two nodes to ``out[0:3]`` (on ``a``)
    and ``out[3:6]`` (on ``b``).  Returns True when any obstacle is touched.

    The penetration ``radius - sdf`` along the segment is taken piecewise linear through the
    two nodes and the deepest point (exact for a plane and a straight edge), the normal is
    the obstacle's at the deepest point; the force ``k A (1 + c delta_dot)`` with ``A`` the
    penetrated area of the profile acts at its centroid, shared by the nodes by the lever
    rule."""
    n_sh = int(c[CL.N_SHAPES])
    dx, dy, dz = bx - ax, by - ay, bz - az
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    hit = False
    for i in range(n_sh):
        base = c.shape[0] - (n_sh - i) * CL.SHAPE_SIZE
        da, nax, nay, naz = sdf(c, base, ax, ay, az)
        db, nbx, nby, nbz = sdf(c, base, bx, by, bz)
        nx, ny, nz = nax, nay, naz
        if c[base + CL.KIND] == CL.PLANE:
            if da >= radius and db >= radius:
                continue
            ts, ds = (0.0, da) if da < db else (1.0, db)
            if da >= db:
                nx, ny, nz = nbx, nby, nbz
        else:
            dm, _, _, _ = sdf(c, base, ax + 0.5 * dx, ay + 0.5 * dy, az + 0.5 * dz)
            # the distance is 1-Lipschitz: no point of the segment is closer than this
            if dm - 0.5 * length >= radius:
                continue
            lo, hi = 0.0, 1.0
            t1 = hi - _GOLDEN * (hi - lo)
            t2 = lo + _GOLDEN * (hi - lo)
            f1 = sdf(c, base, ax + t1 * dx, ay + t1 * dy, az + t1 * dz)[0]
            f2 = sdf(c, base, ax + t2 * dx, ay + t2 * dy, az + t2 * dz)[0]
            for _ in range(_SEARCH_ITERS):
                if f1 < f2:
                    hi, t2, f2 = t2, t1, f1
                    t1 = hi - _GOLDEN * (hi - lo)
                    f1 = sdf(c, base, ax + t1 * dx, ay + t1 * dy, az + t1 * dz)[0]
                else:
                    lo, t1, f1 = t1, t2, f2
                    t2 = lo + _GOLDEN * (hi - lo)
                    f2 = sdf(c, base, ax + t2 * dx, ay + t2 * dy, az + t2 * dz)[0]
            ts = 0.5 * (lo + hi)
            ds, nx, ny, nz = sdf(c, base, ax + ts * dx, ay + ts * dy, az + ts * dz)
            if da < ds:
                ts, ds, nx, ny, nz = 0.0, da, nax, nay, naz
            if db < ds:
                ts, ds, nx, ny, nz = 1.0, db, nbx, nby, nbz
            if ds >= radius:
                continue
        pa, pb, ps = radius - da, radius - db, radius - ds
        s1, m1 = _piece(0.0, pa, ts, ps)
        s2, m2 = _piece(ts, ps, 1.0, pb)
        area = s1 + s2
        if area <= 0.0:
            continue
        tc = (m1 + m2) / area
        vx = (1.0 - tc) * va[0] + tc * vb[0]
        vy = (1.0 - tc) * va[1] + tc * vb[1]
        vz = (1.0 - tc) * va[2] + tc * vb[2]
        # depth at the centroid times the contact length: the area of the profile
        fx, fy, fz, fn = contact_law(c, c[CL.K_ROD], area * length, nx, ny, nz, vx, vy, vz)
        if fn == 0.0:
            continue
        hit = True
        out[0] += (1.0 - tc) * fx
        out[1] += (1.0 - tc) * fy
        out[2] += (1.0 - tc) * fz
        out[3] += tc * fx
        out[4] += tc * fy
        out[5] += tc * fz
    return hit


@njit(cache=True)
def clearance(c, x, y, z):
    """The smallest signed distance of the point ``(x, y, z)`` to the obstacles."""
    n_sh = int(c[CL.N_SHAPES])
    out = math.inf
    for i in range(n_sh):
        out = min(out, sdf(c, c.shape[0] - (n_sh - i) * CL.SHAPE_SIZE, x, y, z)[0])
    return out
