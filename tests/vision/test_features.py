"""Advanced features: agreement with the paper's equations, robustness beyond +-90 deg yaw,
analytic interaction matrix against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tdacm.lie.se3 import expmap
from tdacm.vision import (
    PAPER_MARKER,
    PAPER_PATTERN,
    advanced_features,
    depth_from_size,
    estimate_depths,
    feature_error,
    feature_interaction_matrix,
    features_jacobian,
    paper_features,
    point_interaction_matrix,
    wrap_angle,
)
from tdacm.vision.kinematic import project_points


def camera_in_target(distance, yaw=0.0, rx=0.0, ry=0.0, offset=(0.0, 0.0)):
    g = np.eye(4)
    g[:3, :3] = Rotation.from_euler("zyx", [yaw, ry, rx]).as_matrix()
    g[:3, 3] = g[:3, :3] @ [0.0, 0.0, -distance] + [*offset, 0.0]
    return g


def random_pose(rng):
    return camera_in_target(
        rng.uniform(0.7, 3.0),
        rng.uniform(-np.pi, np.pi),
        rng.uniform(-0.5, 0.5),
        rng.uniform(-0.5, 0.5),
        rng.uniform(-0.3, 0.3, 2),
    )


def test_head_on_view():
    xy, z = project_points(PAPER_MARKER.feature_points, camera_in_target(1.5))
    f = advanced_features(xy)
    np.testing.assert_allclose(f[:5], 0.0, atol=1e-15)
    assert f[5] == pytest.approx(4 * 0.2 / 1.5)
    assert depth_from_size(xy, PAPER_MARKER.feature_scale) == pytest.approx(1.5)


def test_equal_to_paper_equations_for_upright_targets():
    rng = np.random.default_rng(0)
    for _ in range(200):
        g = camera_in_target(
            rng.uniform(0.7, 3),
            rng.uniform(-1.2, 1.2),
            rng.uniform(-0.4, 0.4),
            rng.uniform(-0.4, 0.4),
        )
        for target in (PAPER_MARKER, PAPER_PATTERN):
            xy, _ = project_points(target.feature_points, g)
            np.testing.assert_allclose(advanced_features(xy), paper_features(xy), atol=1e-12)


def test_yaw_feature_beyond_90_degrees():
    """The yaw feature follows the target over the full circle; the paper's plain atan
    folds it into (-90, 90] degrees."""
    yaws = np.radians(np.arange(-179.0, 180.0, 1.0))
    robust, plain = [], []
    for yaw in yaws:
        xy, _ = project_points(PAPER_MARKER.feature_points, camera_in_target(1.5, yaw, 0.1, -0.1))
        robust.append(advanced_features(xy))
        plain.append(paper_features(xy))
    robust, plain = np.array(robust), np.array(plain)
    # p_psi is the camera's rotation about its optical axis relative to the target
    np.testing.assert_allclose(wrap_angle(robust[:, 2] - yaws), 0.0, atol=0.02)
    assert np.all(np.abs(np.diff(robust[:, 2])) < np.radians(1.5))  # continuous
    assert np.all(np.abs(np.diff(robust[:, :2], axis=0)) < 0.01)  # phi/theta continuous
    big = np.abs(yaws) > np.radians(95)
    assert np.all(np.abs(plain[big, 2] - wrap_angle(yaws[big] + np.pi)) < 0.02)  # off by pi


def test_no_division_by_zero_at_90_degrees():
    """At exactly 90 degrees the paper's denominators vanish; the robust features are
    finite and continuous there."""
    xy, _ = project_points(PAPER_MARKER.feature_points, camera_in_target(1.5, np.pi / 2))
    f = advanced_features(xy)
    assert np.all(np.isfinite(f)) and f[2] == pytest.approx(np.pi / 2)
    assert np.all(np.isfinite(feature_interaction_matrix(xy, 1.5)))
    for eps in (1e-9, -1e-9):
        xe, _ = project_points(PAPER_MARKER.feature_points, camera_in_target(1.5, np.pi / 2 + eps))
        np.testing.assert_allclose(advanced_features(xe), f, atol=1e-8)


def test_feature_error_wraps_angles():
    f = np.array([0.1, -0.1, np.radians(170.0), 0.0, 0.0, 1.0])
    fd = np.array([0.0, 0.0, np.radians(-170.0), 0.0, 0.0, 1.0])
    e = feature_error(f, fd)
    assert e[2] == pytest.approx(np.radians(-20.0))
    np.testing.assert_allclose(e[:2], [0.1, -0.1])


def test_features_jacobian_finite_differences():
    rng = np.random.default_rng(1)
    for _ in range(50):
        xy, _ = project_points(PAPER_MARKER.feature_points, random_pose(rng))
        jac = features_jacobian(xy)
        h = 1e-7
        num = np.zeros((6, 8))
        for k in range(8):
            d = np.zeros(8)
            d[k] = h
            fp = advanced_features(xy + d.reshape(4, 2))
            fm = advanced_features(xy - d.reshape(4, 2))
            num[:, k] = feature_error(fp, fm) / (2 * h)
        np.testing.assert_allclose(jac, num, atol=1e-6 * np.abs(jac).max())


@pytest.mark.parametrize("target", [PAPER_MARKER, PAPER_PATTERN], ids=["marker", "pattern"])
def test_interaction_matrix_finite_differences(target):
    """d p*/dt = J_img [w; v] for small camera motions g -> g exp(h xi) (body twist)."""
    rng = np.random.default_rng(2)
    pts = target.feature_points
    for _ in range(40):
        g = random_pose(rng)
        xy, z = project_points(pts, g)
        jac = feature_interaction_matrix(xy, z)
        h = 1e-6
        num = np.zeros((6, 6))
        for i in range(6):
            xi = np.zeros(6)
            xi[i] = h
            fp = advanced_features(project_points(pts, g @ expmap(xi))[0])
            fm = advanced_features(project_points(pts, g @ expmap(-xi))[0])
            num[:, i] = feature_error(fp, fm) / (2 * h)
        np.testing.assert_allclose(jac, num, rtol=0, atol=1e-7 * np.abs(jac).max())
        # the linear-first layout is the same matrix with permuted columns
        lin = feature_interaction_matrix(xy, z, order="linear_first")
        np.testing.assert_allclose(lin[:, :3], jac[:, 3:])
        np.testing.assert_allclose(lin[:, 3:], jac[:, :3])


def test_point_interaction_matrix_matches_notes():
    x, y, z = 0.2, -0.1, 2.0
    lin = point_interaction_matrix([[x, y]], z, order="linear_first")
    np.testing.assert_allclose(lin[0], [-1 / z, 0, x / z, x * y, -(1 + x * x), y])
    np.testing.assert_allclose(lin[1], [0, -1 / z, y / z, 1 + y * y, -x * y, -x])
    ang = point_interaction_matrix([[x, y]], z)
    np.testing.assert_allclose(ang, lin[:, [3, 4, 5, 0, 1, 2]])


def test_decoupling_at_the_desired_view():
    """Head-on and centred: p_psi sees only w_z, p_z only v_z, and the matrix is
    well conditioned (the paper's "decouples translational from rotational motion")."""
    xy, z = project_points(PAPER_MARKER.feature_points, camera_in_target(1.5))
    jac = feature_interaction_matrix(xy, z)
    np.testing.assert_allclose(jac[2], [0, 0, 1, 0, 0, 0], atol=1e-12)
    assert np.count_nonzero(np.abs(jac[5]) > 1e-12) == 1 and jac[5, 5] > 0
    assert np.linalg.cond(jac) < 100


def test_estimate_depths():
    rng = np.random.default_rng(3)
    for target in (PAPER_MARKER, PAPER_PATTERN):
        for _ in range(10):
            xy, z = project_points(target.feature_points, random_pose(rng))
            np.testing.assert_allclose(estimate_depths(xy, target.feature_points), z, rtol=1e-6)


def test_validation():
    with pytest.raises(ValueError, match="points"):
        advanced_features(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="points"):
        advanced_features([[0, 0], [0, 1], [1, 1], [np.nan, 0]])
    with pytest.raises(ValueError, match="distinct"):
        advanced_features([[0, 0], [0, 0], [1, 1], [1, 0]])
    with pytest.raises(ValueError, match="depths"):
        feature_interaction_matrix([[0, 0], [0, 1], [1, 1], [1, 0]], [1, 1, -1, 1])
    with pytest.raises(ValueError, match="order"):
        point_interaction_matrix([[0, 0]], 1.0, order="sideways")
