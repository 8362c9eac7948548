"""The whole local-camera chain on rendered images, with the loop's blocks: render -> detect
-> perception (normalized points, PnP depths) -> C_V -> features -> twist, and a short
image-based closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.lie.se3 import expmap
from tdacm.loop.data import CameraMeasurement
from tdacm.loop.perception import Perception
from tdacm.vision import (
    DEFAULT_TIP_CAMERA_MOUNT,
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PAPER_MARKER,
    IBVSController,
    TargetDetector,
    advanced_features,
    camera_pose,
    feature_interaction_matrix,
    reference_from_pose,
    virtual_camera_points,
    virtual_camera_transform,
)


class _Chain:
    """Detector, perception block and IBVS law of the local camera (the loop's blocks, with a
    free camera in place of the robot)."""

    def __init__(self, scene, camera=LOCAL_CAMERA, gain=0.5):
        self.ref = scene.viewing_pose(1.5)
        xd, zd = reference_from_pose(PAPER_MARKER, scene.target_pose, self.ref)
        self.detector = TargetDetector(PAPER_MARKER)
        self.perception = Perception(camera, GLOBAL_CAMERA, PAPER_MARKER)
        self.ibvs = IBVSController(xd, zd, gain=gain, floor=0.0, mode="current")

    def view(self, image):
        return self.perception.local(CameraMeasurement(0.0, self.detector.detect(image)))


def test_step_matches_analytic_twist(planar_marker, marker_scene):
    chain = _Chain(marker_scene, gain=1.0)
    g = marker_scene.viewing_pose(2.0, 40.0)
    g[:3, 3] += [0.1, -0.05, 0.0]
    out = chain.view(planar_marker.render(LOCAL_CAMERA, g))
    assert out.found
    pc = (marker_scene.target_points_world() - g[:3, 3]) @ g[:3, :3]
    xy, z = pc[:, :2] / pc[:, 2:], pc[:, 2]
    np.testing.assert_allclose(out.points, xy, atol=2e-4)
    np.testing.assert_allclose(out.depths, z, rtol=2e-3)
    v_true = chain.ibvs.twist(xy, z)
    # p_phi and p_theta react weakly to rotations (J_img rows ~ marker size / depth), so
    # 0.2 px of corner error shows as ~1 % of the twist
    twist = chain.ibvs.twist(out.points, out.depths)
    np.testing.assert_allclose(twist, v_true, atol=0.02 * np.abs(v_true).max())
    assert not chain.view(np.zeros((1024, 1024, 3), np.uint8)).found


def test_step_with_virtual_camera(planar_marker, marker_scene, fake_system):
    """Tilted drone: the compensated features equal those of the level drone."""
    chain = _Chain(marker_scene)
    q = np.array([0.0, 0.0, 0.2, 0.05, -0.05, 3.0, 0.02, -0.01])
    feats = []
    for phi, theta in ((0.0, 0.0), (0.08, -0.05)):
        q[:2] = phi, theta
        g_b = fake_system.base_pose(q)
        g_cl = camera_pose(fake_system.tip_pose(q), DEFAULT_TIP_CAMERA_MOUNT)
        out = chain.view(planar_marker.render(LOCAL_CAMERA, g_cl))
        assert out.found
        gv = virtual_camera_transform(g_b, g_cl)
        xy = virtual_camera_points(out.points, gv, out.depths, "exact", return_depths=True)[0]
        feats.append(advanced_features(xy))
    np.testing.assert_allclose(feats[0], feats[1], atol=2e-4)


@pytest.mark.parametrize("renderer", ["planar_marker", "tiny_marker"])
def test_image_based_closed_loop(renderer, marker_scene, request):
    """A free camera servoed from rendered images converges to the reference view
    (yaw error beyond 90 degrees included). TinyRenderer runs at half resolution (same
    optics) to keep the test short."""
    r = request.getfixturevalue(renderer)
    camera = LOCAL_CAMERA if renderer == "planar_marker" else LOCAL_CAMERA.scaled(0.5)
    chain = _Chain(marker_scene, camera, gain=5.0)
    ref = chain.ref
    g = marker_scene.viewing_pose(1.9, 120.0)
    g[:3, 3] += [0.15, -0.1, 0.0]
    steps = 100 if renderer == "planar_marker" else 30
    e_init = None
    for _ in range(steps):
        out = chain.view(r.render(camera, g))
        assert out.found
        error = chain.ibvs.error(out.points)
        e_init = np.linalg.norm(error) if e_init is None else e_init
        g = g @ expmap(0.02 * chain.ibvs.twist(out.points, out.depths, error=error))
    e0 = np.linalg.norm(error)
    print(
        f"{renderer}: |e| = {e0:.2e} after {steps} frames, position error "
        f"{np.linalg.norm(g[:3, 3] - ref[:3, 3]) * 1000:.2f} mm"
    )
    if renderer == "planar_marker":
        assert np.linalg.norm(g[:3, 3] - ref[:3, 3]) < 0.005
        assert e0 < 2e-3
    else:  # 30 frames of exp(-0.1 k): the error shrinks by ~20
        assert e0 < 0.1 * e_init
    assert np.all(np.isfinite(feature_interaction_matrix(out.points, out.depths)))
