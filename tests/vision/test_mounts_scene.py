"""Camera mounts and scene geometry."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.vision import (
    DEFAULT_DRONE_CAMERA_MOUNT,
    DEFAULT_TIP_CAMERA_MOUNT,
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PAPER_MARKER,
    PAPER_PATTERN,
    SceneConfig,
    camera_pose,
    drone_camera_mount,
    tip_camera_mount,
    world_to_camera,
)


def test_tip_camera_looks_along_the_backbone(fake_system):
    g = DEFAULT_TIP_CAMERA_MOUNT
    np.testing.assert_allclose(g[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # optical axis = tip x
    assert np.linalg.det(g[:3, :3]) == pytest.approx(1.0)
    # for the straight hanging rod the image is upright for the drone:
    # camera x = body right (-y_b), camera y = body backward (-x_b), z = down
    q = np.zeros(8)
    q[5] = 3.0
    r_c = (np.linalg.inv(fake_system.base_pose(q)) @ fake_system.tip_pose(q) @ g)[:3, :3]
    np.testing.assert_allclose(r_c, [[0, -1, 0], [-1, 0, 0], [0, 0, -1]], atol=1e-12)
    np.testing.assert_allclose(tip_camera_mount(fake_system.attachment), g, atol=1e-12)
    np.testing.assert_allclose(tip_camera_mount(offset=0.02)[:3, 3], [0.02, 0.0, 0.0])
    with pytest.raises(ValueError, match="attachment"):
        tip_camera_mount(np.eye(4))


def test_paper_final_pose_sees_target_centred(fake_system):
    """q = [0,0,0, 0,0,3, 0,0]: the target is centred and upright in C_L, ~1.5 m away."""
    scene = SceneConfig()
    q = np.zeros(8)
    q[5] = 3.0
    g_cl = camera_pose(fake_system.tip_pose(q), DEFAULT_TIP_CAMERA_MOUNT)
    pc = world_to_camera(scene.target_points_world(), g_cl)
    assert pc[:, 2].mean() == pytest.approx(1.495, abs=1e-9)
    uv = LOCAL_CAMERA.project(pc)
    np.testing.assert_allclose(uv.mean(axis=0), [LOCAL_CAMERA.cx, LOCAL_CAMERA.cy], atol=1e-9)
    # paper order: TL, BL, BR, TR -> x grows from 1 to 4, y grows from 1 to 2
    assert uv[0, 0] < uv[3, 0] and uv[0, 1] < uv[1, 1] and uv[2, 0] > uv[1, 0]
    np.testing.assert_allclose(scene.viewing_pose(1.495), g_cl, atol=1e-12)


def test_global_camera_sees_arm_and_ground(fake_system):
    g = DEFAULT_DRONE_CAMERA_MOUNT
    assert g[:3, 2] @ [0.0, 0.0, -1.0] == pytest.approx(np.cos(np.radians(10.0)))
    assert g[:3, 2][0] > 0  # tilted forward
    q = np.zeros(8)
    q[5] = 3.0
    g_cg = camera_pose(fake_system.base_pose(q), g)
    s = np.linspace(0.0, 1.0, 41)
    rod = np.array([fake_system.pose(q, si)[:3, 3] for si in s])
    visible = GLOBAL_CAMERA.in_fov(world_to_camera(rod, g_cg))
    assert visible[s >= 0.25].all()  # the rod from 0.25 m below the attachment to the tip
    # and it sees the target on the box below
    scene = SceneConfig()
    assert GLOBAL_CAMERA.all_in_fov(world_to_camera(scene.target_points_world(), g_cg))
    np.testing.assert_allclose(drone_camera_mount(tilt_deg=0.0)[:3, 2], [0, 0, -1], atol=1e-12)


def test_scene_validation():
    with pytest.raises(ValueError, match="box_size"):
        SceneConfig(box_size=0.0)
    with pytest.raises(ValueError, match="target"):
        SceneConfig(target="marker")
    with pytest.raises(ValueError, match="box_rgba"):
        SceneConfig(box_rgba=(2, 0, 0, 1))
    with pytest.raises(ValueError, match="fit"):
        SceneConfig(box_size=0.1)


def test_target_geometry():
    f = PAPER_MARKER.feature_points
    np.testing.assert_allclose(f, [[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0]])
    assert PAPER_MARKER.ids == (65,)
    c = PAPER_PATTERN.feature_points
    np.testing.assert_allclose(
        c, [[-0.09, -0.06, 0], [-0.09, 0.06, 0], [0.09, 0.06, 0], [0.09, -0.06, 0]], atol=1e-12
    )
    for i in PAPER_PATTERN.ids:
        side = np.linalg.norm(np.diff(PAPER_PATTERN.corner_points(i), axis=0), axis=1)
        np.testing.assert_allclose(side, 0.03, atol=1e-12)


@pytest.mark.parametrize("target", [PAPER_MARKER, PAPER_PATTERN], ids=["marker", "pattern"])
def test_texture_matches_corner_points(target):
    """The black squares of the texture sit exactly where ``corner_points`` says."""
    tex = target.texture()
    w, h = target.board_size
    ppm = tex.shape[1] / w
    assert tex.shape[0] / h == pytest.approx(ppm)
    for i in target.ids:
        c = target.corner_points(i)
        col0, row0 = (c[0, :2] + [w / 2, h / 2]) * ppm
        col1, row1 = (c[2, :2] + [w / 2, h / 2]) * ppm
        assert col0 == pytest.approx(round(col0), abs=1e-9)
        r0, r1, c0, c1 = round(row0), round(row1), round(col0), round(col1)
        # the border cells are black, the pixels just outside are white
        assert tex[r0, c0:c1].max() == 0 and tex[r1 - 1, c0:c1].max() == 0
        assert tex[r0:r1, c0].max() == 0 and tex[r0:r1, c1 - 1].max() == 0
        assert tex[r0 - 1, c0:c1].min() == 255 and tex[r0:r1, c1].min() == 255


def test_target_validation():
    from tdacm.vision import AprilTagPattern, ArucoMarker

    with pytest.raises(ValueError, match="marker_id"):
        ArucoMarker(marker_id=65, dictionary=0)  # DICT_4X4_50 has ids 0..49
    with pytest.raises(ValueError, match="size"):
        ArucoMarker(size=-0.2)
    with pytest.raises(ValueError, match="ids"):
        AprilTagPattern(ids=(1, 1, 2, 3))
    with pytest.raises(ValueError, match=r"ids must lie in \[0, 50\)"):
        AprilTagPattern(ids=(0, 1, 2, 60), dictionary=0)  # DICT_4X4_50 has ids 0..49
    import cv2

    m = ArucoMarker(marker_id=65, dictionary=cv2.aruco.DICT_APRILTAG_36h11)
    assert m.texture().shape[0] > 0
