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

    def local_pose(self, q):
        return tip_camera_pose(self.system, q, self.tip_mount)

    def global_pose(self, q):
        return self.system.base_pose(q) @ self.drone_mount

    def desired_local_pixels(self) -> np.ndarray:
        """The target's four corners in C_L at the desired configuration (4, 2) px: where the
        detected points go when the servo converges (the reference view)."""
        return self.local_camera.project_world(
            self.scene.target_points_world(), self.local_pose(self.q_star)
        )


def geometry(scenario) -> Geometry:
    """The :class:`Geometry` of a :class:`~tdacm.sim.Scenario` (its ``[robot]`` section,
    through :func:`tdacm.sim.assemble.build_world`)."""
    w = build_world(scenario)
    r = w.robot
    return Geometry(
        scenario, r.system, w.scene, w.target, r.tip_mount, r.drone_mount, w.q_star,
        r.local_camera, r.global_camera,
    )  # fmt: skip
