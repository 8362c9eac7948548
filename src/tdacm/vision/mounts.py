"""Camera mounting transforms ``g_{C_L}^L`` (tip camera) and ``g_{C_G}^b`` (drone camera).

Frames (the model's conventions): the drone body frame ``O_b`` is FLU (x forward, y left,
z up, thrust along +z); the rod's backbone is the local x axis of every cross-section frame
and the attachment ``g_a^b`` turns the rod's x axis to the body's -z, so the rod hangs down.
Cameras are x right, y down, z forward (optical axis).

Tip camera C_L (paper: "attached to the final disk at the CR tip")
    Optical axis along the tip frame's +x (it looks along the backbone, i.e. down for a
    hanging rod), centre ``offset`` metres beyond the tip along that axis. The roll about the
    optical axis is chosen so that for the straight rod the image is "north-up" for the drone:
    image right = body right (-y_b), image up = body forward (+x_b). This needs the attachment
    rotation; the default assumes ``R_a^b = Ry(+90 deg)`` (rod x -> body -z, rod y -> body y,
    rod z -> body x), for which ``R_{C_L}^L = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]``.
    Pass the system's ``attachment`` to :func:`tip_camera_mount` if it differs.

Drone camera C_G
    On the underside of the body, ``position`` (default 0.10 m forward, 0.06 m below the
    centre of mass), looking down and tilted ``tilt_deg`` (default 10 deg) forward about its
    own x axis; image right = body right, image up = forward. With Table II's 71 deg field of
    view this sees the hanging 1 m rod from about 0.25 m below the body to the tip (in the
    lower half of the image) and the ground below and ahead of the drone.

Naming: ``g_{C}^{F}`` is the pose of frame C expressed in frame F, so the camera's inertial
pose is ``g_F @ g_{C}^{F}``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import paper_values as PV
from ..lie.blocks import compose_rp_into, expmap_rp_into
from ..lie.euler import rot_zyx
from ..lie.magnus import magnus_step_into
from ..system.kernels import chain_start, make_workspace, rod_step
from . import _checks as C


def _rx(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


#: Camera looking straight down from an FLU body, image right = -y_b, image down = -x_b.
R_DOWN_CAMERA_IN_BODY = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: The attachment rotation the default tip mount assumes (rod x -> body -z).
DEFAULT_ATTACHMENT_ROTATION = _ry(np.pi / 2)


def tip_camera_mount(attachment=None, offset: float = PV.LOCAL_CAMERA_OFFSET) -> np.ndarray:
    """``g_{C_L}^L``: pose of the tip camera in the tip frame ``O_L`` (4x4).

    Parameters
    ----------
    attachment:
        ``g_a^b`` (4x4) or ``R_a^b`` (3x3) of the system; only its rotation is used, to fix
        the camera's roll about the optical axis (see module docstring). ``None`` uses
        :data:`DEFAULT_ATTACHMENT_ROTATION`. The attachment must map the rod's x axis to the
        body's -z axis (rod hanging down).
    offset:
        Distance of the optical centre beyond the tip along the backbone (m).
    """
    if attachment is None:
        r_ab = DEFAULT_ATTACHMENT_ROTATION
    else:
        a = np.asarray(attachment, dtype=float)
        r_ab = (
            C.transform("attachment", a)[:3, :3]
            if a.shape == (4, 4)
            else C.rotation("attachment", a)
        )
    if not np.allclose(r_ab[:, 0], [0.0, 0.0, -1.0], atol=1e-6):
        raise ValueError("attachment must map the rod's x axis to the body's -z axis")
    off = C.finite_scalar("offset", offset)
    g = np.eye(4)
    g[:3, :3] = r_ab.T @ R_DOWN_CAMERA_IN_BODY
    g[:3, 3] = [off, 0.0, 0.0]
    return g


def drone_camera_mount(
    position=PV.GLOBAL_CAMERA_POSITION, tilt_deg: float = PV.GLOBAL_CAMERA_TILT_DEG
) -> np.ndarray:
    """``g_{C_G}^b``: pose of the drone camera in the body frame (4x4).

    Looks straight down (image up = body forward) rotated by ``tilt_deg`` about the camera x
    axis, positive tilting the optical axis forward.
    """
    pos = C.array("position", position, (3,))
    tilt = np.radians(C.finite_scalar("tilt_deg", tilt_deg))
    g = np.eye(4)
    g[:3, :3] = R_DOWN_CAMERA_IN_BODY @ _rx(tilt)
    g[:3, 3] = pos
    return g


#: Default ``g_{C_L}^L`` (camera at the tip, looking along the backbone).
DEFAULT_TIP_CAMERA_MOUNT = tip_camera_mount()

#: Default ``g_{C_G}^b`` (0.10 m forward, 0.06 m below the CoM, 10 deg forward tilt).
DEFAULT_DRONE_CAMERA_MOUNT = drone_camera_mount()


def tip_camera_pose(system, q, mount, rod: int = 0) -> np.ndarray:
    """World pose of the tip camera, ``g_{C_L} = g_L(q) g_{C_L}^L`` (eq. (10)'s chain), from
    the system's tip pose at ``q`` (of rod ``rod`` for a system with several) and the mount.
    Unchecked (called several times a period): the caller checks the mount once."""
    return (system.tip_pose(q) if rod == 0 else system.tip_pose(q, rod)) @ mount


@njit(cache=True)
def camera_chain(q, m, rod, want_j, g_out, j_out):
    """The pose ``g_L(q)`` (4, 4) of the end of a camera's rod (its Magnus steps ``rod[0] <= k <
    rod[1]`` of the model arrays ``m``, from that rod's attachment) into ``g_out`` and, when ``want_j``, its Jacobian
    ``J_L^L(q)`` (6 x n) into ``j_out``: the recursion of
    :func:`~tdacm.system.kernels.chain_jacobian` at zero rates without what a camera does not
    read. The Jacobian comes from :func:`~tdacm.system.kernels.rod_step` without the
    Jacobian rate (its columns of ``T X`` are computed one by one, so ``J`` and ``g`` are the
    same numbers); the pose alone needs only each step's Magnus exponential and the product
    of the poses."""
    lo, hi = rod[0], rod[1]
    n = q.shape[0]
    zero = np.zeros(n)
    off = 6 if m.floating else 0
    att = 0  # the rod whose steps start at lo: its attachment
    for r in range(m.rod_steps.shape[0] - 1):
        if m.rod_steps[r] == lo:
            att = r
    _, _, _, g, j, jd, jdq = chain_start(q, zero, m.floating, m.g_fixed, m.g_att[att])
    ws = make_workspace(n, m.bs.shape[3])
    if want_j:
        eta = np.zeros(6)
        for k in range(lo, hi):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            rod_step(m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], zero[c0:c1], c0, g, j, jd, eta, jdq,
                     False, ws)  # fmt: skip
        j_out[:, :] = j
    else:
        omega, z, zdq, zd, mwork, r, p = ws[0], ws[1], ws[2], ws[3], ws[4], ws[5], ws[6]
        gr = ws[13]
        for k in range(lo, hi):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            magnus_step_into(m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], zero[c0:c1], omega, z, zdq,
                             zd, mwork)  # fmt: skip
            expmap_rp_into(omega, r, p)
            compose_rp_into(g, gr, r, p)
    g_out[:, :] = g


@njit(cache=True)
def mul4(a, b, out):
    """``out = a b`` of 4 x 4 matrices."""
    for i in range(4):
        for j in range(4):
            out[i, j] = (
                a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j] + a[i, 3] * b[3, j]
            )


@njit(cache=True)
def inv4(g, out):
    """``out = g^-1`` of a rigid 4 x 4 transform."""
    for i in range(3):
        for j in range(3):
            out[i, j] = g[j, i]
        out[3, i] = 0.0
    for i in range(3):
        out[i, 3] = -(out[i, 0] * g[0, 3] + out[i, 1] * g[1, 3] + out[i, 2] * g[2, 3])
    out[3, 3] = 1.0


@njit(cache=True)
def tip_camera_pose_into(q, m, rod, mount, out):
    """``g_{C_L} = g_L(q) g_{C_L}^L`` (:func:`tip_camera_pose`) into ``out`` (4, 4), from the
    rod's Magnus steps ``rod`` (:func:`camera_chain`)."""
    g = np.empty((4, 4))
    camera_chain(q, m, rod, bool(0), g, np.empty((0, 0)))  # a variable: one specialization
    mul4(g, mount, out)


@njit(cache=True)
def tip_jacobian_into(q, m, rod, out):
    """``J_L^L(q)`` (6 x n) of a camera's rod into ``out`` (:func:`camera_chain`)."""
    camera_chain(q, m, rod, bool(1), np.empty((4, 4)), out)  # a variable: one specialization


@njit(cache=True)
def base_pose_into(q, m, out):
    """The drone pose ``g_b`` (eq. (1)) into ``out``; the clamp for a fixed base."""
    if not m.floating:
        out[:, :] = m.g_fixed
        return
    r = rot_zyx(q[0], q[1], q[2])
    for i in range(3):
        for j in range(3):
            out[i, j] = r[i, j]
        out[i, 3] = q[3 + i]
        out[3, i] = 0.0
    out[3, 3] = 1.0


def rod_steps(system, rod: int = 0) -> np.ndarray:
    """``[first, end)`` of rod ``rod``'s Magnus steps in the system's model arrays (the
    ``rod`` argument of :func:`camera_chain`)."""
    m = system.model_arrays
    return np.array([m.rod_steps[rod], m.rod_steps[rod + 1]], np.int64)


def camera_pose(frame_pose, mount) -> np.ndarray:
    """Inertial camera pose ``g_F @ g_C^F`` from the carrying frame's pose and the mount."""
    return C.transform("frame_pose", frame_pose) @ C.transform("mount", mount)
