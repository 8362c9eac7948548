"""Numba kernels of the coupled TD-ACM model (paper eqs. (5)-(22)).

One forward recursion along the rod carries, from the drone to the tip, the pose ``g``, the
Jacobian ``J`` (6 x n, local frame) and its time derivative ``J_dot``:

    J_0 = Ad(g_a^b)^-1 J_b^b,                                   (paper eq. (9), first term)
    J_{k+1} = Ad(exp Omega_k)^-1 (J_k + [0 | T(Omega_k) Z_k]),   (eq. (9), second term, discretized)
    J_dot_{k+1} = Ad(exp Omega_k)^-1 (J_dot_k + [0 | T_dot Z_k + T Z_dot_k]) - ad(w_k) J_{k+1},

with ``w_k = Ad(exp Omega_k)^-1 T Z_k qdot_s`` the relative twist of the step.  At every Gauss
point the section adds its share to ``M`` (eq. (10)), ``C`` (eq. (11)) and ``tau_ext`` (eq. (16));
the tip body adds its own.  The gyroscopic term is written ``-S(Mbar eta) J`` (see
:func:`tdacm.lie.se3.wrench_skew`), equal to ``coad(eta) Mbar J`` when multiplied by ``qdot``,
which makes ``Mdot - 2C`` skew-symmetric.

Generalized coordinates ``q = [phi, theta, psi, x, y, z, q_s]`` for a floating base, ``q = q_s``
for a fixed base.  The packed load vector ``loads`` (27,) is
``[gravity(3), base wrench in O_b (6), rod wrench density in O_s (6), rod force density in the
inertial frame (3), tip wrench in O_L (6), tip force in the inertial frame (3)]``.

Aerodynamics (:mod:`tdacm.aero`): the ``*_aero`` kernels take a packed array ``aero`` besides the
loads; at every Gauss point the drag of the air (rotor wake + wind - section velocity) joins the
section's wrench density, at the tip the camera's drag, at the drone its rotor and body drag.
The plain kernels pass an empty array and skip every aerodynamic term (bit-identical results).

Contact (:mod:`tdacm.contact`): the environment kernels ``coupled_terms_env``,
``forward_dynamics_env`` and ``rk4_run_env`` take the packed aerodynamics and the packed contact
scene; the rod is a chain of capsules between its nodes (rod base, Gauss points, tip) and the tip
body a sphere; the obstacles' forces at the nodes add ``J^T [0; R^T f]`` to ``tau_ext`` with the
node Jacobians of the same recursion (the previous node's kept for the capsule's share).  The
``*_aero`` kernels are these with an empty contact array, the plain ones with both empty.

Flags: numba compiles a separate specialization of a kernel for each literal flag
(``True`` / ``False``) it receives from jitted code, besides the one for Python callers (a
plain ``bool``). The jitted callers pass ``bool(1)``, typed as a plain ``bool``, and share the
Python callers' build.

The forward dynamics (``forward_dynamics*``, ``rk4_run*``, and ``coupled_terms*`` with
``want_c = False``) runs the recursion of :mod:`tdacm.system.forward`: the same arithmetic as the
recursion below without ``C`` (bit-identical results), over ``J`` stored by rows with loops the
compiler vectorizes, without ``J_dot``, with one workspace per call.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._jit import kernel
from .._linalg import cholesky_into, cholesky_substitute
from ..aero import layout as AL
from ..contact import layout as CL
from ..contact.geometry import sdf
from ..lie.blocks import (
    ad_apply,
    adinv_apply,
    compose_rp_into,
    expmap_rp,
    expmap_rp_into,
    skew_apply_sub,
    tangent_apply_into,
)
from ..lie.euler import euler_rate_matrix, euler_rate_matrix_dot, rot_zyx
from ..lie.magnus import magnus_step, magnus_step_into
from .bodies import (  # noqa: F401  (the model arrays' building blocks, used here and re-exported)
    LOAD_DISTRIBUTED,
    LOAD_GRAVITY,
    LOAD_SLICES,
    LOAD_TIP,
    N_LOADS,
    _air_on_body,
    _air_on_drone,
    _has_probe,
    _node_contact,
    _rod_base_node,
    _rotor_setup,
    _tip_contact,
    body_bias_wrench,
    has_inertia,
    probe_point,
    skew_entry,
    step_wrench,
    tendon_accumulate,
    tendon_lengths_and_matrix,
)


class ModelArrays(NamedTuple):
    """Constant arrays of a built model, passed to every kernel (see ``TDACM``).

    The rods (one or several, each of one or several sections) are stored as chains of Magnus
    steps: rod ``r`` owns the steps ``rod_steps[r] <= k < rod_steps[r + 1]`` and starts at the
    attachment ``g_att[r]``.  Step ``k`` depends on the ``step_nc[k]`` strain coordinates starting
    at ``step_col[k]`` (indices into ``q_s``: the section it lies in); its basis block sits in the
    first ``step_nc[k]`` columns of ``bs[k]``.  After the step, a section (or body) of inertia
    ``step_mass[k]`` and weight ``step_w[k]`` (quadrature weight in metres, 1 for a point body,
    0 for none) adds its share to ``M``, ``C`` and ``tau_ext``; ``step_load[k]`` says which loads
    it carries (:data:`LOAD_DISTRIBUTED`, :data:`LOAD_TIP` or :data:`LOAD_GRAVITY` only).
    The Gauss-point arrays (``g_*``, ``wq``, ``bg``, ``tendon_*``) serve the tendon model.
    The last fields are computed once from the others (:func:`tdacm.system.forward.run_constants`
    and :meth:`TDACM._build`): a record with other stiffness, damping or basis arrays keeps
    their zeros (per-world factors do).
    """

    floating: bool
    g_fixed: np.ndarray  # (4, 4) clamp pose (fixed base only)
    g_att: np.ndarray  # (n_rods, 4, 4) attachments g_a^b
    rod_steps: np.ndarray  # (n_rods + 1,) int, first step of every rod (and the end)
    h: np.ndarray  # (n_steps,) Magnus step lengths (m)
    xi0s: np.ndarray  # (n_steps, p, 6) reference strain at the Magnus sample points
    bs: np.ndarray  # (n_steps, p, 6, w) basis block at the Magnus sample points
    step_col: np.ndarray  # (n_steps,) int, first strain coordinate of the step's section
    step_nc: np.ndarray  # (n_steps,) int, its number of strain coordinates
    step_w: np.ndarray  # (n_steps,) weight of the body after the step
    step_mass: np.ndarray  # (n_steps, 6) diagonal inertia (density) of that body
    step_load: np.ndarray  # (n_steps,) int, which loads it carries
    mb6: np.ndarray  # (6,) diagonal of the drone inertia (zeros for a fixed base)
    stiffness: np.ndarray  # (n, n) generalized stiffness, K(q) = stiffness @ q (eq. (18))
    damping: np.ndarray  # (n, n) generalized damping D (eq. (17), (19))
    gamma: np.ndarray  # (6, 4) motor thrusts -> body wrench (eq. (15))
    wq: np.ndarray  # (n_g,) quadrature weights (m) of all Gauss points of all rods
    xi0g: np.ndarray  # (n_g, 6) reference strain at the Gauss points
    bg: np.ndarray  # (n_g, 6, w) basis block at the Gauss points
    g_col: np.ndarray  # (n_g,) int, first strain coordinate of the point's section
    g_nc: np.ndarray  # (n_g,) int, its number of strain coordinates
    tendon_d: np.ndarray  # (n_g, n_a, 3) tendon offsets
    tendon_dd: np.ndarray  # (n_g, n_a, 3) d(offset)/ds
    tendon_on: np.ndarray  # (n_g, n_a) 1 where the tendon runs (its rod, before its end)
    # run constants (tdacm.system.forward.run_constants): computed once from the arrays above
    step_z: np.ndarray  # (n_steps, 6, w) h B (one sample) or h/2 (B_1 + B_2) (two)
    step_c4: np.ndarray  # (n_steps,) sqrt(3) h^2 / 12 (two samples), 0 (one)
    step_one: np.ndarray  # (n_steps,) int, 1: the step takes one sample
    step_nzc: np.ndarray  # (n_steps, 6, w) int, non-zero columns of each row of bs[k]
    step_nzn: np.ndarray  # (n_steps, 6) int, their number
    g_nzc: np.ndarray  # (n_g, 6, w) int, non-zero columns of each row of bg[i]
    g_nzn: np.ndarray  # (n_g, 6) int, their number
    g_nzr: np.ndarray  # (n_g, w, 6) int, non-zero rows of each column of bg[i]
    g_nzrn: np.ndarray  # (n_g, w) int, their number
    kd_lo: np.ndarray  # (n,) int, row i of K and D is zero outside columns kd_lo[i]..kd_hi[i]
    kd_hi: np.ndarray  # (n,) int


@njit(cache=True)
def base_state(q, qd, floating, g_fixed, n):
    """Drone pose ``g_b``, its Jacobian ``J_b^b`` (6 x n, eq. (3)) and ``J_dot_b^b``."""
    jb = np.zeros((6, n))
    jbd = np.zeros((6, n))
    if not floating:
        return g_fixed.copy(), jb, jbd
    r = rot_zyx(q[0], q[1], q[2])
    t = euler_rate_matrix(q[0], q[1])
    td = euler_rate_matrix_dot(q[0], q[1], qd[0], qd[1])
    g = np.eye(4)
    g[:3, :3] = r
    g[:3, 3] = q[3:6]
    w = np.zeros(3)
    for i in range(3):
        for k in range(3):
            w[i] += t[i, k] * qd[k]
            jb[i, k] = t[i, k]
            jbd[i, k] = td[i, k]
            jb[3 + i, 3 + k] = r[k, i]
    # d/dt R^T = -w~ R^T
    for i in range(3):
        for k in range(3):
            acc = 0.0
            for p in range(3):
                acc -= skew_entry(w, i, p) * r[k, p]
            jbd[3 + i, 3 + k] = acc
    return g, jb, jbd


@njit(cache=True)
def _matvec(a, x):
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        acc = 0.0
        for k in range(a.shape[1]):
            acc += a[i, k] * x[k]
        out[i] = acc
    return out


@njit(cache=True)
def _matmul(a, b):
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            aik = a[i, k]
            for c in range(b.shape[1]):
                out[i, c] += aik * b[k, c]
    return out


@njit(cache=True)
def _tmatvec_add(a, x, weight, out):
    """``out += weight * a^T x``."""
    for k in range(a.shape[1]):
        acc = 0.0
        for i in range(a.shape[0]):
            acc += a[i, k] * x[i]
        out[k] += weight * acc


@njit(cache=True)
def _add_body(mass6, j, jd, eta, jdq, weight, want_c, m_out, c_out, cqd_out):
    """Add a body (or a Gauss section with weight ``w``) with diagonal inertia ``mass6``.

    ``M += w J^T Mb J``; ``C qdot += w J^T (Mb J_dot qdot + coad(eta) Mb eta)``; and when
    ``want_c``, ``C += w J^T (Mb J_dot - S(Mb eta) J)``  (``eta = J qdot``, ``jdq = J_dot qdot``).
    """
    n = j.shape[1]
    for a in range(n):
        for b in range(a, n):
            acc = 0.0
            for r in range(6):
                acc += j[r, a] * mass6[r] * j[r, b]
            m_out[a, b] += weight * acc
            if b != a:
                m_out[b, a] += weight * acc
    f0, f1, f2, f3, f4, f5 = body_bias_wrench(mass6, eta, jdq)
    for a in range(n):
        cqd_out[a] += weight * (
            j[0, a] * f0 + j[1, a] * f1 + j[2, a] * f2 + j[3, a] * f3 + j[4, a] * f4 + j[5, a] * f5
        )
    if want_c:
        mu = mass6 * eta
        tmp = np.empty((6, n))
        for r in range(6):
            for c in range(n):
                tmp[r, c] = mass6[r] * jd[r, c]
        skew_apply_sub(mu, j, tmp)
        for a in range(n):
            for b in range(n):
                acc = 0.0
                for r in range(6):
                    acc += j[r, a] * tmp[r, b]
                c_out[a, b] += weight * acc


@njit(cache=True)
def chain_start(q, qd, floating, g_fixed, g_att):
    """Drone pose, then pose, Jacobian, Jacobian rate and ``J_dot qdot`` of the rod base ``O_a``.

    Returns ``g_b, J_b^b, J_dot_b^b, g_a, J_a, J_dot_a, J_dot_a qdot`` with
    ``J_a = Ad(g_a^b)^-1 J_b^b``.
    """
    gb, jb, jbd = base_state(q, qd, floating, g_fixed, q.shape[0])
    g, j, jd, jdq = rod_start(gb, jb, jbd, qd, g_att)
    return gb, jb, jbd, g, j, jd, jdq


@njit(cache=True)
def make_workspace(n, ns):
    """Scratch arrays for :func:`rod_step`, allocated once per kernel call (allocation inside
    the per-step loop dominated the cost of the small products)."""
    ncol = 2 * ns + 2
    return (
        np.empty(6),  # 0 omega
        np.empty((6, ns)),  # 1 Z
        np.empty(6),  # 2 Z_dot qdot
        np.empty((6, ns)),  # 3 Z_dot
        np.empty((6, 6, ns)),  # 4 Magnus scratch
        np.empty((3, 3)),  # 5 R of exp(Omega)
        np.empty(3),  # 6 p of exp(Omega)
        np.empty((6, ncol)),  # 7 columns fed to the tangent operator
        np.empty((6, ncol)),  # 8 T X
        np.empty((6, ncol)),  # 9 T_dot X
        np.empty((5, 6, ncol)),  # 10 tangent scratch
        np.empty((6, 4)),  # 11 vector columns: relative twist, J_dot qdot, eta, ad product
        np.empty((6, n)),  # 12 ad(w) J
        np.empty((3, 3)),  # 13 copy of the rotation of g
        np.empty(6),  # 14 Omega_dot
    )


@kernel
def rod_step(h, xi0s, bs, qs, qsd, off, g, j, jd, eta, jdq, full_rate, ws):
    """One Magnus step of the pose / Jacobian / Jacobian-rate recursion (module docstring).

    Updates in place ``g`` (4x4), ``j`` (6 x n), the twist ``eta = J qdot`` and
    ``jdq = J_dot qdot``; ``jd`` (6 x n) too when ``full_rate`` (needed for the matrix ``C``,
    not for the forward dynamics).  ``ws`` is a :func:`make_workspace` tuple.
    """
    omega, z, zdq, zd, mwork, r, p, x, tx, tdx, twork, cols, tmpj, gr, omega_dot = ws
    ns = qs.shape[0]
    magnus_step_into(h, xi0s, bs, qs, qsd, omega, z, zdq, zd, mwork)
    expmap_rp_into(omega, r, p)
    # columns [Omega_dot | Z | Z_dot qdot | Z_dot]; the rate T_dot is needed for Omega_dot (the
    # J_dot qdot recursion) and, for the full J_dot, for Z too
    for i in range(6):
        acc = 0.0
        for c in range(ns):
            x[i, 1 + c] = z[i, c]
            x[i, ns + 2 + c] = zd[i, c]
            acc += z[i, c] * qsd[c]
        x[i, 0] = acc
        x[i, ns + 1] = zdq[i]
    order4 = xi0s.shape[0] == 2
    # order 2: Z_dot = 0, so the (zero) Z_dot columns are skipped
    ncol = (2 * ns + 2 if full_rate else ns + 2) if order4 else ns + 1
    n_rate = ns + 1 if full_rate else 1
    for i in range(6):
        omega_dot[i] = x[i, 0]
    tangent_apply_into(
        omega, omega_dot, x[:, :ncol], n_rate, tx[:, :ncol], tdx[:, :n_rate], twork[:, :, :ncol]
    )
    # increments before the change of frame; T Omega_dot is the relative twist of the step
    w = cols[:, 0:1]
    v = cols[:, 1:2]
    e = cols[:, 2:3]
    t = cols[:, 3:4]
    for i in range(6):
        for c in range(ns):
            j[i, off + c] += tx[i, 1 + c]
            if full_rate:
                jd[i, off + c] += tdx[i, 1 + c] + (tx[i, ns + 2 + c] if order4 else 0.0)
        w[i, 0] = tx[i, 0]
        v[i, 0] = jdq[i] + tdx[i, 0] + (tx[i, ns + 1] if order4 else 0.0)
        e[i, 0] = eta[i] + tx[i, 0]
    adinv_apply(r, p, j)
    adinv_apply(r, p, cols[:, 0:3])
    wv = cols[:, 0]
    ad_apply(wv, e, t)
    for i in range(6):
        eta[i] = e[i, 0]
        jdq[i] = v[i, 0] - t[i, 0]
    if full_rate:
        adinv_apply(r, p, jd)
        ad_apply(wv, j, tmpj)
        for i in range(6):
            for c in range(j.shape[1]):
                jd[i, c] -= tmpj[i, c]
    compose_rp_into(g, gr, r, p)  # g <- g exp(Omega)


@njit(cache=True)
def coupled_terms(q, qd, m, loads, want_c):
    """``M``, ``C`` (zeros unless ``want_c``), ``C qdot``, ``tau_ext``, tip pose, tip ``J``, tip
    ``J_dot`` (paper eqs. (10), (11), (16)); the last is zeros unless ``want_c``.  The tip
    returned is the last rod's.

    ``m`` is a :class:`ModelArrays`: every rod is a chain of Magnus steps from its attachment;
    after each step the body described by ``m.step_w``, ``m.step_mass`` and ``m.step_load``
    (a Gauss section of the rod, a joint mass, the tip body) adds its inertia and loads.
    """
    return coupled_terms_aero(q, qd, m, loads, want_c, np.empty(0), np.empty(0))


@njit(cache=True)
def coupled_terms_aero(q, qd, m, loads, want_c, u, aero):
    """:func:`coupled_terms` with the aerodynamic wrench densities of the rod sections, the tip
    body and the drone added to ``tau_ext`` (eq. (16)); ``aero`` is the packed array of
    :mod:`tdacm.aero.layout` (empty: none) and ``u`` the inputs (the rotor thrusts make the
    wake).  With an empty ``aero`` the arithmetic is exactly that of :func:`coupled_terms`."""
    return coupled_terms_env(q, qd, m, loads, want_c, u, aero, np.empty(0))


@njit(cache=True)
def _add_point_force(j, g, fx, fy, fz, tau):
    """``tau += J^T [0; R^T f]``: an inertial force ``f`` at the origin of the frame ``g``."""
    f = np.zeros(6)
    for i in range(3):
        f[3 + i] = g[0, i] * fx + g[1, i] * fy + g[2, i] * fz
    _tmatvec_add(j, f, 1.0, tau)


@njit(cache=True)
def coupled_terms_env(q, qd, m, loads, want_c, u, aero, contact):
    """:func:`coupled_terms` with the loads of the environment: the aerodynamics of the packed
    array ``aero`` (:func:`coupled_terms_aero`) and the contact of the rod's backbone and tip
    body with the obstacles of the packed array ``contact`` (:mod:`tdacm.contact.layout`), as
    forces at the rod's nodes (the rod base, its Gauss points and its tip) entering
    ``tau_ext`` through the node Jacobians (eq. (16)).  Empty arrays: none (the arithmetic of
    :func:`coupled_terms`)."""
    if not want_c:  # the same arithmetic, faster (tdacm.system.forward)
        m_out, cqd, tau, g, j, jd = _F.forward_terms(q, qd, m, loads, u, aero, contact)
        n = q.shape[0]
        return m_out, np.zeros((n, n)), cqd, tau, g, j, jd
    floating = m.floating
    n = q.shape[0]
    off = 6 if floating else 0
    m_out = np.zeros((n, n))
    c_out = np.zeros((n, n))
    cqd = np.zeros(n)
    tau = np.zeros(n)
    grav = loads[0:3]
    gb, jb, jbd = base_state(q, qd, floating, m.g_fixed, n)
    f = np.empty(6)
    air = aero.shape[0] > 0
    drone_air = air and floating and aero[AL.DRONE_ON] > 0.0
    rod_air = air and aero[AL.ROD_ON] > 0.0
    wake = rod_air and aero[AL.WAKE_ON] > 0.0
    rot = np.empty((AL.N_ROTORS, AL.ROTOR_STATE))
    ax = ay = az = 0.0
    if wake:
        ax, ay, az = _rotor_setup(q, qd, u, m, gb, aero, rot)
    nst = m.h.shape[0]
    if floating:
        _add_body(m.mb6, jb, jbd, _matvec(jb, qd), _matvec(jbd, qd), 1.0, want_c, m_out, c_out, cqd)
        for i in range(6):
            f[i] = loads[3 + i]
        for i in range(3):
            for k in range(3):
                f[3 + i] += m.mb6[3] * gb[k, i] * grav[k]
        if drone_air:
            d0, d1, d2 = _air_on_drone(gb, _matvec(jb, qd), aero)
            f[3] += d0
            f[4] += d1
            f[5] += d2
        _tmatvec_add(jb, f, 1.0, tau)
    ws = make_workspace(n, m.bs.shape[3])
    g = np.eye(4)
    j = np.zeros((6, n))
    jd = np.zeros((6, n))
    cont = contact.shape[0] > 0
    prev = np.empty(6)
    fa = np.empty(6)
    fb = np.empty(3)
    mb = np.zeros(3)
    probe = cont and _has_probe(contact)
    g_prev = np.eye(4)
    j_prev = np.zeros((6, n))
    for rod in range(m.rod_steps.shape[0] - 1):
        g, j, jd, jdq = rod_start(gb, jb, jbd, qd, m.g_att[rod])
        eta = _matvec(j, qd)
        if cont:
            _rod_base_node(g, eta, prev)
            g_prev[:] = g
            j_prev[:] = j
        for k in range(m.rod_steps[rod], m.rod_steps[rod + 1]):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            rod_step(
                m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], qd[c0:c1], c0, g, j, jd, eta, jdq, want_c, ws
            )
            w = m.step_w[k]
            if w == 0.0:
                continue
            mass6 = m.step_mass[k]
            if has_inertia(mass6):
                _add_body(mass6, j, jd, eta, jdq, w, want_c, m_out, c_out, cqd)
            lo = m.step_load[k]
            step_wrench(
                f, g, eta, k, lo, mass6, grav, loads, rod_air, aero, nst, rot, ax, ay, az, wake
            )
            _tmatvec_add(j, f, w, tau)
            if cont and lo != LOAD_GRAVITY:
                hit_a, hit_b = _node_contact(contact, k, g, eta, prev, fa, fb)
                mb[0] = mb[1] = mb[2] = 0.0
                if lo == LOAD_TIP and _tip_contact(contact, g, eta, fb, mb):
                    hit_b = True
                if hit_a:
                    _add_point_force(j_prev, g_prev, fa[0], fa[1], fa[2], tau)
                if hit_b:
                    _add_point_force(j, g, fb[0], fb[1], fb[2], tau)
                    if probe and lo == LOAD_TIP:
                        _tmatvec_add(j, np.array([mb[0], mb[1], mb[2], 0.0, 0.0, 0.0]), 1.0, tau)
                g_prev[:] = g
                j_prev[:] = j
    return m_out, c_out, cqd, tau, g, j, jd


@njit(cache=True)
def rod_start(gb, jb, jbd, qd, g_att):
    """Pose, Jacobian, Jacobian rate and ``J_dot qdot`` of a rod base ``O_a`` from the drone's:
    ``J_a = Ad(g_a^b)^-1 J_b^b``."""
    ra = g_att[:3, :3].copy()
    pa = g_att[:3, 3].copy()
    j = jb.copy()
    jd = jbd.copy()
    adinv_apply(ra, pa, j)
    adinv_apply(ra, pa, jd)
    return _matmul(gb, g_att), j, jd, _matvec(jd, qd)


@njit(cache=True)
def chain_poses(q, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs):
    """Poses after every Magnus step (n_steps, 4, 4) of one chain, the rod base pose and the
    drone pose (``cols``, ``ncs``: strain block of every step, as in :class:`ModelArrays`)."""
    off = 6 if floating else 0
    gb, _, _ = base_state(q, np.zeros(q.shape[0]), floating, g_fixed, q.shape[0])
    g = _matmul(gb, g_att)
    g0 = g.copy()
    out = np.empty((h.shape[0], 4, 4))
    for k in range(h.shape[0]):
        c0 = off + cols[k]
        qs = q[c0 : c0 + ncs[k]]
        omega, _, _, _ = magnus_step(h[k], xi0s[k], bs[k], qs, np.zeros(qs.shape[0]))
        r, p = expmap_rp(omega)
        e = np.eye(4)
        e[:3, :3] = r
        e[:3, 3] = p
        g = _matmul(g, e)
        out[k] = g
    return out, g0, gb


@njit(cache=True)
def chain_jacobian(q, qd, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs):
    """Pose, Jacobian and Jacobian rate at the end of an arbitrary chain of Magnus steps."""
    off = 6 if floating else 0
    _, _, _, g, j, jd, jdq = chain_start(q, qd, floating, g_fixed, g_att)
    eta = _matvec(j, qd)
    ws = make_workspace(q.shape[0], bs.shape[3])
    for k in range(h.shape[0]):
        c0 = off + cols[k]
        c1 = c0 + ncs[k]
        rod_step(h[k], xi0s[k], bs[k], q[c0:c1], qd[c0:c1], c0, g, j, jd, eta, jdq, bool(1), ws)
    return g, j, jd


@njit(cache=True)
def chain_frames(q, qd, m, rod):
    """Pose (n_k, 4, 4) and twist ``J qdot`` (n_k, 6) after every step of rod ``rod``."""
    off = 6 if m.floating else 0
    n = q.shape[0]
    gb, jb, jbd = base_state(q, qd, m.floating, m.g_fixed, n)
    g, j, jd, jdq = rod_start(gb, jb, jbd, qd, m.g_att[rod])
    eta = _matvec(j, qd)
    ws = make_workspace(n, m.bs.shape[3])
    lo, hi = m.rod_steps[rod], m.rod_steps[rod + 1]
    poses = np.empty((hi - lo, 4, 4))
    twists = np.empty((hi - lo, 6))
    for k in range(lo, hi):
        c0 = off + m.step_col[k]
        c1 = c0 + m.step_nc[k]
        rod_step(m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], qd[c0:c1], c0, g, j, jd, eta, jdq, bool(0),
                 ws)  # fmt: skip
        poses[k - lo] = g
        twists[k - lo] = eta
    return poses, twists


@njit(cache=True)
def cholesky_solve(a, b):
    """Solve ``a x = b`` for symmetric positive definite ``a`` (small, dense); returns
    ``(x, ok)`` with ``ok = False`` when ``a`` is not positive definite."""
    n = a.shape[0]
    lo = np.zeros((n, n))
    if not cholesky_into(a, n, lo):
        return np.zeros(n), False
    x = np.empty(n)
    cholesky_substitute(lo, n, b, np.empty(n), x)
    return x, True


@njit(cache=True)
def tendon_matrix(qs, m):
    """``B_s(q)`` (n_s x n_a) of :func:`tendon_lengths_and_matrix`."""
    return tendon_lengths_and_matrix(qs, m)[1]


@njit(cache=True)
def input_matrix(q, m):
    """Generalized actuation matrix ``B(q)`` (paper eq. (14)-(16)): n x (4 + n_a) for a
    floating base (motor thrusts, then tensions), n_s x n_a for a fixed base."""
    n = q.shape[0]
    if not m.floating:
        return tendon_matrix(q, m)
    na = m.tendon_d.shape[1]
    out = np.zeros((n, 4 + na))
    r = rot_zyx(q[0], q[1], q[2])
    t = euler_rate_matrix(q[0], q[1])
    for i in range(3):
        for c in range(4):
            a0 = 0.0
            a1 = 0.0
            for k in range(3):
                a0 += t[k, i] * m.gamma[k, c]
                a1 += r[i, k] * m.gamma[3 + k, c]
            out[i, c] = a0
            out[3 + i, c] = a1
    out[6:, 4:] = tendon_matrix(q[6:], m)
    return out


@njit(cache=True)
def forward_dynamics(q, qd, u, m, loads):
    """``qdd = M^-1 (B u + tau_ext - C qdot - D qdot - K)`` (paper eq. (9)); ``ok`` False when
    ``M`` is not positive definite (Euler singularity)."""
    return forward_dynamics_aero(q, qd, u, m, loads, np.empty(0))


@njit(cache=True)
def forward_dynamics_aero(q, qd, u, m, loads, aero):
    """:func:`forward_dynamics` with the aerodynamic loads of the packed array ``aero`` (empty:
    none, bit-identical to :func:`forward_dynamics`)."""
    return forward_dynamics_env(q, qd, u, m, loads, aero, np.empty(0))


@njit(cache=True)
def forward_dynamics_env(q, qd, u, m, loads, aero, contact):
    """:func:`forward_dynamics` with the environment's loads (:func:`coupled_terms_env`:
    aerodynamics and contact; empty arrays: none, bit-identical)."""
    qdd = np.empty(q.shape[0])
    ok = _F.forward_dynamics_ws(q, qd, u, m, loads, aero, contact, _F.workspace(q.shape[0], m), qdd)
    return qdd, ok


@njit(cache=True)
def rk4_run(q0, qd0, u, dt, nsteps, every, m, loads):
    """Integrate with classical RK4 at constant input ``u``; keep every ``every``-th state.

    Returns ``(qs, qds, ok)``; ``ok`` is False if the mass matrix became singular, in which case
    the arrays hold the states up to that point.
    """
    return rk4_run_aero(q0, qd0, u, dt, nsteps, every, m, loads, np.empty(0))


@njit(cache=True)
def rk4_run_aero(q0, qd0, u, dt, nsteps, every, m, loads, aero):
    """:func:`rk4_run` with the aerodynamic loads of the packed array ``aero`` (held, like the
    loads, over the call; the wake follows the state at every stage)."""
    return rk4_run_env(q0, qd0, u, dt, nsteps, every, m, loads, aero, np.empty(0))


@njit(cache=True)
def rk4_run_env(q0, qd0, u, dt, nsteps, every, m, loads, aero, contact):
    """:func:`rk4_run` with the environment's loads (:func:`forward_dynamics_env`: the packed
    aerodynamics and contact arrays, held over the call; empty: none)."""
    return _F.rk4_steps(q0, qd0, u, dt, nsteps, every, m, loads, aero, contact)


@njit(cache=True)
def contact_nodes(q, qd, m, contact):
    """The contact state of every rod node (the rod bases, Gauss points and tips, in order):
    ``(points (N, 3), forces (N, 3), tip_force (3,), clearance, speed)`` with the inertial
    forces the obstacles apply on the nodes (the capsules' shares and, at the last rod's tip,
    the tip sphere's, which is also ``tip_force``), the smallest clearance ``sdf - radius``
    of a node sphere (rod radius, or the tip sphere) over the obstacles, and the largest node
    speed.  The same arithmetic as :func:`coupled_terms_env`."""
    off = 6 if m.floating else 0
    n = q.shape[0]
    nrod = m.rod_steps.shape[0] - 1
    count = nrod
    for k in range(m.h.shape[0]):
        if m.step_w[k] != 0.0 and m.step_load[k] != LOAD_GRAVITY:
            count += 1
    points = np.zeros((count, 3))
    forces = np.zeros((count, 3))
    tip = np.zeros(3)
    clearance = np.inf
    speed = 0.0
    gb, jb, jbd = base_state(q, qd, m.floating, m.g_fixed, n)
    ws = make_workspace(n, m.bs.shape[3])
    prev = np.empty(6)
    fa = np.empty(6)
    fb = np.empty(3)
    mb = np.zeros(3)
    nsh = int(contact[CL.N_SHAPES])
    node = 0
    for rod in range(nrod):
        g, j, jd, jdq = rod_start(gb, jb, jbd, qd, m.g_att[rod])
        eta = _matvec(j, qd)
        _rod_base_node(g, eta, prev)
        points[node] = prev[0:3]
        node += 1
        for k in range(m.rod_steps[rod], m.rod_steps[rod + 1]):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            rod_step(
                m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], qd[c0:c1], c0, g, j, jd, eta, jdq, False, ws
            )
            lo = m.step_load[k]
            if m.step_w[k] == 0.0 or lo == LOAD_GRAVITY:
                continue
            _node_contact(contact, k, g, eta, prev, fa, fb)
            for i in range(3):
                forces[node - 1, i] += fa[i]
            if lo == LOAD_TIP:
                t0 = fb[0]
                t1 = fb[1]
                t2 = fb[2]
                if _tip_contact(contact, g, eta, fb, mb):
                    tip[0] = fb[0] - t0
                    tip[1] = fb[1] - t1
                    tip[2] = fb[2] - t2
            for i in range(3):
                points[node, i] = g[i, 3]
                forces[node, i] += fb[i]
            sp = np.sqrt(prev[3] ** 2 + prev[4] ** 2 + prev[5] ** 2)
            speed = max(speed, sp)
            r = contact[CL.N_HEADER + k] if contact[CL.ROD_ON] > 0.0 else 0.0
            probe_tip = lo == LOAD_TIP and contact[CL.TIP_ON] > 0.0 and _has_probe(contact)
            if lo == LOAD_TIP and contact[CL.TIP_ON] > 0.0 and not probe_tip:
                r = max(r, contact[CL.TIP_RADIUS])
            if r > 0.0:
                for s in range(nsh):
                    base = contact.shape[0] - (nsh - s) * CL.SHAPE_SIZE
                    d = sdf(contact, base, g[0, 3], g[1, 3], g[2, 3])[0]
                    clearance = min(clearance, d - r)
            if probe_tip:  # the sphere at the probe's end, and the fastest point its end
                x, v = probe_point(contact, g, eta)
                speed = max(speed, np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2))
                for s in range(nsh):
                    base = contact.shape[0] - (nsh - s) * CL.SHAPE_SIZE
                    d = sdf(contact, base, x[0], x[1], x[2])[0]
                    clearance = min(clearance, d - contact[CL.TIP_RADIUS])
            node += 1
    return points, forces, tip, clearance, speed


from . import forward as _F  # noqa: E402  (it uses this module's helpers)
