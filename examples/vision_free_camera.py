"""Image-based closed loop of a free-flying tip camera (no dynamics).

The camera starts 1.9 m above the paper's marker, yawed by 120 degrees and offset sideways,
renders what it sees, detects the marker, computes the advanced features and integrates the
IBVS twist ``[w; v]`` for one control period (20 ms) per frame. Prints the feature error
and the wall-clock time per step.

    python examples/vision_free_camera.py [--renderer planar|tiny] [--frames 150]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tdacm.lie.se3 import expmap
from tdacm.loop.data import CameraMeasurement
from tdacm.loop.perception import Perception
from tdacm.vision import (
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    IBVSController,
    PlanarRenderer,
    PyBulletRenderer,
    SceneConfig,
    TargetDetector,
    reference_from_pose,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renderer", default="planar", choices=["planar", "tiny", "egl"])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--gain", type=float, default=3.0)
    args = ap.parse_args()

    scene = SceneConfig()
    camera = LOCAL_CAMERA
    if args.renderer == "planar":
        renderer = PlanarRenderer(scene)
    else:
        renderer = PyBulletRenderer(scene, arm=None, backend=args.renderer)
    ref = scene.viewing_pose(1.5)
    xd, zd = reference_from_pose(scene.target, scene.target_pose, ref)
    # the closed loop's local-camera chain: detector, perception block, IBVS law
    detector = TargetDetector(scene.target)
    perception = Perception(camera, GLOBAL_CAMERA, scene.target)
    ibvs = IBVSController(xd, zd, gain=args.gain, floor=0.0)

    g = scene.viewing_pose(1.9, 120.0)
    g[:3, 3] += [0.15, -0.1, 0.0]
    times = []
    for k in range(args.frames):
        t0 = time.perf_counter()
        det = detector.detect(renderer.render(camera, g))
        view = perception.local(CameraMeasurement(0.02 * k, det))
        if view.found:
            error = ibvs.error(view.points)
            twist = ibvs.twist(view.points, view.depths, error=error)
        times.append(time.perf_counter() - t0)
        if not view.found:
            print(f"frame {k}: target lost")
            break
        g = g @ expmap(0.02 * twist)
        if k % 10 == 0:
            print(
                f"frame {k:4d}  |e| = {np.linalg.norm(error):.2e}  "
                f"yaw error {np.degrees(error[2]):7.2f} deg  "
                f"step {1000 * times[-1]:6.1f} ms"
            )
    print(
        f"final position error {1000 * np.linalg.norm(g[:3, 3] - ref[:3, 3]):.2f} mm, "
        f"median step {1000 * np.median(times):.1f} ms"
    )
    renderer.close()


if __name__ == "__main__":
    main()
