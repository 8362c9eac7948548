"""The bodies of the coupled model's chain: what each Magnus step's body (a Gauss section of
a rod, a joint mass, the tip body) and the drone add to the equations of motion (inertia bias,
gravity and the applied loads, the air, the contact with the obstacles, the tendons), and the
packed loads' layout.

These are the building blocks that both the assembly of the model's terms
(:mod:`tdacm.system.kernels`) and the forward dynamics (:mod:`tdacm.system.forward`) call; they
sit below both so that neither imports the other's helpers.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import allocating, kernel
from ..aero import layout as AL
from ..aero.drag import quadratic_drag, rod_force
from ..aero.wake import rotor_states, wake_at
from ..contact import layout as CL
from ..contact.geometry import point_contact, segment_contact

#: ``step_load`` codes: gravity only (a joint mass), the distributed loads (a Gauss section),
#: the tip loads (the tip body of a rod).
LOAD_GRAVITY = 0
LOAD_DISTRIBUTED = 9
LOAD_TIP = 18


LOAD_SLICES = {
    "gravity": slice(0, 3),
    "base_wrench": slice(3, 9),
    "rod_wrench": slice(9, 15),
    "rod_force": slice(15, 18),
    "tip_wrench": slice(18, 24),
    "tip_force": slice(24, 27),
}
N_LOADS = 27


@njit(cache=True, inline="always")
def skew_entry(w, i, p):
    if i == p:
        return 0.0
    if i == 0:
        return -w[2] if p == 1 else w[1]
    if i == 1:
        return w[2] if p == 0 else -w[0]
    return -w[1] if p == 0 else w[0]


@njit(cache=True, inline="always")
def has_inertia(mass6):
    """Whether a step's body has mass or rotational inertia (massless joints add nothing)."""
    return not (mass6[3] == 0.0 and mass6[0] == 0.0 and mass6[1] == 0.0 and mass6[2] == 0.0)


@njit(cache=True, inline="always")
def body_bias_wrench(mass6, eta, jdq):
    """``f = Mb J_dot qdot + coad(eta) Mb eta`` of a body with diagonal inertia ``mass6``
    (paper eq. (11)), with ``coad(eta) mu = -S(mu) eta = [m x w + f x v; f x w]``."""
    m0, m1, m2 = mass6[0] * eta[0], mass6[1] * eta[1], mass6[2] * eta[2]
    p0, p1, p2 = mass6[3] * eta[3], mass6[4] * eta[4], mass6[5] * eta[5]
    w0, w1, w2, v0, v1, v2 = eta[0], eta[1], eta[2], eta[3], eta[4], eta[5]
    f0 = mass6[0] * jdq[0] - (m1 * w2 - m2 * w1 + p1 * v2 - p2 * v1)
    f1 = mass6[1] * jdq[1] - (m2 * w0 - m0 * w2 + p2 * v0 - p0 * v2)
    f2 = mass6[2] * jdq[2] - (m0 * w1 - m1 * w0 + p0 * v1 - p1 * v0)
    f3 = mass6[3] * jdq[3] - (p1 * w2 - p2 * w1)
    f4 = mass6[4] * jdq[4] - (p2 * w0 - p0 * w2)
    f5 = mass6[5] * jdq[5] - (p0 * w1 - p1 * w0)
    return f0, f1, f2, f3, f4, f5


@njit(cache=True, inline="always")
def step_wrench(f, g, eta, k, lo, mass6, grav, loads, rod_air, aero, nst, rot, ax, ay, az, wake):
    """The body wrench ``f`` (local frame) of step ``k``'s body with load slot ``lo``: its
    weight, and unless it is a plain Gauss section (``LOAD_GRAVITY``) the external load of its
    slot (a wrench, plus a force in the inertial frame) and, when ``rod_air``, the rotor wake
    and drag on it (paper eq. (16))."""
    if lo == LOAD_GRAVITY:
        for i in range(6):
            f[i] = 0.0
        for i in range(3):
            for kk in range(3):
                f[3 + i] += g[kk, i] * (mass6[3] * grav[kk])
    else:
        for i in range(6):
            f[i] = loads[lo + i]
        for i in range(3):
            for kk in range(3):
                f[3 + i] += g[kk, i] * (mass6[3] * grav[kk] + loads[lo + 6 + kk])
        if rod_air:
            a0, a1, a2 = _air_on_body(g, eta, k, lo == LOAD_TIP, aero, nst, rot, ax, ay, az, wake)
            f[3] += a0
            f[4] += a1
            f[5] += a2


@kernel
def _air_on_body(g, eta, k, tip, aero, nst, rot, ax, ay, az, wake):
    """Aerodynamic force on the body after Magnus step ``k`` (a Gauss section of the rod, per
    metre, or the tip body), in its own frame: the air (wind + rotor wake at the body's
    position) relative to the body's velocity ``eta[3:6]`` (:mod:`tdacm.aero.drag`)."""
    ux, uy, uz = aero[AL.WIND], aero[AL.WIND + 1], aero[AL.WIND + 2]
    if wake:
        sp = wake_at(g[0, 3], g[1, 3], g[2, 3], rot, ax, ay, az, aero)
        ux += sp * ax
        uy += sp * ay
        uz += sp * az
    v0 = g[0, 0] * ux + g[1, 0] * uy + g[2, 0] * uz - eta[3]
    v1 = g[0, 1] * ux + g[1, 1] * uy + g[2, 1] * uz - eta[4]
    v2 = g[0, 2] * ux + g[1, 2] * uy + g[2, 2] * uz - eta[5]
    rho = aero[AL.RHO]
    if tip:
        c = AL.TIP_CDA
        return quadratic_drag(v0, v1, v2, aero[c], aero[c + 1], aero[c + 2], rho)
    return rod_force(
        v0, v1, v2, aero[AL.N_HEADER + k], aero[AL.N_HEADER + nst + k], rho, aero[AL.MU],
        aero[AL.CD], aero[AL.CF],
    )  # fmt: skip


@kernel
def _air_on_drone(gb, eb, aero):
    """Rotor drag and body drag of the drone (body frame) from the wind and its twist ``eb``."""
    w0, w1, w2 = aero[AL.WIND], aero[AL.WIND + 1], aero[AL.WIND + 2]
    v0 = gb[0, 0] * w0 + gb[1, 0] * w1 + gb[2, 0] * w2 - eb[3]
    v1 = gb[0, 1] * w0 + gb[1, 1] * w1 + gb[2, 1] * w2 - eb[4]
    v2 = gb[0, 2] * w0 + gb[1, 2] * w1 + gb[2, 2] * w2 - eb[5]
    c = AL.DRONE_CDA
    f0, f1, f2 = quadratic_drag(v0, v1, v2, aero[c], aero[c + 1], aero[c + 2], aero[AL.RHO])
    d = AL.DRONE_D
    return f0 + aero[d] * v0, f1 + aero[d + 1] * v1, f2 + aero[d + 2] * v2


@allocating
def _rotor_setup(q, qd, u, m, gb, aero, rot):
    """Rotor centres and induced velocities (:func:`tdacm.aero.wake.rotor_states`): the drone's
    own thrusts ``u[0:4]`` and velocity, or the stand's thrusts for a fixed base."""
    if m.floating:
        return rotor_states(gb, qd[3:6], u[0:4], aero, rot)
    return rotor_states(gb, np.zeros(3), aero[AL.THRUST : AL.THRUST + 4], aero, rot)


@allocating
def _node_contact(contact, k, g, eta, prev, fa, fb):
    """Contact forces of the rod node after Magnus step ``k`` (a Gauss section or the tip):
    the capsule from the previous node ``prev`` (``[p, v]``, inertial) to this one, and, at the
    tip, the tip sphere.  Sets ``fa[0:3]`` (force on the previous node) and ``fb`` (on this
    node), inertial; returns ``(hit_a, hit_b)``; moves ``prev`` to this node."""
    px, py, pz = g[0, 3], g[1, 3], g[2, 3]
    vb = np.empty(3)
    for i in range(3):
        vb[i] = g[i, 0] * eta[3] + g[i, 1] * eta[4] + g[i, 2] * eta[5]
    for i in range(6):
        fa[i] = 0.0
    hit_a = False
    hit_b = False
    r = contact[CL.N_HEADER + k]
    if contact[CL.ROD_ON] > 0.0 and r > 0.0:
        hit_a = segment_contact(
            contact, r, prev[0], prev[1], prev[2], px, py, pz, prev[3:6], vb, fa
        )
        hit_b = hit_a
    for i in range(3):
        fb[i] = fa[3 + i]
    prev[0], prev[1], prev[2] = px, py, pz
    prev[3], prev[4], prev[5] = vb[0], vb[1], vb[2]
    return hit_a, hit_b


@kernel
def _has_probe(contact):
    """True when the tip sphere sits on a rigid probe (its centre off the tip's origin)."""
    return contact[CL.PROBE] != 0.0 or contact[CL.PROBE + 1] != 0.0 or contact[CL.PROBE + 2] != 0.0


@allocating
def probe_point(contact, g, eta):
    """Inertial position and velocity of the tip sphere's centre ``p + R o`` (``o``: the
    probe offset in the tip frame; velocity ``R (v + w x o)`` from the body twist ``eta``)."""
    o0, o1, o2 = contact[CL.PROBE], contact[CL.PROBE + 1], contact[CL.PROBE + 2]
    b0 = eta[3] + eta[1] * o2 - eta[2] * o1
    b1 = eta[4] + eta[2] * o0 - eta[0] * o2
    b2 = eta[5] + eta[0] * o1 - eta[1] * o0
    x = np.empty(3)
    v = np.empty(3)
    for i in range(3):
        x[i] = g[i, 3] + g[i, 0] * o0 + g[i, 1] * o1 + g[i, 2] * o2
        v[i] = g[i, 0] * b0 + g[i, 1] * b1 + g[i, 2] * b2
    return x, v


@allocating
def _tip_contact(contact, g, eta, fb, mb):
    """Adds the tip sphere's contact force (inertial) to ``fb``; True when touching.  On a
    probe (:data:`~tdacm.contact.layout.PROBE` not zero) the sphere's centre is ``p + R o``
    and ``mb`` receives the force's moment about the tip, ``o x R^T f`` (tip frame); without
    a probe the arithmetic is the plain tip sphere's and ``mb`` is not touched."""
    if contact[CL.TIP_ON] <= 0.0:
        return False
    if _has_probe(contact):
        x, v = probe_point(contact, g, eta)
        t0, t1, t2 = point_contact(
            contact, contact[CL.TIP_RADIUS], x[0], x[1], x[2], v[0], v[1], v[2]
        )
        if t0 == 0.0 and t1 == 0.0 and t2 == 0.0:
            return False
        fb[0] += t0
        fb[1] += t1
        fb[2] += t2
        f0 = g[0, 0] * t0 + g[1, 0] * t1 + g[2, 0] * t2
        f1 = g[0, 1] * t0 + g[1, 1] * t1 + g[2, 1] * t2
        f2 = g[0, 2] * t0 + g[1, 2] * t1 + g[2, 2] * t2
        o0, o1, o2 = contact[CL.PROBE], contact[CL.PROBE + 1], contact[CL.PROBE + 2]
        mb[0] += o1 * f2 - o2 * f1
        mb[1] += o2 * f0 - o0 * f2
        mb[2] += o0 * f1 - o1 * f0
        return True
    v0 = g[0, 0] * eta[3] + g[0, 1] * eta[4] + g[0, 2] * eta[5]
    v1 = g[1, 0] * eta[3] + g[1, 1] * eta[4] + g[1, 2] * eta[5]
    v2 = g[2, 0] * eta[3] + g[2, 1] * eta[4] + g[2, 2] * eta[5]
    t0, t1, t2 = point_contact(
        contact, contact[CL.TIP_RADIUS], g[0, 3], g[1, 3], g[2, 3], v0, v1, v2
    )
    if t0 == 0.0 and t1 == 0.0 and t2 == 0.0:
        return False
    fb[0] += t0
    fb[1] += t1
    fb[2] += t2
    return True


@kernel
def _rod_base_node(g, eta, prev):
    """The rod base as the first node of the capsule chain (``prev = [p, v]``)."""
    for i in range(3):
        prev[i] = g[i, 3]
        prev[3 + i] = g[i, 0] * eta[3] + g[i, 1] * eta[4] + g[i, 2] * eta[5]


@njit(cache=True)
def tendon_lengths_and_matrix(qs, m):
    """Tendon path lengths ``l_i = int_0^{end_i} |k x d_i + u + d_i'| ds`` and
    ``B_s(q) = int B_q^T B_a ds = -dl/dq_s`` (n_s x n_a), ``B_a = -[d~ t; t]`` (paper eq. (13)),
    on the same Gauss points; each tendon integrates where it runs (``m.tendon_on``)."""
    na = m.tendon_d.shape[1]
    lengths = np.zeros(na)
    out = np.zeros((qs.shape[0], na))
    tendon_accumulate(qs, m, np.empty(6), np.empty(6), out, lengths, bool(1))
    return lengths, out


@kernel
def tendon_accumulate(qs, m, xi, col, out, lengths, want_lengths):
    """Add ``B_s(q)`` (:func:`tendon_lengths_and_matrix`) into ``out`` (rows ``0..n_s``) and,
    when ``want_lengths``, the path lengths into ``lengths``; ``xi`` and ``col`` are (6,)
    scratch. Shared by :func:`tendon_lengths_and_matrix` and the forward dynamics' ``B u``
    (:mod:`tdacm.system.forward`), so both sum in the same order."""
    ng = m.bg.shape[0]
    na = m.tendon_d.shape[1]
    for gi in range(ng):
        b = m.bg[gi]
        c0 = m.g_col[gi]
        nc = m.g_nc[gi]
        nzc, nzn, nzr, nzrn = m.g_nzc[gi], m.g_nzn[gi], m.g_nzr[gi], m.g_nzrn[gi]
        for r in range(6):  # the sums skip the basis block's exact zeros
            acc = 0.0
            for t in range(nzn[r]):
                c = nzc[r, t]
                acc += b[r, c] * qs[c0 + c]
            xi[r] = acc + m.xi0g[gi, r]
        k0, k1, k2 = xi[0], xi[1], xi[2]
        for i in range(na):
            if m.tendon_on[gi, i] == 0.0:
                continue
            d0, d1, d2 = m.tendon_d[gi, i, 0], m.tendon_d[gi, i, 1], m.tendon_d[gi, i, 2]
            v0 = k1 * d2 - k2 * d1 + xi[3] + m.tendon_dd[gi, i, 0]
            v1 = k2 * d0 - k0 * d2 + xi[4] + m.tendon_dd[gi, i, 1]
            v2 = k0 * d1 - k1 * d0 + xi[5] + m.tendon_dd[gi, i, 2]
            nv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            t0, t1, t2 = v0 / nv, v1 / nv, v2 / nv
            col[0] = -(d1 * t2 - d2 * t1)
            col[1] = -(d2 * t0 - d0 * t2)
            col[2] = -(d0 * t1 - d1 * t0)
            col[3] = -t0
            col[4] = -t1
            col[5] = -t2
            wq = m.wq[gi]
            if want_lengths:
                lengths[i] += wq * nv
            for c in range(nc):
                acc = 0.0
                for t in range(nzrn[c]):
                    r = nzr[c, t]
                    acc += b[r, c] * col[r]
                out[c0 + c, i] += wq * acc
