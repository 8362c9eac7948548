"""Scene geometry shared by the renderers (a plain dataclass, no rendering here).

The paper's simulation has a ``cube_small`` box ("wall") carrying a 20 x 20 cm fiducial
marker; its drone starts at 5 m and ends at 3 m with the tip camera looking down. Here the
box stands on the ground (``cube_small`` is a 5 cm cube, scaled to ``box_size``) and the
target lies on its top face, facing up. With the defaults (0.4 m box at the origin, target
yaw 0) a drone hovering at ``[0, 0, 3]`` m with yaw 0 and a straight 1 m rod (attached 0.1 m
below the drone, so the tip is at 1.9 m) sees the target centred and upright in the tip
camera C_L, 1.5 m below it: the paper's final configuration ``q = [0, 0, 0, 0, 0, 3, 0, 0]``.

World frame: z up, gravity -z. The target frame (see :mod:`.targets`) has its z axis pointing
down (into the box) and, for ``target_yaw_deg = 0``, its x axis along world -y and its y axis
along world -x, so "up" on the printed marker points to world +x (the drone's forward
direction at yaw 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..lie.euler import rot_zyx
from . import _checks as C
from .mounts import R_DOWN_CAMERA_IN_BODY
from .targets import PAPER_MARKER, FiducialTarget

#: Edge of pybullet_data's ``cube_small.urdf`` (m).
CUBE_SMALL_SIZE = 0.05


@dataclass(frozen=True)
class SceneConfig:
    """Static scene: ground, a box (``cube_small`` scaled) and a target on its top face.

    Parameters
    ----------
    target:
        The fiducial target (default: the paper's ArUco marker ID 65, 20 cm).
    box_size:
        Edge of the cubic box in metres (``cube_small`` scaled by ``box_size / 0.05``).
    box_xy:
        Position of the box centre on the ground (m).
    target_yaw_deg:
        Rotation of the target about the world z axis (deg).
    target_tilt_deg:
        Tilt of the target board about the world x and y axes (deg), applied after the yaw:
        a board that does not lie exactly level (the servo's level prior is a belief, this
        is the truth; default level).
    target_lift:
        Height of the target above the box top (m): the board's thickness, which keeps the
        target from z-fighting with the box top in 16-bit depth buffers (EGL).
    ground_size:
        Edge of the square ground plane (m).
    ground_rgba, box_rgba:
        Colours (0..1).
    """

    target: FiducialTarget = field(default=PAPER_MARKER)
    box_size: float = 0.4
    box_xy: tuple = (0.0, 0.0)
    target_yaw_deg: float = 0.0
    target_tilt_deg: tuple = (0.0, 0.0)
    target_lift: float = 0.005
    ground_size: float = 30.0
    ground_rgba: tuple = (0.45, 0.47, 0.45, 1.0)
    box_rgba: tuple = (0.70, 0.62, 0.50, 1.0)

    def __post_init__(self):
        if not isinstance(self.target, FiducialTarget):
            raise ValueError(f"target must be a FiducialTarget, got {self.target!r}")
        C.positive("box_size", self.box_size)
        C.array("box_xy", self.box_xy, (2,))
        C.finite_scalar("target_yaw_deg", self.target_yaw_deg)
        tilt = C.array("target_tilt_deg", self.target_tilt_deg, (2,))
        if np.any(np.abs(tilt) > 30.0):
            raise ValueError(f"target_tilt_deg must lie within +-30 deg, got {tilt!r}")
        C.nonnegative("target_lift", self.target_lift)
        C.positive("ground_size", self.ground_size)
        for name in ("ground_rgba", "box_rgba"):
            c = C.array(name, getattr(self, name), (4,))
            if np.any(c < 0) or np.any(c > 1):
                raise ValueError(f"{name} must have entries in [0, 1], got {c!r}")
        w, h = self.target.board_size
        if max(w, h) > self.box_size * np.sqrt(2):
            raise ValueError("the target board does not fit on the box top; increase box_size")

    @property
    def box_pose(self) -> np.ndarray:
        """4x4 pose of the box centre (axis-aligned with the world)."""
        g = np.eye(4)
        g[:2, 3] = self.box_xy
        g[2, 3] = 0.5 * self.box_size
        return g

    @property
    def target_pose(self) -> np.ndarray:
        """4x4 pose of the target frame in the world (facing up, on the box top)."""
        a = np.radians(self.target_yaw_deg)
        rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
        g = np.eye(4)
        g[:3, :3] = rz @ R_DOWN_CAMERA_IN_BODY
        tx, ty = np.radians(np.asarray(self.target_tilt_deg, float))
        if tx or ty:  # about world x, then y (the board's centre stays put): Ry(ty) Rx(tx)
            g[:3, :3] = rot_zyx(tx, ty, 0.0) @ g[:3, :3]
        g[:2, 3] = self.box_xy
        g[2, 3] = self.box_size + self.target_lift
        return g

    def target_points_world(self) -> np.ndarray:
        """``(4, 3)`` feature points of the target in the world frame, paper order."""
        g = self.target_pose
        return self.target.feature_points @ g[:3, :3].T + g[:3, 3]

    def viewing_pose(self, distance: float, yaw_deg: float = 0.0) -> np.ndarray:
        """Camera pose (``T_wc``) looking straight down at the target centre from
        ``distance`` metres, image upright when ``yaw_deg == 0`` (rotated about the optical
        axis by ``yaw_deg`` otherwise). The reference snapshot of the paper."""
        d = C.positive("distance", distance)
        a = np.radians(C.finite_scalar("yaw_deg", yaw_deg))
        rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
        g = self.target_pose.copy()
        g[:3, :3] = g[:3, :3] @ rz
        g[:3, 3] = g[:3, 3] - d * g[:3, 2]
        return g


@dataclass(frozen=True)
class ArmStyle:
    """How the TD-ACM is drawn (only the drawing: the geometry comes in as poses).

    The drone is a ``+`` frame (arms along body x and y, ``span`` motor-to-motor, X650 class)
    with a central body box and four rotor discs; the rod is ``segments`` capsules of radius
    ``rod_radius`` (the real rod is 2 mm thick; it is drawn 1 cm thick so the 500 px global
    camera resolves it).
    """

    span: float = 0.65
    body_size: tuple = (0.18, 0.18, 0.06)
    rotor_disc_radius: float = 0.11
    rod_radius: float = 0.005
    segments: int = 20
    drone_rgba: tuple = (0.15, 0.15, 0.18, 1.0)
    rotor_rgba: tuple = (0.6, 0.6, 0.65, 1.0)
    rod_rgba: tuple = (0.85, 0.2, 0.1, 1.0)

    def __post_init__(self):
        C.positive("span", self.span)
        b = C.array("body_size", self.body_size, (3,))
        if np.any(b <= 0):
            raise ValueError(f"body_size must be positive, got {self.body_size!r}")
        C.positive("rotor_disc_radius", self.rotor_disc_radius)
        C.positive("rod_radius", self.rod_radius)
        C.positive_int("segments", self.segments)
