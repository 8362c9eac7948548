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

from .. import paper_values as PV
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


def camera_pose(frame_pose, mount) -> np.ndarray:
    """Inertial camera pose ``g_F @ g_C^F`` from the carrying frame's pose and the mount."""
    return C.transform("frame_pose", frame_pose) @ C.transform("mount", mount)
