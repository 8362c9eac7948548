"""ZYX Euler angles of the drone (paper, eqs. (1) and (4)).

``R_b = Rz(psi) Ry(theta) Rx(phi)``; the body angular velocity is ``w_b = T(Phi) Phi_dot`` with

    T = [[1, 0, -sin th], [0, cos phi, sin phi cos th], [0, -sin phi, cos phi cos th]].

``T`` is singular at ``theta = +-pi/2`` (gimbal lock); callers that invert it check
:func:`is_singular` first.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._jit import kernel

#: |cos(theta)| below this is treated as the Euler singularity.
SINGULAR_COS = 1e-6


@kernel
def rot_zyx_into(r, cf, sf, ct, st, cp, sp):
    """``Rz(psi) Ry(theta) Rx(phi)`` into ``r`` (3x3) from the sines and cosines of ``phi``
    (``cf, sf``), ``theta`` (``ct, st``) and ``psi`` (``cp, sp``)."""
    r[0, 0] = cp * ct
    r[0, 1] = cp * st * sf - sp * cf
    r[0, 2] = cp * st * cf + sp * sf
    r[1, 0] = sp * ct
    r[1, 1] = sp * st * sf + cp * cf
    r[1, 2] = sp * st * cf - cp * sf
    r[2, 0] = -st
    r[2, 1] = ct * sf
    r[2, 2] = ct * cf


@kernel
def euler_rates_into(t, td, cf, sf, ct, st, phi_dot, theta_dot):
    """``T(phi, theta)`` of paper eq. (4) into ``t`` and its time derivative into ``td`` (3x3
    each) from the sines and cosines of ``phi`` (``cf, sf``) and ``theta`` (``ct, st``)."""
    for i in range(3):
        for k in range(3):
            t[i, k] = 0.0
            td[i, k] = 0.0
    t[0, 0] = 1.0
    t[0, 2] = -st
    t[1, 1] = cf
    t[1, 2] = sf * ct
    t[2, 1] = -sf
    t[2, 2] = cf * ct
    td[0, 2] = -ct * theta_dot
    td[1, 1] = -sf * phi_dot
    td[1, 2] = cf * ct * phi_dot - sf * st * theta_dot
    td[2, 1] = -cf * phi_dot
    td[2, 2] = -sf * ct * phi_dot - cf * st * theta_dot


@njit(cache=True)
def rot_zyx(phi, theta, psi):
    """``Rz(psi) Ry(theta) Rx(phi)``."""
    r = np.empty((3, 3))
    rot_zyx_into(
        r, np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    )
    return r


@njit(cache=True)
def euler_rate_matrix(phi, theta):
    """``T(phi, theta)`` of paper eq. (4): Euler rates -> body angular velocity."""
    t = np.empty((3, 3))
    td = np.empty((3, 3))
    euler_rates_into(t, td, np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), 0.0, 0.0)
    return t


@njit(cache=True)
def euler_rate_matrix_dot(phi, theta, phi_dot, theta_dot):
    """Time derivative of :func:`euler_rate_matrix`."""
    t = np.empty((3, 3))
    td = np.empty((3, 3))
    cf, sf, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    euler_rates_into(t, td, cf, sf, ct, st, phi_dot, theta_dot)
    return td


def is_singular(theta: float) -> bool:
    """True at the ZYX gimbal lock ``theta = +-pi/2`` (within :data:`SINGULAR_COS`)."""
    return abs(np.cos(theta)) < SINGULAR_COS


def euler_from_rotation(r: np.ndarray) -> np.ndarray:
    """``[phi, theta, psi]`` of a rotation matrix (ZYX), ``theta`` in ``[-pi/2, pi/2]``
    (:func:`euler_zyx`)."""
    return np.array(euler_zyx(np.ascontiguousarray(r, dtype=float)))


@njit(cache=True)
def euler_zyx(r):
    """``(phi, theta, psi)`` of a rotation matrix ``r`` (ZYX), ``theta`` in
    ``[-pi/2, pi/2]``."""
    theta = -np.arcsin(min(max(r[2, 0], -1.0), 1.0))
    phi = np.arctan2(r[2, 1], r[2, 2])
    psi = np.arctan2(r[1, 0], r[0, 0])
    return phi, theta, psi
