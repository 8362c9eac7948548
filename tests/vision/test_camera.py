"""Pinhole camera: presets (paper Table II), projection round trips, FoV test, validation."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.vision import GLOBAL_CAMERA, LOCAL_CAMERA, PinholeCamera, world_to_camera


def test_presets_match_table_ii():
    assert LOCAL_CAMERA.resolution == (1024, 1024)
    assert GLOBAL_CAMERA.resolution == (500, 500)
    assert (LOCAL_CAMERA.fx, LOCAL_CAMERA.cx, LOCAL_CAMERA.cy) == (886.8, 512.0, 512.0)
    assert (GLOBAL_CAMERA.fx, GLOBAL_CAMERA.cx, GLOBAL_CAMERA.cy) == (350.5, 250.0, 250.0)
    assert (LOCAL_CAMERA.near, LOCAL_CAMERA.far) == (0.5, 10.0)
    assert (GLOBAL_CAMERA.near, GLOBAL_CAMERA.far) == (0.01, 20.0)
    np.testing.assert_allclose(LOCAL_CAMERA.fov_deg, (60.0, 60.0), atol=0.01)
    np.testing.assert_allclose(GLOBAL_CAMERA.fov_deg, (71.0, 71.0), atol=0.01)
    f = PinholeCamera.from_fov(1024, 1024, 60.0)
    assert f.fx == pytest.approx(886.8, abs=0.05)


@pytest.mark.parametrize("cam", [LOCAL_CAMERA, GLOBAL_CAMERA], ids=["C_L", "C_G"])
def test_projection_round_trip(cam):
    rng = np.random.default_rng(0)
    p = np.column_stack((rng.uniform(-1, 1, (50, 2)), rng.uniform(0.6, 9.0, 50)))
    uv = cam.project(p)
    xy = cam.normalize(uv)
    np.testing.assert_allclose(xy, p[:, :2] / p[:, 2:], atol=1e-12)
    np.testing.assert_allclose(cam.denormalize(xy), uv, atol=1e-9)
    rays = cam.ray(uv)
    np.testing.assert_allclose(rays * np.linalg.norm(p, axis=1)[:, None], p, atol=1e-9)
    # the principal point is the image of the optical axis
    np.testing.assert_allclose(cam.project([0.0, 0.0, 2.0])[0], [cam.cx, cam.cy])


def test_world_projection_round_trip():
    rng = np.random.default_rng(1)
    from scipy.spatial.transform import Rotation

    g = np.eye(4)
    g[:3, :3] = Rotation.random(random_state=3).as_matrix()
    g[:3, 3] = [0.3, -0.2, 2.0]
    pc = np.column_stack((rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(1, 3, 20)))
    pw = pc @ g[:3, :3].T + g[:3, 3]
    np.testing.assert_allclose(world_to_camera(pw, g), pc, atol=1e-12)
    np.testing.assert_allclose(
        LOCAL_CAMERA.project_world(pw, g), LOCAL_CAMERA.project(pc), atol=1e-9
    )


def test_distortion_round_trip():
    cam = PinholeCamera(640, 480, 500, 505, 320.5, 240.2, distortion=(-0.2, 0.05, 1e-3, -1e-3))
    rng = np.random.default_rng(2)
    xy = rng.uniform(-0.4, 0.4, (30, 2))
    uv = cam.denormalize(xy)
    assert not np.allclose(uv, xy * [500, 505] + [320.5, 240.2])
    np.testing.assert_allclose(cam.normalize(uv), xy, atol=1e-6)


def test_behind_camera_is_nan():
    uv = LOCAL_CAMERA.project([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert np.all(np.isnan(uv[0])) and np.all(np.isfinite(uv[1]))


def test_fov_with_margin():
    cam = LOCAL_CAMERA
    z = 2.0
    # a point exactly 10 px inside the left border
    x_in = (10 - 0.5 - cam.cx) / cam.fx * z
    p = np.array([[x_in, 0.0, z]])
    assert cam.in_fov(p, margin=10.0 - 1e-6)[0]
    assert not cam.in_fov(p, margin=10.0 + 1e-3)[0]
    # half the field of view is 30 degrees: 29 deg inside, 31 deg outside
    for deg, inside in ((29.0, True), (31.0, False)):
        q = [np.tan(np.radians(deg)) * z, 0.0, z]
        assert cam.in_fov(q)[0] == inside
    # clipping planes
    assert not cam.in_fov([0.0, 0.0, 0.4])[0]  # nearer than 0.5 m
    assert not cam.in_fov([0.0, 0.0, 10.5])[0]  # beyond 10 m
    assert not cam.in_fov([0.0, 0.0, -3.0])[0]  # behind
    assert cam.all_in_fov([[0.0, 0.0, 1.0], [0.1, 0.1, 2.0]])
    assert not cam.pixels_in_image([[np.nan, 3.0]])[0]


def test_scaled_camera_keeps_the_optics():
    half = LOCAL_CAMERA.scaled(0.5)
    assert half.resolution == (512, 512)
    np.testing.assert_allclose(half.fov_deg, LOCAL_CAMERA.fov_deg, atol=1e-9)
    p = np.array([[0.2, -0.1, 1.5]])
    # the same scene point lands on the same place of the (scaled) pixel grid
    uv_full = LOCAL_CAMERA.project(p)[0]
    uv_half = half.project(p)[0]
    np.testing.assert_allclose((uv_half + 0.5) * 2 - 0.5, uv_full, atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"fx": 0.0}, "fx"),
        ({"fy": -1.0}, "fy"),
        ({"cx": np.nan}, "cx"),
        ({"width": 0}, "width"),
        ({"near": 2.0, "far": 1.0}, "far"),
        ({"near": -0.1}, "near"),
        ({"distortion": (0.1, 0.2)}, "distortion"),
    ],
)
def test_invalid_intrinsics(kwargs, name):
    args = {"width": 100, "height": 100, "fx": 100.0, "fy": 100.0, "cx": 50.0, "cy": 50.0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        PinholeCamera(**args)


def test_invalid_points():
    with pytest.raises(ValueError, match="points_cam"):
        LOCAL_CAMERA.project(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="points_cam"):
        LOCAL_CAMERA.project([[0.0, np.nan, 1.0]])
    with pytest.raises(ValueError, match="camera_pose"):
        LOCAL_CAMERA.project_world([[0.0, 0.0, 1.0]], np.eye(3))


def test_checked_forms_match_the_validating_methods():
    """The per-period callers use the *_checked forms on arrays validated where they entered."""
    from tdacm.vision.camera import LOCAL_CAMERA as cam

    rng = np.random.default_rng(0)
    pc = np.column_stack((rng.uniform(-1, 1, (6, 2)), rng.uniform(-0.5, 3, 6)))
    assert np.array_equal(cam.project(pc), cam.project_checked(pc), equal_nan=True)
    uv = rng.uniform(-50, 1100, (6, 2))
    assert np.array_equal(cam.normalize(uv), cam.normalize_checked(uv))
    xy = cam.normalize(uv)
    assert np.array_equal(cam.denormalize(xy), cam.denormalize_checked(xy))
    assert np.array_equal(cam.pixels_in_image(uv, 3.0), cam.pixels_in_image_checked(uv, 3.0))
    with pytest.raises(ValueError, match="points_cam"):
        cam.project(np.full((2, 3), np.inf))
