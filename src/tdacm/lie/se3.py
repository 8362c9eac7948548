"""SE(3) / se(3) kernels with the angular-first convention.

A twist (or strain) is ``xi = [k; u]`` (angular part ``k``, linear part ``u``), a wrench is
``[m; f]``.  Every function here is a numba kernel over plain ``float64`` arrays so that the
rod recursion can call them without Python overhead; they are also the public reference
implementation used by the tests.

Formulas (Renda et al. 2020, "Geometric variable-strain approach"; ``docs/model.md``):

* ``ad(xi) = [[k~, 0], [u~, k~]]``,  ``coad(xi) = -ad(xi)^T``
* ``Ad(g) = [[R, 0], [p~ R, R]]``,   ``Ad(g)^-1 = [[R^T, 0], [-R^T p~, R^T]]``
* ``exp(Omega^) = I + Omega^ + (1-cos th)/th^2 Omega^2 + (th-sin th)/th^3 Omega^3``
* ``T(Omega) = I + a1 ad + a2 ad^2 + a3 ad^3 + a4 ad^4`` (the tangent operator ``dexp``),
  so that for ``g = g0 exp(Omega(t))`` the body twist is ``Ad(exp Omega)^-1 (eta0 + T(Omega) Omega_dot)``.

Near ``th = 0`` the closed forms cancel catastrophically, so below ``SMALL_ANGLE`` every
coefficient is evaluated from its Taylor series (truncation below 1e-16 relative there; the
closed forms lose about ``eps / th^8`` to cancellation, ~1e-15 at the switch).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import kernel

#: Below this rotation angle the trigonometric coefficients use their Taylor series.
SMALL_ANGLE = 1.0


@njit(cache=True)
def skew(v):
    """3x3 skew-symmetric matrix ``v~`` with ``v~ w = v x w``."""
    m = np.zeros((3, 3))
    m[0, 1] = -v[2]
    m[0, 2] = v[1]
    m[1, 0] = v[2]
    m[1, 2] = -v[0]
    m[2, 0] = -v[1]
    m[2, 1] = v[0]
    return m


@njit(cache=True)
def unskew(m):
    """Inverse of :func:`skew` (takes the skew part of ``m``)."""
    return np.array(
        [0.5 * (m[2, 1] - m[1, 2]), 0.5 * (m[0, 2] - m[2, 0]), 0.5 * (m[1, 0] - m[0, 1])]
    )


@njit(cache=True)
def hat(xi):
    """4x4 matrix of the twist ``xi = [k; u]``."""
    m = np.zeros((4, 4))
    m[:3, :3] = skew(xi[:3])
    m[0, 3] = xi[3]
    m[1, 3] = xi[4]
    m[2, 3] = xi[5]
    return m


@njit(cache=True)
def vee(m):
    """Inverse of :func:`hat`."""
    out = np.empty(6)
    out[:3] = unskew(m[:3, :3])
    out[3] = m[0, 3]
    out[4] = m[1, 3]
    out[5] = m[2, 3]
    return out


@njit(cache=True)
def ad(xi):
    """6x6 adjoint of the Lie algebra, ``ad(xi) = [[k~, 0], [u~, k~]]``."""
    m = np.zeros((6, 6))
    k = skew(xi[:3])
    m[:3, :3] = k
    m[3:, 3:] = k
    m[3:, :3] = skew(xi[3:])
    return m


@njit(cache=True)
def coad(xi):
    """Co-adjoint ``ad*(xi) = -ad(xi)^T`` acting on wrenches."""
    return -ad(xi).T.copy()


@njit(cache=True)
def Ad(g):
    """6x6 adjoint of the group element ``g`` (4x4): ``[[R, 0], [p~ R, R]]``."""
    m = np.zeros((6, 6))
    r = g[:3, :3].copy()
    m[:3, :3] = r
    m[3:, 3:] = r
    m[3:, :3] = skew(g[:3, 3]) @ r
    return m


@njit(cache=True)
def Ad_inv(g):
    """Inverse adjoint ``Ad(g)^-1 = Ad(g^-1) = [[R^T, 0], [-R^T p~, R^T]]``."""
    m = np.zeros((6, 6))
    rt = g[:3, :3].T.copy()
    m[:3, :3] = rt
    m[3:, 3:] = rt
    m[3:, :3] = -rt @ skew(g[:3, 3])
    return m


def adjoint_pair(g) -> tuple[np.ndarray, np.ndarray]:
    """``(Ad(g), Ad(g)^-1)`` in plain numpy, the same products as :func:`Ad` and
    :func:`Ad_inv` (tested equal), for set-up code: a servo needs its mount's two adjoints
    once, and compiling the two kernels for that took 1.9 s of a cold start."""
    g = np.asarray(g, dtype=float)
    r = g[:3, :3].copy()
    rt = g[:3, :3].T.copy()
    x, y, z = g[:3, 3]
    p = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])  # skew(p)
    ad = np.zeros((6, 6))
    ad[:3, :3] = r
    ad[3:, 3:] = r
    ad[3:, :3] = p @ r
    ad_inv = np.zeros((6, 6))
    ad_inv[:3, :3] = rt
    ad_inv[3:, 3:] = rt
    ad_inv[3:, :3] = -rt @ p
    return ad, ad_inv


@njit(cache=True)
def inv_se3(g):
    """Inverse of a homogeneous transform."""
    out = np.eye(4)
    rt = g[:3, :3].T.copy()
    out[:3, :3] = rt
    out[:3, 3] = -rt @ g[:3, 3].copy()
    return out


# Taylor coefficients (in th^2) of a1..a4 of the tangent operator, of (1-cos th)/th^2 and of
# (th-sin th)/th^3, from sympy; truncation < 1e-16 relative for th < SMALL_ANGLE.
_A1 = (
    1 / 2,
    0.0,
    -1 / 720,
    1 / 20160,
    -1 / 1209600,
    1 / 119750400,
    -1 / 17435658240,
    1 / 3487131648000,
    -1 / 914624815104000,
    1 / 304112751022080000,
)
_A2 = (
    1 / 6,
    0.0,
    -1 / 5040,
    1 / 181440,
    -1 / 13305600,
    1 / 1556755200,
    -1 / 261534873600,
    1 / 59281238016000,
    -1 / 17377871486976000,
    1 / 6386367771463680000,
)
_A3 = (
    1 / 24,
    -1 / 360,
    1 / 13440,
    -1 / 907200,
    1 / 95800320,
    -1 / 14529715200,
    1 / 2988969984000,
    -1 / 800296713216000,
    1 / 270322445352960000,
    -1 / 112400072777760768000,
)
_A4 = (
    1 / 120,
    -1 / 2520,
    1 / 120960,
    -1 / 9979200,
    1 / 1245404160,
    -1 / 217945728000,
    1 / 50812489728000,
    -1 / 15205637551104000,
    1 / 5676771352412160000,
    -1 / 2585201673888497664000,
)
_C1 = (
    1 / 2,
    -1 / 24,
    1 / 720,
    -1 / 40320,
    1 / 3628800,
    -1 / 479001600,
    1 / 87178291200,
    -1 / 20922789888000,
    1 / 6402373705728000,
    -1 / 2432902008176640000,
)
_C2 = (
    1 / 6,
    -1 / 120,
    1 / 5040,
    -1 / 362880,
    1 / 39916800,
    -1 / 6227020800,
    1 / 1307674368000,
    -1 / 355687428096000,
    1 / 121645100408832000,
    -1 / 51090942171709440000,
)


@kernel
def _exp_coefficients(th):
    """Return ``(1-cos th)/th^2`` and ``(th-sin th)/th^3`` accurately for any ``th >= 0``."""
    if th < SMALL_ANGLE:
        t2 = th * th
        return _series(_C1, t2), _series(_C2, t2)
    return (1.0 - np.cos(th)) / (th * th), (th - np.sin(th)) / (th * th * th)


@njit(cache=True)
def so3_exp_and_left_jacobian(w):
    """``exp([w]x)`` and the left Jacobian ``J_l(w) = I + c1 [w]x + c2 [w]x^2`` of SO(3)
    (``exp([w + d]x) = exp([J_l d]x) exp([w]x)`` to first order), with the coefficients of
    :func:`_exp_coefficients` (``exp = I + (1 - c2 th^2) [w]x + c1 [w]x^2``)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    c1, c2 = _exp_coefficients(th)
    k = skew(w)
    k2 = k @ k
    rot = np.eye(3) + (1.0 - c2 * th * th) * k + c1 * k2
    jl = np.eye(3) + c1 * k + c2 * k2
    return rot, jl


def rotation_angle(r) -> float:
    """Angle (rad, in ``[0, pi]``) of the rotation ``R``: ``arccos((tr R - 1) / 2)``, the
    argument clipped to ``[-1, 1]``. For reporting errors (logs, summaries): near 0 and pi it
    keeps half the digits of :func:`so3_log`'s ``atan2`` form, which the kernels use."""
    return float(np.arccos(np.clip(0.5 * (np.trace(r) - 1.0), -1.0, 1.0)))


@njit(cache=True)
def so3_log(r):
    """Rotation vector ``w`` with ``exp(w~) = R`` (``|w| <= pi``): ``th/(2 sin th) vee(R - R^T)``,
    its first-order form near ``th = 0`` and, near ``th = pi`` (where that quotient loses its
    digits), the axis from the symmetric part with the sign of the antisymmetric one."""
    c = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    # atan2(sin, cos): arccos(c) would lose half the digits near 0 and near pi
    th = np.arctan2(0.5 * np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), c)
    if th < 1e-6:
        return 0.5 * v
    if np.pi - th < 1e-4:  # sym(R) - cos(th) I = (1 - cos th) a a^T; sign from vee(R - R^T)
        b = 0.5 * (r + r.T) - c * np.eye(3)
        k = 0
        for i in range(1, 3):
            if b[i, i] > b[k, k]:
                k = i
        a = b[:, k] / np.sqrt(b[k, k])
        a = a / np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        if a[0] * v[0] + a[1] * v[1] + a[2] * v[2] < 0.0:
            a = -a
        return th * a
    return th / (2.0 * np.sin(th)) * v


@njit(cache=True)
def expmap(xi):
    """Exponential ``exp(xi^)`` of a twist, as a 4x4 homogeneous transform."""
    th = np.sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    c1, c2 = _exp_coefficients(th)
    x = hat(xi)
    x2 = x @ x
    return np.eye(4) + x + c1 * x2 + c2 * (x2 @ x)


@kernel
def _series(coefs, t2):
    acc = 0.0
    for i in range(len(coefs) - 1, -1, -1):
        acc = acc * t2 + coefs[i]
    return acc


@kernel
def _dseries(coefs, t2):
    """``(d/dth f)/th`` for ``f = sum c_i th^(2i)``, i.e. ``sum 2 i c_i th^(2i-2)``."""
    acc = 0.0
    for i in range(len(coefs) - 1, 0, -1):
        acc = acc * t2 + 2.0 * i * coefs[i]
    return acc


@kernel
def tangent_coefficients_scalars(th):
    """Coefficients ``a1..a4`` of ``T(Omega)`` and ``b_i = a_i'(th)/th`` (for ``dT/dt``) as
    eight scalars ``(a1, a2, a3, a4, b1, b2, b3, b4)``: no allocation, for the kernels of the
    rod's recursion (:mod:`tdacm._jit`)."""
    if th < SMALL_ANGLE:
        t2 = th * th
        return (
            _series(_A1, t2), _series(_A2, t2), _series(_A3, t2), _series(_A4, t2),
            _dseries(_A1, t2), _dseries(_A2, t2), _dseries(_A3, t2), _dseries(_A4, t2),
        )  # fmt: skip
    s = np.sin(th)
    c = np.cos(th)
    t2 = th * th
    t3 = t2 * th
    t4 = t2 * t2
    a0 = (4.0 - 4.0 * c - th * s) / (2.0 * t2)
    a1 = (4.0 * th - 5.0 * s + th * c) / (2.0 * t3)
    a2 = (2.0 - 2.0 * c - th * s) / (2.0 * t4)
    a3 = (2.0 * th - 3.0 * s + th * c) / (2.0 * t4 * th)
    # derivatives a_i'(th) divided by th (derived by hand, checked against sympy in the tests)
    p = 5.0 * th * s - t2 * c - 8.0 + 8.0 * c
    r = -8.0 * th - 7.0 * th * c - t2 * s + 15.0 * s
    return (
        a0, a1, a2, a3,
        p / (2.0 * t4), r / (2.0 * t4 * th), p / (2.0 * t4 * t2), r / (2.0 * t4 * t3),
    )  # fmt: skip


@njit(cache=True)
def tangent_coefficients(th):
    """Coefficients ``a1..a4`` of ``T(Omega)`` and ``b_i = a_i'(th)/th`` (for ``dT/dt``) as
    two arrays (:func:`tangent_coefficients_scalars`)."""
    co = tangent_coefficients_scalars(th)
    a = np.empty(4)
    b = np.empty(4)
    for i in range(4):
        a[i] = co[i]
        b[i] = co[4 + i]
    return a, b


@njit(cache=True)
def tangent(omega):
    """Tangent operator ``T(Omega) = sum_k ad(Omega)^k / (k+1)!`` in closed form (6x6)."""
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    a, _ = tangent_coefficients(th)
    x = ad(omega)
    x2 = x @ x
    x3 = x2 @ x
    x4 = x3 @ x
    return np.eye(6) + a[0] * x + a[1] * x2 + a[2] * x3 + a[3] * x4


@njit(cache=True)
def tangent_and_rate(omega, omega_dot):
    """Return ``T(Omega)`` and its time derivative along ``Omega_dot``.

    ``dT = sum_i (b_i (w . w_dot)) ad^i + a_i d(ad^i)`` with ``d(ad^i)`` expanded by the product
    rule, where ``w`` is the angular part of ``Omega``.
    """
    th = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    a, b = tangent_coefficients(th)
    wwd = omega[0] * omega_dot[0] + omega[1] * omega_dot[1] + omega[2] * omega_dot[2]
    x = ad(omega)
    y = ad(omega_dot)
    x2 = x @ x
    x3 = x2 @ x
    x4 = x3 @ x
    d1 = y
    d2 = y @ x + x @ y
    d3 = d2 @ x + x2 @ y
    d4 = d3 @ x + x3 @ y
    t = np.eye(6) + a[0] * x + a[1] * x2 + a[2] * x3 + a[3] * x4
    dt = (
        b[0] * wwd * x
        + b[1] * wwd * x2
        + b[2] * wwd * x3
        + b[3] * wwd * x4
        + a[0] * d1
        + a[1] * d2
        + a[2] * d3
        + a[3] * d4
    )
    return t, dt


@njit(cache=True)
def wrench_skew(mu):
    """Skew 6x6 matrix ``S(mu)`` with ``coad(eta) mu = -S(mu) eta``.

    ``S(mu) = [[m~, f~], [f~, 0]]`` for ``mu = [m; f]``.  Writing the gyroscopic term of a rigid
    body (or a rod section) as ``-S(M eta) eta`` instead of ``coad(eta) M eta`` gives a Coriolis
    matrix with ``Mdot - 2C`` skew-symmetric, the property the adaptive controller's
    stability proof uses, while ``C qdot`` is unchanged.
    """
    m = np.zeros((6, 6))
    a = skew(mu[:3])
    f = skew(mu[3:])
    m[:3, :3] = a
    m[:3, 3:] = f
    m[3:, :3] = f
    return m
