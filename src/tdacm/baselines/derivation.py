"""Symbolic derivation of the constant-curvature (CC) coupled Lagrangian model.

The classical way to model an aerial continuum manipulator (Samadikhoshkho et al., the paper's
baseline [samadikhoshkho2021coupled]): write the kinetic and potential energies of the drone and
of a constant-curvature rod in the generalized coordinates with a computer-algebra system, then
obtain the equations of motion by differentiation,

    M(q) = d^2 T / d qdot^2,
    C_ij = sum_k Gamma_ijk qdot_k,  Gamma_ijk = 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i),
    G = dV_gravity/dq,  K = dV_elastic/dq,  tau_load = -dV_load/dq,  B = -d(tendon lengths)/dq
    (tendons) and blkdiag(T^T, R_b) Gamma (motors),

and generate numeric code from the expressions (here: common-subexpression elimination and
Python/``math`` code, see :mod:`tdacm.baselines.codegen`).

Coordinates: ``q = [phi, theta, psi, x, y, z, k_y, k_z]`` (floating base; ZYX Euler angles and
the drone's centre of mass, as in the GVS model) or ``q = [k_y, k_z]`` (clamped base at the
identity pose).  The rod's strain is ``xi = [0, k_y, k_z, 1, 0, 0]``, its sections
``g_s^a = exp(s xi^)``:

    R_arc(s) = I + s c_1 W + s^2 c_2 W^2,   p_arc(s) = [s c_1, k_z s^2 c_2, -k_y s^2 c_2],
    W = skew([0, k_y, k_z]),   c_k = c_k((k_y^2 + k_z^2) s^2)  (Stumpff functions),

exact for every curvature and free of the ``1/kappa`` singularity of the textbook
``(1 - cos(kappa s))/kappa`` form (see :mod:`tdacm.baselines.stumpff`).  The angular velocity of a
section in its own frame is ``R_arc^T R_a^T w_b + s (I - s c_2 W + s^2 c_3 W^2) [0, k_y', k_z']``
(right Jacobian of the exponential).

Discretization: as Lagrangian CC models do in practice, the rod's kinetic and gravitational
energies are Gauss-Legendre sums over ``n_gauss`` sections (the same points as the GVS model, so
that the two discretizations coincide) plus the tip point mass at ``s = L``.  Each section has
the inertia density ``rho diag(J, I, I, A, A, A)``.

``M`` is the Hessian of ``T = 1/2 sum_b (m_b |J_v,b qdot|^2 + (J_w,b qdot)^T I_b (J_w,b qdot))``;
since ``T`` is a sum of squares of linear forms in ``qdot`` its Hessian is formed directly as
``sum_b J_v^T m J_v + J_w^T I J_w`` (the expression ``sympy.hessian`` would return, without
differentiating the expanded squares).  ``dM/dq_k`` is derived by the product rule on that
sum, ``sum c ((dJ/dq_k)^T J + J^T dJ/dq_k)`` with ``dJ/dq_k`` differentiated symbolically
(differentiating the assembled entries of ``M`` gives the same functions but took 36-65 s
instead of 17-27 s here, and 16,445 instead of 11,915 operations after CSE); every other
term is a plain symbolic gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from ..base.quadrotor import gamma_rows
from .stumpff import STUMPFF

#: bump when the derivation changes (part of the cache key)
DERIVATION_VERSION = "2"

#: physical parameters passed to the generated code at run time, in this order
PARAM_NAMES = (
    "m_b",  # drone mass (kg)
    "I1",
    "I2",
    "I3",  # drone principal inertias (kg m^2)
    "mu",  # rod mass per length rho A (kg/m)
    "rho_I",  # rotational inertia density rho I (kg m); torsion uses rho J = 2 rho I
    "L",  # rod length (m)
    "m_tip",  # tip point mass (kg)
    "h_att",  # attachment offset below the drone's centre of mass (m)
    "EI",  # bending stiffness (N m^2)
    "r_t",  # tendon offset radius (m)
    "r_m",  # motor arm length (m)
    "k_d",  # rotor drag factor (m)
    "gx",
    "gy",
    "gz",  # gravity (m/s^2, inertial)
    "fx",
    "fy",
    "fz",  # dead load on the tip (N, inertial)
)

FLOATING_COORDS = ("phi", "theta", "psi", "x", "y", "z", "k_y", "k_z")
FIXED_COORDS = ("k_y", "k_z")


@dataclass(frozen=True)
class DerivationSpec:
    """What the symbolic derivation depends on (the cache key, with the sympy version)."""

    floating: bool = True
    n_gauss: int = 5

    @property
    def coords(self) -> tuple:
        return FLOATING_COORDS if self.floating else FIXED_COORDS

    @property
    def n(self) -> int:
        return len(self.coords)

    @property
    def n_u(self) -> int:
        return 8 if self.floating else 4


@dataclass
class Derived:
    """Symbolic results: matrices as sympy ``Matrix``, energies as expressions."""

    spec: DerivationSpec
    q: tuple
    qd: tuple
    params: tuple
    M: sp.Matrix
    C: sp.Matrix
    G: sp.Matrix
    K: sp.Matrix
    tau_load: sp.Matrix
    B: sp.Matrix
    T: sp.Expr
    V_gravity: sp.Expr
    V_elastic: sp.Expr
    V_load: sp.Expr
    tip_position: sp.Matrix
    tip_rotation: sp.Matrix


def _skew(v):
    return sp.Matrix([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _rot_zyx(phi, theta, psi):
    cx, sx = sp.cos(phi), sp.sin(phi)
    cy, sy = sp.cos(theta), sp.sin(theta)
    cz, sz = sp.cos(psi), sp.sin(psi)
    rz = sp.Matrix([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = sp.Matrix([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = sp.Matrix([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return rz * ry * rx


def _euler_rate(phi, theta):
    """``T``: ZYX Euler rates -> body angular velocity (paper eq. (4))."""
    return sp.Matrix(
        [
            [1, 0, -sp.sin(theta)],
            [0, sp.cos(phi), sp.sin(phi) * sp.cos(theta)],
            [0, -sp.sin(phi), sp.cos(phi) * sp.cos(theta)],
        ]
    )


def derive(spec: DerivationSpec) -> Derived:
    """Energies and equations of motion of the CC coupled model (module docstring)."""
    q = sp.symbols(spec.coords)
    qd = sp.symbols(tuple("d" + c for c in spec.coords))
    par = dict(zip(PARAM_NAMES, sp.symbols(PARAM_NAMES), strict=True))
    n = spec.n
    ky, kz = q[-2], q[-1]
    kyd, kzd = qd[-2], qd[-1]
    if spec.floating:
        phi, theta, psi = q[:3]
        rb = sp.Matrix(q[3:6])
        Rb = _rot_zyx(phi, theta, psi)
        Tm = _euler_rate(phi, theta)
        wb = Tm * sp.Matrix(qd[:3])
    else:
        rb = sp.zeros(3, 1)
        Rb = sp.eye(3)
        Tm = None
        wb = sp.zeros(3, 1)
    Ra = sp.Matrix([[0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    pa = sp.Matrix([0, 0, -par["h_att"]])
    W = _skew((0, ky, kz))
    wdot = sp.Matrix([0, kyd, kzd])
    L = par["L"]
    grav = sp.Matrix([par["gx"], par["gy"], par["gz"]])

    def section(s):
        zz = (ky**2 + kz**2) * s**2
        c1, c2, c3 = (STUMPFF[k](zz) for k in (1, 2, 3))
        r_arc = sp.eye(3) + s * c1 * W + s**2 * c2 * W * W
        p_arc = sp.Matrix([s * c1, kz * s**2 * c2, -ky * s**2 * c2])
        p = rb + Rb * (pa + Ra * p_arc)
        w = r_arc.T * (Ra.T * wb) + s * (wdot - s * c2 * (W * wdot) + s**2 * c3 * (W * (W * wdot)))
        return p, w, Rb * Ra * r_arc

    qv, qdv = sp.Matrix(q), sp.Matrix(qd)
    xg, wg = np.polynomial.legendre.leggauss(spec.n_gauss)
    xg, wg = 0.5 * (xg + 1.0), 0.5 * wg
    # bodies: (position, angular velocity, mass, rotational inertia diag) with quadrature weight
    # inertia terms (c, J): T = 1/2 sum c |J qdot|^2, hence M = sum c J^T J
    inertia_terms = []
    T = sp.Integer(0)
    V_grav = sp.Integer(0)
    rot_density = (2 * par["rho_I"], par["rho_I"], par["rho_I"])
    for x, w in zip(xg, wg, strict=True):
        s = sp.Float(float(x), 17) * L
        wl = sp.Float(float(w), 17) * L
        p, om, _ = section(s)
        jv = p.jacobian(qv)
        jw = om.jacobian(qdv)
        inertia_terms.append((wl * par["mu"], jv))
        for a in range(3):
            inertia_terms.append((wl * rot_density[a], jw[a, :]))
        v = jv * qdv
        T += (
            wl * (par["mu"] * (v.T * v)[0] + sum(rot_density[a] * om[a] ** 2 for a in range(3))) / 2
        )
        V_grav -= wl * par["mu"] * (grav.T * p)[0]
    p_tip, _, r_tip = section(L)
    jv = p_tip.jacobian(qv)
    inertia_terms.append((par["m_tip"], jv))
    v = jv * qdv
    T += par["m_tip"] * (v.T * v)[0] / 2
    V_grav -= par["m_tip"] * (grav.T * p_tip)[0]
    f_tip = sp.Matrix([par["fx"], par["fy"], par["fz"]])
    V_load = -(f_tip.T * p_tip)[0]
    if spec.floating:
        ib = (par["I1"], par["I2"], par["I3"])
        jw = wb.jacobian(qdv)
        jv = rb.jacobian(qv)
        inertia_terms.append((par["m_b"], jv))
        for a in range(3):
            inertia_terms.append((ib[a], jw[a, :]))
        T += (
            par["m_b"] * (qdv[3:6, 0].T * qdv[3:6, 0])[0]
            + sum(ib[a] * wb[a] ** 2 for a in range(3))
        ) / 2
        V_grav -= par["m_b"] * (grav.T * rb)[0]
    V_el = par["EI"] * L * (ky**2 + kz**2) / 2

    M = sp.zeros(n, n)
    for c, jac in inertia_terms:
        M += c * (jac.T * jac)

    # Christoffel symbols of the first kind from symbolic dM/dq, by the product rule on
    # M = sum c J^T J: dM/dq_k = A_k + A_k^T, A_k = sum c (dJ/dq_k)^T J.  (Differentiating the
    # assembled entries of M gives the same expressions but takes minutes in sympy.)
    dMk = []
    for qk in q:
        a = sp.zeros(n, n)
        for c, jac in inertia_terms:
            if qk in jac.free_symbols:
                a += c * (jac.diff(qk).T * jac)
        dMk.append(a + a.T)

    def dm(i, j, k):
        return dMk[k][i, j]

    C = sp.zeros(n, n)
    for i in range(n):
        for j in range(n):
            C[i, j] = sum((dm(i, j, k) + dm(i, k, j) - dm(j, k, i)) * qd[k] / 2 for k in range(n))

    G = sp.Matrix([sp.diff(V_grav, qk) for qk in q])
    Kf = sp.Matrix([sp.diff(V_el, qk) for qk in q])
    tau_load = sp.Matrix([-sp.diff(V_load, qk) for qk in q])

    # tendons: parallel at r_t on +y, +z, -y, -z; a CC rod makes each one a straight line in the
    # curved frame of length l_i = L (1 + k_y d_z - k_z d_y); tension T_i does -T_i dl_i/dq
    r = par["r_t"]
    offsets = ((r, 0), (0, r), (-r, 0), (0, -r))
    lengths = [L * (1 + ky * dz - kz * dy) for dy, dz in offsets]
    Bs = sp.Matrix([[-sp.diff(li, qk) for li in lengths] for qk in q])
    if spec.floating:
        rm, kd = par["r_m"], par["k_d"]
        gamma = sp.Matrix(gamma_rows(rm, kd))
        # virtual work of the body wrench: J_b^b^T Gamma u, J_b^b = blkdiag(T, R_b^T) on (Euler, r)
        jb = sp.zeros(6, n)
        jb[:3, :3] = Tm
        jb[3:, 3:6] = Rb.T
        Bm = jb.T * gamma
        B = Bm.row_join(Bs)
    else:
        B = Bs
    return Derived(
        spec,
        q,
        qd,
        tuple(par.values()),
        M,
        C,
        G,
        Kf,
        tau_load,
        B,
        T,
        V_grav,
        V_el,
        V_load,
        p_tip,
        r_tip,
    )
