"""Render what the two cameras see and run one local-camera servo step.

Uses the coupled model (``tdacm.paper_system()``) for the TD-ACM's poses: the vision layer
only receives poses (model -> sensors -> controllers). Writes PNG images to ``out/``.

    python examples/vision_snapshots.py [--backend tiny|egl] [--out out]
"""

from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

import tdacm
from tdacm.loop.data import CameraMeasurement
from tdacm.loop.perception import Perception
from tdacm.vision import (
    DEFAULT_DRONE_CAMERA_MOUNT,
    DEFAULT_TIP_CAMERA_MOUNT,
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    IBVSController,
    PyBulletRenderer,
    SceneConfig,
    TargetDetector,
    advanced_features,
    camera_pose,
    reference_from_pose,
    virtual_camera_points,
    virtual_camera_transform,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="tiny", choices=["tiny", "egl"])
    ap.add_argument("--out", default="out")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)

    system = tdacm.paper_system()
    scene = SceneConfig()
    q_final = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0])  # paper: hover at 3 m
    q_now = np.array([0.04, -0.03, np.radians(20.0), -0.2, 0.15, 3.4, 0.1, -0.08])

    # reference snapshot: the target centred in C_L at the final configuration
    g_ref = camera_pose(system.tip_pose(q_final), DEFAULT_TIP_CAMERA_MOUNT)
    xd, zd = reference_from_pose(scene.target, scene.target_pose, g_ref)
    ibvs = IBVSController(xd, zd, gain=0.5, floor=0.0)

    with PyBulletRenderer(scene, backend=args.backend) as renderer:
        for name, q in (("final", q_final), ("current", q_now)):
            g_b = system.base_pose(q)
            renderer.set_arm(g_b, system.backbone(q, 41))
            g_cl = camera_pose(system.tip_pose(q), DEFAULT_TIP_CAMERA_MOUNT)
            g_cg = camera_pose(g_b, DEFAULT_DRONE_CAMERA_MOUNT)
            img_l = renderer.render(LOCAL_CAMERA, g_cl)
            img_g = renderer.render(GLOBAL_CAMERA, g_cg)
            cv2.imwrite(os.path.join(args.out, f"vision_{name}_CL.png"), img_l[:, :, ::-1])
            cv2.imwrite(os.path.join(args.out, f"vision_{name}_CG.png"), img_g[:, :, ::-1])
            # as the closed loop: normalized points and PnP depths of C_L, then C_V (eq. (18))
            view = Perception(LOCAL_CAMERA, GLOBAL_CAMERA, scene.target).local(
                CameraMeasurement(0.0, TargetDetector(scene.target).detect(img_l))
            )
            if view.found:
                gv = virtual_camera_transform(g_b, g_cl)
                xy, z = virtual_camera_points(view.points, gv, view.depths, "exact", True)
                error = ibvs.error(xy)
                print(f"{name}: features {np.round(advanced_features(xy), 4)}")
                print(f"{name}: error    {np.round(error, 4)}")
                print(f"{name}: C_V twist [w; v] {np.round(ibvs.twist(xy, z, error=error), 4)}")
            else:
                print(f"{name}: target not detected in C_L")
    print(f"images written to {args.out}/")


if __name__ == "__main__":
    main()
