"""Virtual camera C_V: roll/pitch compensation (paper, "UAV Roll and Pitch Compensation in
Image Space")."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.vision import (
    DEFAULT_TIP_CAMERA_MOUNT,
    PAPER_MARKER,
    SceneConfig,
    camera_pose,
    estimate_depths,
    virtual_camera_points,
    virtual_camera_pose,
    virtual_camera_transform,
    world_to_camera,
    yaw_only_pose,
)

SCENE = SceneConfig()
ATTITUDES = [(0.0, 0.0), (0.1, 0.0), (0.0, -0.12), (0.15, 0.1), (-0.2, 0.18), (0.05, -0.25)]


def _view(system, q):
    """Normalized points, depths, g_{C_L}^{C_V} and g_{C_V} for configuration q."""
    g_b = system.base_pose(q)
    g_cl = camera_pose(system.tip_pose(q), DEFAULT_TIP_CAMERA_MOUNT)
    pc = world_to_camera(SCENE.target_points_world(), g_cl)
    return (
        pc[:, :2] / pc[:, 2:],
        pc[:, 2],
        virtual_camera_transform(g_b, g_cl),
        virtual_camera_pose(g_b, g_cl),
    )


def test_exact_compensation_is_invariant_to_roll_and_pitch(fake_system):
    q0 = np.array([0.0, 0.0, 0.3, 0.1, -0.05, 3.0, 0.05, -0.03])
    reference = None
    for phi, theta in ATTITUDES:
        q = q0.copy()
        q[:2] = phi, theta
        xy, z, g_lv, g_v = _view(fake_system, q)
        assert np.all(z > 0.5)  # in front of the camera
        pv = virtual_camera_points(xy, g_lv, z, method="exact")
        # also with depths estimated from the image (planar PnP)
        pv_est = virtual_camera_points(xy, g_lv, estimate_depths(xy, PAPER_MARKER.feature_points))
        np.testing.assert_allclose(pv_est, pv, atol=1e-9)
        if reference is None:
            reference = pv
            g_v0 = g_v
        np.testing.assert_allclose(pv, reference, atol=1e-12)
        np.testing.assert_allclose(g_v, g_v0, atol=1e-12)  # C_V does not move
    # and it equals the view of the level drone
    xy0, _, _, _ = _view(fake_system, q0)
    np.testing.assert_allclose(reference, xy0, atol=1e-12)


def test_rotation_part_and_lever_arm(fake_system):
    """The paper's pure-rotation claim holds only for a camera at the CoM: here the tip
    camera is 1.1 m below it and C_V is displaced by |(R' - I) t_c|."""
    q = np.array([0.1, -0.05, 0.3, 0.0, 0.0, 3.0, 0.0, 0.0])
    _, _, g_lv, _ = _view(fake_system, q)
    np.testing.assert_allclose(g_lv[:3, :3] @ g_lv[:3, :3].T, np.eye(3), atol=1e-12)
    lever = np.linalg.norm(g_lv[:3, 3])
    tilt = np.arccos(np.cos(0.1) * np.cos(-0.05))
    assert lever == pytest.approx(2 * np.sin(tilt / 2) * 1.1, rel=1e-6)


def test_rotation_and_approx_methods_for_a_camera_at_the_com():
    """With the camera at the drone's CoM the translation vanishes: the paper's projective
    formula is exact and its small-displacement approximation is first-order accurate."""
    from tdacm.lie.euler import rot_zyx

    mount = np.eye(4)
    mount[:3, :3] = [[0, -1, 0], [-1, 0, 0], [0, 0, -1]]  # looking down from the CoM
    ref = None
    for phi, theta in ATTITUDES:
        g_b = np.eye(4)
        g_b[:3, :3] = rot_zyx(phi, theta, 0.4)
        g_b[:3, 3] = [0.05, -0.02, 2.0]
        g_cl = g_b @ mount
        g_lv = virtual_camera_transform(g_b, g_cl)
        np.testing.assert_allclose(g_lv[:3, 3], 0.0, atol=1e-12)
        pc = world_to_camera(SCENE.target_points_world(), g_cl)
        xy, z = pc[:, :2] / pc[:, 2:], pc[:, 2]
        exact = virtual_camera_points(xy, g_lv, z)
        rot = virtual_camera_points(xy, g_lv[:3, :3], method="rotation")
        approx = virtual_camera_points(xy, g_lv, method="approx")
        np.testing.assert_allclose(rot, exact, atol=1e-12)
        if ref is None:
            ref = exact
        np.testing.assert_allclose(exact, ref, atol=1e-12)
        angle = max(abs(phi), abs(theta))
        assert np.abs(approx - exact).max() <= 1.5 * angle * (angle + 0.2) + 1e-12


def test_yaw_only_pose():
    from tdacm.lie.euler import rot_zyx

    g = np.eye(4)
    g[:3, :3] = rot_zyx(0.2, -0.3, 2.5)
    g[:3, 3] = [1, 2, 3]
    gp = yaw_only_pose(g)
    np.testing.assert_allclose(gp[:3, :3], rot_zyx(0.0, 0.0, 2.5), atol=1e-12)
    np.testing.assert_allclose(gp[:3, 3], [1, 2, 3])


def test_validation():
    xy = np.zeros((4, 2))
    with pytest.raises(ValueError, match="method"):
        virtual_camera_points(xy, np.eye(4), 1.0, method="magic")
    with pytest.raises(ValueError, match="depths"):
        virtual_camera_points(xy, np.eye(4))
    with pytest.raises(ValueError, match="depths"):
        virtual_camera_points(xy, np.eye(4), [1, 1, 0, 1])
    with pytest.raises(ValueError, match="transform"):
        virtual_camera_points(xy, np.ones((3, 3)), method="approx")
    with pytest.raises(ValueError, match="base_pose"):
        virtual_camera_transform(np.eye(3), np.eye(4))
