"""Virtual camera C_V: removes the drone's roll and pitch from the tip camera's image.

Paper, section "UAV Roll and Pitch Compensation in Image Space":

    g_{C_L} = g_b g_a^b g_L^a g_{C_L}^L,      g_{C_V} = g_psi g_a^b g_L^a g_{C_L}^L,
    g_{C_L}^{C_V} = g_{C_V}^-1 g_{C_L},

where ``g_psi`` is the drone pose with ``(phi, theta)`` set to 0 (same position and yaw).
Writing ``g_{C_L}^b = g_a^b g_L^a g_{C_L}^L = [R_c, t_c]`` and
``R' = R_psi^T R_b = Ry(theta) Rx(phi)``:

    g_{C_L}^{C_V} = [[R_c^T R' R_c,  R_c^T (R' - I) t_c], [0, 1]].

The paper states that the translation cancels. That holds only when the camera sits at the
drone's centre of mass (``t_c = 0``); with the camera at the tip of a 1 m rod the virtual
camera is displaced by ``|(R' - I) t_c| ~ 2 sin(tilt/2) * 1 m`` (1.7 cm per degree of tilt).
Three mappings of normalized points ``p^{C_L} -> p^{C_V}`` are therefore provided
(:func:`virtual_camera_points`):

* ``"exact"``: the full rigid transform with the points' depths,
  ``r^{C_V} = R z p^{C_L} + t``, ``p^{C_V} = r^{C_V} / z^{C_V}``. Invariant to any
  roll/pitch of the drone (tested); needs the depths (e.g. from
  :func:`~.features.estimate_depths`).
* ``"rotation"``: the paper's projective formula ``p^{C_V} = (z^{C_L}/z^{C_V}) R p^{C_L}``
  with ``z^{C_V}/z^{C_L} = e3^T R p^{C_L}`` (the rotation-only homography; depth-free, exact
  when ``t`` is negligible against the depth).
* ``"approx"``: the paper's small-displacement approximation ``p^{C_V} ~ R p^{C_L}`` (first
  two components), from Kim et al. 2016.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..lie.se3 import inv_se3
from . import _checks as C
from .mounts import inv4, mul4

METHODS = ("exact", "rotation", "approx")
#: the codes of :data:`METHODS` in the compiled steps
EXACT, ROTATION, APPROX = range(3)


def _rz(psi: float) -> np.ndarray:
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_only_pose(base_pose) -> np.ndarray:
    """``g_psi``: the drone pose with roll and pitch removed (ZYX Euler, same yaw and
    position)."""
    return _yaw_only_pose(C.transform("base_pose", base_pose))


def _yaw_only_pose(g: np.ndarray) -> np.ndarray:
    r = g[:3, :3]
    psi = np.arctan2(r[1, 0], r[0, 0])
    out = np.eye(4)
    out[:3, :3] = _rz(psi)
    out[:3, 3] = g[:3, 3]
    return out


def virtual_camera_pose(base_pose, camera_pose) -> np.ndarray:
    """``g_{C_V} = g_psi g_{C_L}^b`` (inertial), from the inertial drone pose ``g_b`` and
    the inertial pose of the real camera ``g_{C_L}``."""
    return virtual_pose(
        C.transform("base_pose", base_pose), C.transform("camera_pose", camera_pose)
    )


def virtual_pose(g_b: np.ndarray, g_c: np.ndarray) -> np.ndarray:
    """:func:`virtual_camera_pose` of transforms already known to be rigid (no checks)."""
    return _yaw_only_pose(g_b) @ inv_se3(g_b) @ g_c


def virtual_camera_transform(base_pose, camera_pose) -> np.ndarray:
    """``g_{C_L}^{C_V} = g_{C_V}^-1 g_{C_L}`` (4x4; pose of the real camera in the virtual
    camera's frame). Its rotation is ``R_{C_L}^{C_V}``; its translation is zero only for a
    camera at the drone's centre of mass (see module docstring)."""
    return virtual_transform(
        C.transform("base_pose", base_pose), C.transform("camera_pose", camera_pose)
    )


def virtual_transform(g_b: np.ndarray, g_c: np.ndarray) -> np.ndarray:
    """:func:`virtual_camera_transform` of transforms already known to be rigid (the model's
    poses; no checks)."""
    return inv_se3(virtual_pose(g_b, g_c)) @ g_c


@njit(cache=True)
def virtual_transform_into(g_b, g_c, out):
    """``g_{C_L}^{C_V} = g_{C_V}^-1 g_{C_L}`` with ``g_{C_V} = g_psi g_b^-1 g_{C_L}`` (eq. (18),
    :func:`virtual_transform`) into ``out``: the compiled steps' form."""
    psi = np.arctan2(g_b[1, 0], g_b[0, 0])
    c, s = np.cos(psi), np.sin(psi)
    gy = np.eye(4)
    gy[0, 0], gy[0, 1], gy[1, 0], gy[1, 1] = c, -s, s, c
    for i in range(3):
        gy[i, 3] = g_b[i, 3]
    ib = np.empty((4, 4))
    inv4(g_b, ib)
    a = np.empty((4, 4))
    mul4(gy, ib, a)
    v = np.empty((4, 4))
    mul4(a, g_c, v)
    iv = np.empty((4, 4))
    inv4(v, iv)
    mul4(iv, g_c, out)


@njit(cache=True)
def virtual_points_into(p, z, g, method, out_p, out_z):
    """Points ``p`` (N, 2) with depths ``z`` of C_L in C_V (eq. (18), the module docstring's
    forms by :data:`EXACT`, :data:`ROTATION`, :data:`APPROX`): ``out_z`` the depths in C_V for
    ``EXACT``, the ratio ``z^{C_V} / z^{C_L}`` for ``ROTATION`` (ones for ``APPROX``). False
    when a point maps behind the virtual camera."""
    for k in range(p.shape[0]):
        x, y = p[k, 0], p[k, 1]
        if method == EXACT:
            zk = z[k]
            r0 = (x * zk) * g[0, 0] + (y * zk) * g[0, 1] + zk * g[0, 2] + g[0, 3]
            r1 = (x * zk) * g[1, 0] + (y * zk) * g[1, 1] + zk * g[1, 2] + g[1, 3]
            r2 = (x * zk) * g[2, 0] + (y * zk) * g[2, 1] + zk * g[2, 2] + g[2, 3]
        else:
            r0 = x * g[0, 0] + y * g[0, 1] + g[0, 2]
            r1 = x * g[1, 0] + y * g[1, 1] + g[1, 2]
            r2 = x * g[2, 0] + y * g[2, 1] + g[2, 2]
        if method == APPROX:
            out_p[k, 0], out_p[k, 1], out_z[k] = r0, r1, 1.0
            continue
        if not r2 > 0.0:
            return False
        out_p[k, 0], out_p[k, 1], out_z[k] = r0 / r2, r1 / r2, r2
    return True


def virtual_camera_points(
    points, transform, depths=None, method: str = "exact", return_depths: bool = False
):
    """Map normalized points ``(N, 2)`` of C_L to C_V.

    Parameters
    ----------
    points:
        Normalized coordinates in the real camera C_L.
    transform:
        ``g_{C_L}^{C_V}`` (4x4, from :func:`virtual_camera_transform`) or
        ``R_{C_L}^{C_V}`` (3x3; then the translation is taken as zero).
    depths:
        ``z^{C_L}`` of each point (``(N,)`` or scalar); required by ``"exact"``.
    method:
        ``"exact"``, ``"rotation"`` or ``"approx"`` (module docstring).
    return_depths:
        Also return ``z^{C_V}`` (``"exact"``) or the ratio ``z^{C_V}/z^{C_L}``
        (``"rotation"``, ``"approx"``: ones).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    p = C.points("points", points, 2)
    t = np.asarray(transform, dtype=float)
    if t.shape == (4, 4):
        g = C.transform("transform", t)
    else:
        g = np.eye(4)
        g[:3, :3] = C.rotation("transform", t)
    z = None
    if method == "exact":
        if depths is None:
            raise ValueError("depths are required by method='exact'")
        z = np.asarray(depths, dtype=float)
        z = np.full(p.shape[0], float(z)) if z.ndim == 0 else z
        z = C.array("depths", z, (p.shape[0],))
        if np.any(z <= 0.0):
            raise ValueError(f"depths must be positive, got {z!r}")
    return virtual_points(p, g, z, method, return_depths)


class BehindVirtualCamera(ValueError):
    """A point maps behind the virtual camera (the drone tilted so far that C_V cannot see
    what C_L sees): the closed loop ends the run with a named termination."""


def virtual_points(p, g, z, method: str = "exact", return_depths: bool = False):
    """:func:`virtual_camera_points` on checked inputs (``(N, 2)`` points, a rigid 4x4
    ``g_{C_L}^{C_V}``, positive depths for ``"exact"``; :func:`virtual_points_into`)."""
    n = p.shape[0]
    out, zv = np.empty((n, 2)), np.empty(n)
    zz = np.ones(n) if z is None else np.ascontiguousarray(z, dtype=float)
    code = METHODS.index(method)
    ok = virtual_points_into(
        np.ascontiguousarray(p, dtype=float), zz, np.ascontiguousarray(g, dtype=float), code,
        out, zv,
    )  # fmt: skip
    if not ok:
        raise BehindVirtualCamera("a point lies behind the virtual camera")
    return (out, zv) if return_depths else out
