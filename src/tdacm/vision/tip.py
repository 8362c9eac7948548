"""Tip-level mapping: camera twist -> tip twist -> desired joint rates.

Paper, end of "IBVS in Local Camera with Advanced Features":

    v_L^L = Ad(g_{C_V}^L) v_{C_V}^{C_V},       qdot_d = (J_L^L(q))^+ v_L^L.

Twists are angular-first ``[w; v]`` and ``Ad(g) = [[R, 0], [p~ R, R]]``
(:func:`tdacm.lie.se3.Ad`). For a camera rigidly mounted at ``g_{C}^{L}`` (pose of the camera
in the tip frame), the body twists satisfy ``v_L = Ad(g_C^L) v_C``; the virtual camera is
mounted on the virtual tip exactly as C_L on the real one, so ``g_{C_V}^L`` is the mount
``g_{C_L}^L``.

The pseudo-inverse is restricted to the coordinates that can be commanded: for a floating
system (``q = [phi, theta, psi, x, y, z, q_s...]``) roll and pitch are not inputs - the
translational loop sets them to move the drone sideways - so their columns are removed and
``qdot_d`` has zeros there. With the paper's two bending strains this leaves
``[psi, x, y, z, q_s1, q_s2]``: six coordinates for a six-dimensional twist.

The model is only used through its documented API: ``system.n``, ``system.floating`` and
``system.tip_jacobian(q)`` (6 x n, qdot -> tip twist ``[w; v]`` in the tip frame O_L).
"""

from __future__ import annotations

import numpy as np

from tdacm._linalg import SVD_PINV, svd_solve
from tdacm.lie.se3 import Ad

from . import _checks as C
from .mounts import DEFAULT_TIP_CAMERA_MOUNT

#: Coordinates of a floating system that are not commanded (drone roll and pitch).
UNCOMMANDED_FLOATING = (0, 1)

JACOBIAN_AT = ("actual", "virtual")


def camera_to_tip_twist(camera_twist, mount=DEFAULT_TIP_CAMERA_MOUNT) -> np.ndarray:
    """``v_L^L = Ad(g_C^L) v_C^C`` for a camera mounted at ``mount = g_C^L`` (angular-first
    twists)."""
    v = C.array("camera_twist", camera_twist, (6,))
    g = C.transform("mount", mount)
    return Ad(np.ascontiguousarray(g)) @ v


def commanded_coordinates(system) -> np.ndarray:
    """Indices of the generalized coordinates the servo commands: all but the drone's roll
    and pitch for a floating system, all for a fixed base."""
    n = C.positive_int("system.n", system.n)
    if getattr(system, "floating", False):
        return np.array([i for i in range(n) if i not in UNCOMMANDED_FLOATING])
    return np.arange(n)


def tip_joint_rates(
    system, q, tip_twist, commanded=None, jacobian_at: str = "actual", rcond: float = 1e-8
) -> np.ndarray:
    """``qdot_d = (J_L^L(q)[:, commanded])^+ v_L^L`` scattered into a full ``(n,)`` vector.

    Parameters
    ----------
    system:
        Object with ``n``, ``floating`` and ``tip_jacobian(q)`` (see module docstring).
    q:
        Generalized coordinates ``(n,)``.
    tip_twist:
        ``v_L^L`` (angular-first, tip frame).
    commanded:
        Indices of commanded coordinates (default :func:`commanded_coordinates`).
    jacobian_at:
        ``"actual"``: ``J_L^L(q)``, the paper's formula. ``"virtual"``: ``J_L^L`` at ``q``
        with roll and pitch set to zero - the exact Jacobian of the virtual camera chain
        ``g_psi g_a^b g_L^a(q_s)`` (identical to ``"actual"`` when the drone is level).
    rcond:
        Cut-off of the pseudo-inverse.
    """
    n = C.positive_int("system.n", system.n)
    qv = C.array("q", q, (n,))
    v = C.array("tip_twist", tip_twist, (6,))
    if jacobian_at not in JACOBIAN_AT:
        raise ValueError(f"jacobian_at must be one of {JACOBIAN_AT}, got {jacobian_at!r}")
    idx = commanded_coordinates(system) if commanded is None else np.asarray(commanded, int)
    if idx.ndim != 1 or idx.size == 0 or np.any(idx < 0) or np.any(idx >= n):
        raise ValueError(f"commanded must be indices in [0, {n}), got {commanded!r}")
    if jacobian_at == "virtual" and getattr(system, "floating", False):
        qv = qv.copy()
        qv[list(UNCOMMANDED_FLOATING)] = 0.0
    jac = np.asarray(system.tip_jacobian(qv), dtype=float)
    if jac.shape != (6, n):
        raise ValueError(f"system.tip_jacobian(q) must have shape (6, {n}), got {jac.shape}")
    return rates_from_jacobian(jac, v, idx, rcond)


def rates_from_jacobian(jac, tip_twist, commanded, rcond: float = 1e-8) -> np.ndarray:
    """``qdot_d[commanded] = (J[:, commanded])^+ v`` (zeros elsewhere), on checked inputs:
    the per-period core of :func:`tip_joint_rates` (:func:`~tdacm._linalg.svd_solve`)."""
    qdot = np.zeros(jac.shape[1])
    qdot[commanded] = svd_solve(
        np.ascontiguousarray(jac[:, commanded]), np.asarray(tip_twist, float), SVD_PINV,
        float(rcond),
    )  # fmt: skip
    return qdot


def camera_joint_rates(
    system, q, camera_twist, mount=DEFAULT_TIP_CAMERA_MOUNT, **kwargs
) -> np.ndarray:
    """:func:`tip_joint_rates` of the tip twist of ``camera_twist`` (see
    :func:`camera_to_tip_twist`)."""
    return tip_joint_rates(system, q, camera_to_tip_twist(camera_twist, mount), **kwargs)
