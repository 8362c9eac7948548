"""The geometry of a scenario without the closed loop: system, scene, camera mounts.

The figures, the replay and the Rerun recording re-render a stored run from its
``scenario.toml``; they need only these pieces (not the runner), so they keep working when the
loop is restructured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sim.assemble import build_world
from ..vision.mounts import tip_camera_pose


@dataclass(frozen=True)
class ArmView:
    """One arm as the outputs draw it: its rod (index into the system), tip camera C_L and
    mount, and the scene its C_L sees (its own marker and box)."""

    index: int
    rod: int
    tip_mount: np.ndarray
    local_camera: object
    scene: object


@dataclass
class Geometry:
    scenario: object
    system: object
    scene: object
    target: object
    tip_mount: np.ndarray
    drone_mount: np.ndarray
    q_star: np.ndarray
    local_camera: object
    global_camera: object

    arms: tuple = ()  # ArmView per arm (one for a single-arm robot)

    def local_pose(self, q, arm: int = 0):
        a = self.arms[arm] if self.arms else None
        if a is None:
            return tip_camera_pose(self.system, q, self.tip_mount)
        return tip_camera_pose(self.system, q, a.tip_mount, a.rod)

    def servo_points(self, q, arm: int = 0) -> np.ndarray:
        """The true points of arm ``arm``'s target in its servo camera (C_V for a floating
        base, C_L for a fixed one), normalized (4, 2): what its servo sees without noise."""
        from .._linalg import solve
        from ..vision.virtual import virtual_pose

        a = self.arms[arm]
        g = self.local_pose(q, arm)
        if self.system.floating:
            g = virtual_pose(self.system.base_pose(q), g)
        r = solve(g, a.scene.target_pose)
        pc = self.target.feature_points @ r[:3, :3].T + r[:3, 3]
        return pc[:, :2] / pc[:, 2:3]

    def global_pose(self, q):
        return self.system.base_pose(q) @ self.drone_mount

    def desired_local_pixels(self, arm: int = 0) -> np.ndarray:
        """The target's four corners in arm ``arm``'s C_L at the desired configuration (4, 2)
        px: where the detected points go when the servo converges (the reference view)."""
        a = self.arms[arm]
        return a.local_camera.project_world(
            a.scene.target_points_world(), self.local_pose(self.q_star, arm)
        )


def geometry(scenario) -> Geometry:
    """The :class:`Geometry` of a :class:`~tdacm.sim.Scenario` (its ``[robot]`` section,
    through :func:`tdacm.sim.assemble.build_world`)."""
    w = build_world(scenario)
    r = w.robot
    if r.arms:
        arms = tuple(
            ArmView(k, a.rod, a.tip_mount, a.local_camera, w.arm(k).scene)
            for k, a in enumerate(r.arms)
        )
    else:
        arms = (ArmView(0, 0, r.tip_mount, r.local_camera, w.scene),)
    return Geometry(
        scenario, r.system, w.scene, w.target, r.tip_mount, r.drone_mount, w.q_star,
        r.local_camera, r.global_camera, arms,
    )  # fmt: skip
