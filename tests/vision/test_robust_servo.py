"""Robust servo: the well-conditioned solve, the world-frame target filter, prediction through
missed frames and latency compensation (docs/control.md, "Robust servo")."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.lie.se3 import expmap, rotation_angle
from tdacm.loop.config import IbvsConfig
from tdacm.loop.servo import RobustServo
from tdacm.system.paper import paper_system
from tdacm.vision import (
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PAPER_MARKER,
    TargetFilter,
    feature_interaction_matrix,
)
from tdacm.vision.features import advanced_features, feature_error
from tdacm.vision.ibvs import robust_solve
from tdacm.vision.kinematic import project_points

SIGMA_PX = 1.0


def _camera(distance, lateral=(0.0, 0.0), tilt=(0.0, 0.0)):
    """World pose of a camera looking at the target (at the origin, facing -z in the
    target frame convention of :func:`project_points`) from ``distance``."""
    g = np.eye(4)
    g[:3, 3] = [lateral[0], lateral[1], -distance]
    return g @ expmap(np.array([tilt[0], tilt[1], 0.0, 0.0, 0.0, 0.0]))


def _pixels(g_cam, target=PAPER_MARKER):
    xy, _ = project_points(target.feature_points, g_cam)
    return LOCAL_CAMERA.denormalize(xy)


def _rot_err_deg(g_est):
    r = np.asarray(g_est)[:3, :3]  # against the identity (the target frame)
    return float(np.degrees(rotation_angle(r)))


# ---------------------------------------------------------------------- the solve
def _interaction_at(distance):
    xy, z = project_points(PAPER_MARKER.feature_points, _camera(distance))
    return xy, z, feature_interaction_matrix(xy, z)


def test_interaction_matrix_has_two_weak_directions():
    """The measured fact behind the design: two singular values 30-60x below the others."""
    _, _, jac = _interaction_at(1.5)
    s = np.linalg.svd(jac, compute_uv=False)
    assert s[0] / s[-1] > 25 and s[0] / s[-2] > 25
    assert s[3] / s[4] > 3


@pytest.mark.parametrize("solver", ["floor", "damped"])
def test_floored_solve_does_not_amplify_noise_along_weak_directions(solver):
    """1 px corner noise through J_img^-1 gives a twist dominated by the weak directions;
    the floored (or damped) solve bounds the amplification by 1/floor (3 m: the start of
    paper-in-fov, where the weak singular values are ~0.02)."""
    xy, z, jac = _interaction_at(3.0)
    floor = 0.05
    rng = np.random.default_rng(0)
    f0 = advanced_features(xy)
    plain, robust = [], []
    for _ in range(400):
        noisy = xy + rng.normal(0.0, SIGMA_PX / LOCAL_CAMERA.fx, xy.shape)
        e = feature_error(advanced_features(noisy), f0)
        plain.append(robust_solve(jac, e, 0.0))
        robust.append(robust_solve(jac, e, floor, solver))
        assert np.linalg.norm(robust[-1]) <= np.linalg.norm(e) / floor * (1 + 1e-9)
    plain, robust = np.std(plain, axis=0), np.std(robust, axis=0)
    # the plain inverse: the noise lands in w_x/v_y and w_y/v_x
    assert plain[[0, 1, 3, 4]].min() > 5 * plain[[2, 5]].max()
    s = np.linalg.svd(jac, compute_uv=False)
    assert s[-1] < 0.5 * floor
    assert np.linalg.norm(robust) < 0.6 * np.linalg.norm(plain)
    # operator norm of the floored inverse
    u, _, _ = np.linalg.svd(jac)
    for k in range(6):
        x = robust_solve(jac, u[:, k], floor, solver)
        assert np.linalg.norm(x) <= 1.0 / floor + 1e-9


def test_floored_solve_is_exact_on_strong_directions_and_positive_definite():
    _, _, jac = _interaction_at(1.5)
    u, s, vt = np.linalg.svd(jac)
    floor = 0.05
    strong = s >= floor
    e = u[:, strong] @ np.array([0.3, -0.2, 0.1, 0.05])[: strong.sum()]
    np.testing.assert_allclose(robust_solve(jac, e, floor), np.linalg.solve(jac, e), atol=1e-12)
    # J J^+ = U diag(min(1, s/floor)) U^T: symmetric positive definite -> |e| decreases
    m = np.column_stack([jac @ robust_solve(jac, u[:, k], floor) for k in range(6)]) @ u.T
    np.testing.assert_allclose(m, m.T, atol=1e-10)
    ev = np.linalg.eigvalsh(0.5 * (m + m.T))
    np.testing.assert_allclose(np.sort(ev), np.sort(np.minimum(1.0, s / floor)), atol=1e-10)
    assert ev.min() > 0


def test_robust_solve_validates():
    _, _, jac = _interaction_at(1.5)
    with pytest.raises(ValueError, match="floor"):
        robust_solve(jac, np.zeros(6), -1.0)
    with pytest.raises(ValueError, match="solver"):
        robust_solve(jac, np.zeros(6), 0.1, "magic")


# ---------------------------------------------------------------------- target filter
def test_filter_averages_noise_in_the_weak_directions():
    """Static target, 1 px noise: one frame knows the tilt to several degrees; 200 fused
    frames to a fraction of a degree, consistent with the filter's covariance."""
    g_cam = _camera(1.5)
    pix = _pixels(g_cam)
    rng = np.random.default_rng(1)
    exact = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    exact.update(pix, g_cam)  # one frame's information at the true pose
    sig1 = np.degrees(np.sqrt(np.diag(exact.P)[:2]))
    f = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    for _ in range(200):
        assert f.update(pix + rng.normal(0, SIGMA_PX, pix.shape), g_cam)
    sig200 = np.degrees(np.sqrt(np.diag(f.P)[:2]))
    assert sig1.min() > 3.0  # one frame: degrees
    np.testing.assert_allclose(sig200, sig1 / np.sqrt(200), rtol=0.1)
    assert _rot_err_deg(f.pose) < 4 * sig200.max()
    assert np.linalg.norm(f.pose[:3, 3]) < 0.01
    assert f.estimate.updates == 200


def test_filter_gates_outliers():
    g_cam = _camera(1.5)
    pix = _pixels(g_cam)
    rng = np.random.default_rng(2)
    f = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    for _ in range(30):
        f.update(pix + rng.normal(0, SIGMA_PX, pix.shape), g_cam)
    before = f.pose.copy()
    bad = pix.copy()
    bad[0] += 40.0  # a mis-detected corner
    assert not f.update(bad, g_cam)
    np.testing.assert_array_equal(f.pose, before)
    assert f.rejected == 1


def test_filter_reinitializes_after_persistent_rejections():
    g_cam = _camera(1.5)
    f = TargetFilter(LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, reset_after=3)
    for _ in range(10):
        f.update(_pixels(g_cam), g_cam)
    moved = np.eye(4)
    moved[:3, 3] = [0.3, 0.0, 0.0]  # the target really moved (or the estimate is wrong)
    for _ in range(3):
        f.update(_pixels(g_cam @ np.linalg.inv(moved)), g_cam)
    np.testing.assert_allclose(f.pose[:3, 3], [0.3, 0.0, 0.0], atol=1e-6)


def test_latency_frames_are_associated_with_the_capture_pose():
    """A frame captured 2 periods ago, while the camera moved at 0.5 m/s: fused with the
    capture-time pose the estimate is exact; with the current pose it is off by the motion."""
    dt, speed = 0.02, 0.5
    poses = [_camera(2.0, lateral=(speed * dt * k, 0.0)) for k in range(40)]
    good = TargetFilter(LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=0.1)
    naive = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=0.1
    )
    for k in range(2, 40):
        pix = _pixels(poses[k - 2])  # delivered at step k
        good.update(pix, poses[k - 2])
        naive.update(pix, poses[k])
    assert np.linalg.norm(good.pose[:3, 3]) < 1e-6
    assert np.linalg.norm(naive.pose[:3, 3]) > 0.5 * 2 * speed * dt


# ---------------------------------------------------------------------- uncertain camera poses
def test_pose_noise_matches_finite_differences():
    """``G`` of :meth:`TargetFilter.pose_noise`: image motion under a camera-pose perturbation
    ``g_C exp(eps^)``, against central differences (camera 1.5 m away, tilted and shifted)."""
    f = TargetFilter(LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0)
    g_cam = _camera(1.5, lateral=(0.1, -0.05), tilt=(0.05, -0.03))
    g_t = np.eye(4)
    rel = np.linalg.solve(g_cam, g_t)
    r = PAPER_MARKER.feature_points @ rel[:3, :3].T + rel[:3, 3]
    g_num = np.zeros((8, 6))
    h = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        xp, _ = project_points(PAPER_MARKER.feature_points, g_cam @ expmap(d))
        xm, _ = project_points(PAPER_MARKER.feature_points, g_cam @ expmap(-d))
        g_num[:, i] = ((xp - xm) / (2 * h)).ravel()
    for i in range(6):  # unit covariance on one coordinate -> G e_i e_i^T G^T
        cov = np.zeros((6, 6))
        cov[i, i] = 1.0
        np.testing.assert_allclose(
            f.pose_noise(r, cov), np.outer(g_num[:, i], g_num[:, i]), atol=1e-6
        )


def _noisy_pose_run(weighted, seed, frames=150, att=0.004, pos=0.003):
    """A static target seen from 1.5 m while the camera drifts sideways; every frame's pose
    is known only to ``att`` rad / ``pos`` m (white), the corners to 1 px."""
    rng = np.random.default_rng(seed)
    cov = np.diag([att**2] * 3 + [pos**2] * 3)
    f = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    for k in range(frames):
        g_true = _camera(1.5, lateral=(0.3 * k / frames, 0.0))
        pix = _pixels(g_true) + rng.normal(0, SIGMA_PX, (4, 2))
        eps = np.concatenate((rng.normal(0, att, 3), rng.normal(0, pos, 3)))
        f.update(pix, g_true @ expmap(eps), cov if weighted else None)
    return f


def test_filter_with_pose_covariance_keeps_frames_and_is_consistent():
    """Camera poses from a state estimate (4 mrad, 3 mm): without their covariance the gate
    rejects frames and the tilt ends several sigma off; with it no frame is rejected, the
    estimate is better and its error consistent with its covariance (NEES over seeds)."""
    nees_w, err_w, err_u, rej_u = [], [], [], 0
    for seed in range(12):
        w = _noisy_pose_run(True, seed)
        u = _noisy_pose_run(False, seed)
        assert w.rejected == 0
        rej_u += u.rejected
        rv = np.array([w.pose[2, 1] - w.pose[1, 2], w.pose[0, 2] - w.pose[2, 0],
                       w.pose[1, 0] - w.pose[0, 1]]) / 2  # fmt: skip
        x = np.concatenate((rv, w.pose[:3, 3]))  # error of the (identity) target pose
        nees_w.append(float(x @ np.linalg.solve(w.P, x)))
        err_w.append(_rot_err_deg(w.pose))
        err_u.append(_rot_err_deg(u.pose))
    assert rej_u > 0
    assert np.mean(err_w) < 0.3 * np.mean(err_u)  # measured: 0.53 vs 4.7 deg
    # 6 degrees of freedom; 12 runs: the mean NEES lies in [3.2, 9.4] with 99 % probability
    assert 3.2 < np.mean(nees_w) < 9.4
    assert abs(w.sigma_hat / SIGMA_PX - 1.0) < 0.15  # the weights explain the residuals


def test_exact_pose_covariance_is_the_unweighted_filter():
    """A zero covariance means an exact pose: bit-identical to passing none."""
    a = _noisy_pose_run(False, 3, frames=40)
    rng = np.random.default_rng(3)
    b = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    for k in range(40):
        g_true = _camera(1.5, lateral=(0.3 * k / 40, 0.0))
        pix = _pixels(g_true) + rng.normal(0, SIGMA_PX, (4, 2))
        eps = np.concatenate((rng.normal(0, 0.004, 3), rng.normal(0, 0.003, 3)))
        b.update(pix, g_true @ expmap(eps), np.zeros((6, 6)))
    np.testing.assert_array_equal(a.pose, b.pose)


# ---------------------------------------------------------------------- predictive servo
def _servo(smoothing=0.0):
    g_des = _camera(1.5)
    xd, zd = project_points(PAPER_MARKER.feature_points, g_des)
    # the prediction takes the camera pose as an argument: the robot (the paper's) is not asked
    return RobustServo(
        paper_system(), LOCAL_CAMERA, GLOBAL_CAMERA, PAPER_MARKER, np.eye(4), np.eye(4), xd, zd,
        config=IbvsConfig(
            gain=1.0, mode="mean", filter_smoothing=smoothing, target_level_prior_deg=0.0
        ),
    )  # fmt: skip


def test_prediction_through_missed_frames():
    """After a few frames the servo keeps predicting the features at the moving camera's
    pose with no detection at all: twist defined and continuous, points exact."""
    servo = _servo()
    assert not servo.predicted_view(_camera(2.0)).valid  # nothing seen yet
    for k in range(5):
        g = _camera(2.0, lateral=(0.01 * k, 0.0))
        assert servo.target_filter.update(_pixels(g), g)
        servo.predict_target(0.02)
    twists = []
    for k in range(5, 30):  # 25 missed frames while the camera keeps moving
        g = _camera(2.0 - 0.01 * k, lateral=(0.01 * k, 0.0))
        servo.predict_target(0.02)
        st = servo.predicted_view(g, g)
        assert st.valid
        xy_true, z_true = project_points(PAPER_MARKER.feature_points, g)
        np.testing.assert_allclose(st.points, xy_true, atol=1e-9)
        np.testing.assert_allclose(st.depths, z_true, atol=1e-9)
        np.testing.assert_allclose(st.pixels_local, LOCAL_CAMERA.denormalize(xy_true), atol=1e-6)
        twists.append(st.twist)
    steps = np.linalg.norm(np.diff(twists, axis=0), axis=1)
    assert steps.max() < 0.05 * np.linalg.norm(twists[0])


def test_smoothing_spreads_estimate_corrections():
    """A correction of the estimate reaches the prediction with the smoothing time constant
    (the target is static, so this adds no lag to the camera's own motion)."""
    servo = _servo(smoothing=0.5)
    g = _camera(2.0)
    servo.target_filter.update(_pixels(g), g)
    servo.predict_target(0.02)
    shift = np.eye(4)
    shift[:3, 3] = [0.05, 0.0, 0.0]
    servo.target_filter.pose = shift @ servo.target_filter.pose  # a 5 cm correction of the estimate
    for _ in range(25):  # 0.5 s = one time constant
        servo.predict_target(0.02)
    moved = servo.target_pose[0, 3]
    assert 0.05 * (1 - np.exp(-1)) * 0.9 < moved < 0.05 * (1 - np.exp(-1)) * 1.1


def test_information_is_the_inverse_of_the_converged_covariance():
    """``information`` of a set of camera poses = ``P^-1`` of the filter that fused noise-free
    frames from them (the Cramer-Rao bound the filter attains); a wider baseline gives more
    information on the tilt than the same number of frames from one pose."""
    f = TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, pixel_sigma=SIGMA_PX
    )
    poses = [_camera(1.5, lateral=(0.004 * k - 0.1, 0.002 * k)) for k in range(50)]
    for g in poses:
        assert f.update(_pixels(g), g)
    info = f.information(np.eye(4), poses)
    np.testing.assert_allclose(info @ f.P, np.eye(6), atol=1e-6)
    one_pose = f.information(np.eye(4), [poses[25]] * 50)
    wide = f.information(
        np.eye(4), [_camera(1.5, lateral=(0.4 * (k % 2) - 0.2, 0)) for k in range(50)]
    )
    assert np.linalg.inv(wide)[1, 1] < 0.5 * np.linalg.inv(one_pose)[1, 1]
    with pytest.raises(ValueError, match="camera_covs"):
        f.information(np.eye(4), poses, [None])


def test_checked_update_is_the_validating_update():
    """``update_checked`` (the servo's per-period call) gives the same estimates as ``update``,
    rejections and the re-initialization included; ``update`` names a bad input."""
    g_cam = _camera(1.5)
    pix = _pixels(g_cam)
    moved = np.eye(4)
    moved[:3, 3] = [0.3, 0.0, 0.0]
    rng = np.random.default_rng(5)
    frames = [pix + rng.normal(0, SIGMA_PX, pix.shape) for _ in range(12)]
    frames += [_pixels(g_cam @ np.linalg.inv(moved))] * 4  # rejected, then a reset
    a = TargetFilter(
        LOCAL_CAMERA,
        PAPER_MARKER.feature_points,
        level_prior=0.0,
        pixel_sigma=SIGMA_PX,
        reset_after=3,
    )
    b = TargetFilter(
        LOCAL_CAMERA,
        PAPER_MARKER.feature_points,
        level_prior=0.0,
        pixel_sigma=SIGMA_PX,
        reset_after=3,
    )
    for px in frames:
        assert a.update(px, g_cam) == b.update_checked(px, g_cam)
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.P, b.P)
    assert a.rejected == b.rejected > 0
    np.testing.assert_allclose(a.pose[:3, 3], [0.3, 0.0, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="camera_pose"):
        a.update(pix, 2.0 * g_cam)
