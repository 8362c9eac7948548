"""Detection of both targets on rendered images (distances, tilts, noise, blur), the
"not detected" result, real-camera-like inputs and validation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tdacm.vision import (
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    NOT_DETECTED,
    PAPER_MARKER,
    PAPER_PATTERN,
    TargetDetector,
    detect_target,
)
from tdacm.vision.detect import tag_center, to_gray

from .vision_helpers import tilted_view

MARKER_VIEWS = [  # (camera, distance, yaw, tilt_x, tilt_y)
    (LOCAL_CAMERA, 1.0, 0.0, 0.0, 0.0),
    (LOCAL_CAMERA, 1.5, 100.0, 15.0, -10.0),
    (LOCAL_CAMERA, 2.5, -150.0, -20.0, 5.0),
    (LOCAL_CAMERA, 3.5, 45.0, 10.0, 25.0),
    (GLOBAL_CAMERA, 1.0, 170.0, 20.0, 0.0),
    (GLOBAL_CAMERA, 2.5, -80.0, 0.0, -25.0),
    (GLOBAL_CAMERA, 4.5, 10.0, 10.0, 10.0),
]

PATTERN_VIEWS = [  # the 3 cm tags need a closer camera
    (LOCAL_CAMERA, 0.6, 0.0, 0.0, 0.0),
    (LOCAL_CAMERA, 0.8, 120.0, 15.0, -10.0),
    (LOCAL_CAMERA, 1.2, -60.0, -20.0, 10.0),
    (GLOBAL_CAMERA, 0.4, -170.0, 10.0, 15.0),
    (GLOBAL_CAMERA, 0.6, 30.0, -15.0, 0.0),
]


def _check(det, img, camera, scene, g, tol):
    d = det.detect(img)
    assert d.found and d.points.shape == (4, 2)
    expected = camera.project_world(scene.target_points_world(), g)
    err = np.linalg.norm(d.points - expected, axis=1)
    assert err.max() < tol, err
    return d


@pytest.mark.parametrize("view", MARKER_VIEWS)
def test_marker_detected_in_order(planar_marker, marker_scene, view):
    cam, dist, yaw, tx, ty = view
    g = tilted_view(marker_scene, dist, yaw, tx, ty)
    d = _check(
        TargetDetector(PAPER_MARKER), planar_marker.render(cam, g), cam, marker_scene, g, 1.5
    )
    assert d.ids == (65,)


@pytest.mark.parametrize("view", PATTERN_VIEWS)
def test_pattern_detected_in_order(planar_pattern, pattern_scene, view):
    cam, dist, yaw, tx, ty = view
    g = tilted_view(pattern_scene, dist, yaw, tx, ty)
    d = _check(
        TargetDetector(PAPER_PATTERN), planar_pattern.render(cam, g), cam, pattern_scene, g, 1.5
    )
    assert d.ids == (0, 1, 2, 3) and len(d.corners) == 4


def test_both_targets_on_pybullet_images(tiny_marker, tiny_pattern, marker_scene, pattern_scene):
    for r, scene, (cam, dist, yaw, tx, ty) in (
        (tiny_marker, marker_scene, (LOCAL_CAMERA, 2.0, 60.0, 10.0, -10.0)),
        (tiny_marker, marker_scene, (GLOBAL_CAMERA, 3.0, -135.0, -5.0, 15.0)),
        (tiny_pattern, pattern_scene, (LOCAL_CAMERA, 0.7, 150.0, 10.0, 10.0)),
        (tiny_pattern, pattern_scene, (GLOBAL_CAMERA, 0.5, -30.0, -10.0, 0.0)),
    ):
        g = tilted_view(scene, dist, yaw, tx, ty)
        _check(TargetDetector(scene.target), r.render(cam, g), cam, scene, g, 1.5)


def test_not_detected_on_empty_images(planar_marker):
    det = TargetDetector(PAPER_MARKER)
    for img in (np.zeros((480, 640), np.uint8), np.full((500, 500, 3), 200, np.uint8)):
        d = det.detect(img)
        assert not d and d.points is None and d == NOT_DETECTED
    # the scene without the target in view (camera looking at the horizon)
    g = np.eye(4)
    g[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # looking along world +x
    g[:3, 3] = [3.0, 0.0, 2.0]
    assert not det.detect(planar_marker.render(GLOBAL_CAMERA, g))


def test_wrong_marker_is_not_detected(marker_scene):
    from tdacm.vision import ArucoMarker, PlanarRenderer, SceneConfig

    other = SceneConfig(target=ArucoMarker(marker_id=7))
    img = PlanarRenderer(other).render(LOCAL_CAMERA, other.viewing_pose(1.5))
    d = detect_target(img, PAPER_MARKER)
    assert not d and d.ids == ()
    assert detect_target(img, other.target).found


def test_partial_pattern_is_not_detected(planar_pattern, pattern_scene):
    g = pattern_scene.viewing_pose(0.6)
    img = planar_pattern.render(LOCAL_CAMERA, g)
    uv = LOCAL_CAMERA.project_world(pattern_scene.target_points_world(), g)
    u, v = np.round(uv[2]).astype(int)
    img[v - 40 : v + 40, u - 40 : u + 40] = 255  # hide the bottom-right tag
    d = detect_target(img, PAPER_PATTERN)
    assert not d and d.ids == (0, 1, 3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_survives_noise_and_blur(planar_marker, planar_pattern, marker_scene, pattern_scene, seed):
    """Gaussian blur (sigma 1 px, defocus), sensor noise (sigma 8 grey levels), JPEG
    compression (quality 80) and a brightness change: still found, corners within 1 px."""
    rng = np.random.default_rng(seed)
    for r, scene, cam, dist in (
        (planar_marker, marker_scene, LOCAL_CAMERA, 2.0),
        (planar_marker, marker_scene, GLOBAL_CAMERA, 2.5),
        (planar_pattern, pattern_scene, LOCAL_CAMERA, 0.7),
    ):
        g = tilted_view(scene, dist, rng.uniform(-180, 180), *rng.uniform(-15, 15, 2))
        img = r.render(cam, g).astype(float)
        img = cv2.GaussianBlur(img, (0, 0), 1.0)
        img = 0.8 * img + 10 + rng.normal(0, 8, img.shape)
        img = np.clip(img, 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        _check(TargetDetector(scene.target), img, cam, scene, g, 1.0)


def test_edge_refinement_beats_cornersubpix(planar_marker, marker_scene):
    """On blurred images of a small marker, the edge refinement is markedly better."""
    rng = np.random.default_rng(5)
    errs = {"edges": [], "subpix": []}
    for _ in range(4):
        g = tilted_view(marker_scene, 2.5, rng.uniform(-180, 180), *rng.uniform(-15, 15, 2))
        img = cv2.GaussianBlur(planar_marker.render(GLOBAL_CAMERA, g), (0, 0), 1.0)
        ref = GLOBAL_CAMERA.project_world(marker_scene.target_points_world(), g)
        for mode in errs:
            d = TargetDetector(PAPER_MARKER, refine=mode).detect(img)
            errs[mode].append(d.points - ref)
    rms = {k: np.sqrt(np.mean(np.sum(np.concatenate(v) ** 2, axis=1))) for k, v in errs.items()}
    assert rms["edges"] < 0.5 * rms["subpix"], rms


def test_real_camera_style_inputs(planar_marker, marker_scene):
    """The same code accepts BGR/RGB/RGBA/gray, uint16 and float images of any size."""
    g = marker_scene.viewing_pose(1.5, 30.0)
    rgb = planar_marker.render(LOCAL_CAMERA, g)
    ref = detect_target(rgb, PAPER_MARKER).points
    variants = [
        rgb[:, :, ::-1],  # BGR as from cv2.imread
        cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY),
        cv2.cvtColor(rgb, cv2.COLOR_RGB2RGBA),
        cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[:, :, None],
        rgb.astype(np.uint16) * 257,
        rgb.astype(np.float32) / 255.0,
    ]
    for img in variants:
        d = detect_target(img, PAPER_MARKER)
        assert d.found
        np.testing.assert_allclose(d.points, ref, atol=0.05)
    # a crop with an odd size (e.g. a 1280 x 720 sensor region)
    crop = rgb[100:821, 50:1013]
    d = detect_target(crop, PAPER_MARKER)
    np.testing.assert_allclose(d.points, ref - [50, 100], atol=0.05)


def test_tracking_gives_the_same_points(planar_marker, marker_scene):
    tracked = TargetDetector(PAPER_MARKER, track=True)
    plain = TargetDetector(PAPER_MARKER)
    for k in range(5):
        g = tilted_view(marker_scene, 1.5 + 0.02 * k, 10.0 * k, k, -k)
        img = planar_marker.render(LOCAL_CAMERA, g)
        a, b = tracked.detect(img), plain.detect(img)
        assert a.found and b.found
        np.testing.assert_allclose(a.points, b.points, atol=0.05)
    assert tracked._last_box is not None
    assert not tracked.detect(np.zeros((1024, 1024), np.uint8))
    assert tracked._last_box is None


def test_tag_center_is_projective():
    # the diagonals' intersection, not the corner mean, is the image of the centre
    c = np.array([[0.0, 0.0], [10.0, 1.0], [12.0, 12.0], [-1.0, 8.0]])
    x = tag_center(c)
    for a, b in ((0, 2), (1, 3)):
        d = c[b] - c[a]
        assert abs(d[0] * (x - c[a])[1] - d[1] * (x - c[a])[0]) < 1e-9


def test_detection_validation():
    with pytest.raises(ValueError, match="image"):
        to_gray(np.zeros((10, 10, 2), np.uint8))
    with pytest.raises(ValueError, match="image"):
        to_gray(np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="image"):
        to_gray(np.full((20, 20), np.nan))
    with pytest.raises(ValueError, match="target"):
        TargetDetector("marker")
    with pytest.raises(ValueError, match="different target"):
        detect_target(np.zeros((20, 20), np.uint8), PAPER_PATTERN, TargetDetector(PAPER_MARKER))
