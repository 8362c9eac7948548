"""The target filter's normal-equation kernel against the matrix-product form (its diagonal-
weight path skips exact zeros only)."""

import numpy as np
import pytest

from tdacm.lie.se3 import expmap
from tdacm.vision.target_filter import (
    _diagonal_flags,
    _frame_residuals,
    _gauss_newton_kernel,
    _level_prior_into,
    _normal_equations,
    _target_points,
)


@pytest.mark.parametrize("diagonal", [True, False])
def test_normal_equations_match_matrix_products(diagonal):
    rng = np.random.default_rng(3)
    n = 40
    obj = np.array([[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0.0]])
    rt = np.ascontiguousarray(expmap(0.1 * rng.standard_normal(6))[:3, :3])
    pt = 0.05 * rng.standard_normal(3)
    rc = np.array([expmap(0.05 * rng.standard_normal(6))[:3, :3] for _ in range(n)])
    pc = np.array([0, 0, -2.0]) + 0.01 * rng.standard_normal((n, 3))
    z = obj[None, :, :2] / 2.0 + 1e-3 * rng.standard_normal((n, 4, 2))
    w = np.tile(np.diag(rng.uniform(1e4, 1e5, 8)), (n, 1, 1))
    if not diagonal:
        w = w + 10.0 * np.ones((8, 8))  # a pose-noise term couples the points
    diag = _diagonal_flags(w)
    assert diag.all() == diagonal and diag.any() == diagonal
    info, grad, cost, ok = _normal_equations(rt, pt, rc, pc, z, obj, w, diag)
    assert ok
    xw = _target_points(rt, pt, obj)
    ref_i, ref_g, ref_c = np.zeros((6, 6)), np.zeros(6), 0.0
    for f in range(n):
        h, e = np.empty((8, 6)), np.empty(8)
        assert _frame_residuals(rc[f], pc[f], rt, xw, obj, z[f], np.empty((3, 3)), h, e)
        ref_i += h.T @ w[f] @ h
        ref_g += h.T @ w[f] @ e
        ref_c += e @ w[f] @ e
    np.testing.assert_allclose(info, ref_i, rtol=1e-12, atol=1e-12 * np.abs(ref_i).max())
    np.testing.assert_allclose(grad, ref_g, rtol=1e-12, atol=1e-12 * np.abs(ref_g).max())
    assert cost == pytest.approx(ref_c, rel=1e-12)


def test_level_prior_terms_match_the_matrix_form():
    """``_level_prior_into`` = ``w [h^T h, h^T e, e.e]`` with ``h = [skew(m)[:2], 0]``,
    ``e = -m[:2]``, ``m = R^T n`` (the target filter's level prior)."""
    from tdacm.lie.se3 import skew

    rng = np.random.default_rng(5)
    rt = np.ascontiguousarray(expmap(0.3 * rng.standard_normal(6))[:3, :3])
    normal = np.array([0.1, -0.2, -0.97])
    normal /= np.linalg.norm(normal)
    m = rt.T @ normal
    h = np.zeros((2, 6))
    h[:, :3] = skew(m)[:2]
    e = -m[:2]
    info, grad = np.ones((6, 6)), np.ones(6)  # the kernel adds to what is there
    cost = _level_prior_into(rt, normal, 7.0, info, grad)
    np.testing.assert_allclose(info, 1.0 + 7.0 * h.T @ h, rtol=0, atol=1e-14)
    np.testing.assert_allclose(grad, 1.0 + 7.0 * h.T @ e, rtol=0, atol=1e-14)
    assert cost == pytest.approx(7.0 * e @ e, rel=1e-14)


def test_gauss_newton_kernel_recovers_the_target_pose():
    """Noise-free frames from 12 camera poses: from a pose 3 deg and 2 cm off, the kernel
    returns the true target pose, zero cost, a symmetric positive definite information, and
    the same step as one numpy Gauss-Newton step (``solve(info, grad)``) on iteration 1."""
    rng = np.random.default_rng(11)
    obj = np.array([[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0.0]])
    g_t = expmap(np.array([0.02, -0.03, 0.4, 0.05, -0.02, 0.0]))
    n = 12
    rc, pc, z = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 4, 2))
    for f in range(n):
        g_c = expmap(np.concatenate((0.1 * rng.standard_normal(3), [0.0, 0.0, 0.0])))
        g_c[:3, 3] = g_t[:3, 3] + np.array([0.0, 0.0, 1.5]) + 0.1 * rng.standard_normal(3)
        g_c[:3, :3] = g_c[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # looking down at the target
        rc[f], pc[f] = g_c[:3, :3].T, g_c[:3, 3]
        r = (obj @ g_t[:3, :3].T + g_t[:3, 3] - pc[f]) @ rc[f].T
        assert np.all(r[:, 2] > 0)
        z[f] = r[:, :2] / r[:, 2:3]
    w = np.tile(np.eye(8) * 1e5, (n, 1, 1))
    diag = np.ones(n, np.bool_)
    start = g_t @ expmap(np.array([0.03, -0.02, 0.04, 0.02, -0.01, 0.015]))
    normal = np.array([0.0, 0.0, -1.0])
    pose, info, cost, p_info, p_grad, p_cost, ok = _gauss_newton_kernel(
        start, rc, pc, z, obj, w, diag, 8, normal, 0.0
    )
    assert ok
    np.testing.assert_allclose(pose, g_t, atol=1e-10)
    assert cost < 1e-16
    np.testing.assert_allclose(info, info.T, atol=1e-9 * np.abs(info).max())
    assert np.linalg.eigvalsh(info).min() > 0
    assert not p_info.any() and not p_grad.any() and p_cost == 0.0  # no prior
    # one iteration = one numpy GN step from the start
    pose1 = _gauss_newton_kernel(start, rc, pc, z, obj, w, diag, 1, normal, 0.0)[0]
    rt0 = np.ascontiguousarray(start[:3, :3])
    i0, g0, _, _ = _normal_equations(rt0, start[:3, 3].copy(), rc, pc, z, obj, w, diag)
    np.testing.assert_allclose(pose1, start @ expmap(np.linalg.solve(i0, g0)), atol=1e-13)
    # a point behind a camera: not ok
    far = start.copy()
    far[2, 3] += 10.0
    assert not _gauss_newton_kernel(far, rc, pc, z, obj, w, diag, 2, normal, 0.0)[-1]


CAM = dict(fx=600.0, fy=610.0, cx=320.0, cy=240.0, width=640, height=480)
OBJ = np.array([[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0.0]])
POSE_COV = np.diag([0.004**2] * 3 + [0.003**2] * 3)  # 4 mrad, 3 mm


def _frames(count, outliers=(), seed=1, pose_error=()):
    """``(pixels, camera pose)`` of a camera moving over a static target 2.5 m below (1 px of
    corner noise; 40 px on the frames ``outliers``; on the frames ``pose_error`` the pose is
    off by :data:`POSE_COV`)."""
    from tdacm.vision.target_filter import target_in_camera

    rng = np.random.default_rng(seed)
    g_t = np.eye(4)
    g_t[:3, :3] = expmap(np.array([0.01, -0.008, 0.3, 0, 0, 0]))[:3, :3]
    g_0 = np.eye(4)
    g_0[:3, :3] = np.diag([1.0, -1.0, -1.0])
    g_0[:3, 3] = [0.1, -0.05, 2.5]
    for i in range(count):
        a = np.array([0.02 * np.sin(i / 30), 0.03 * np.cos(i / 40), 0.001 * i,
                      0.3 * np.sin(i / 50), 0.2 * np.cos(i / 60), 0.1 * np.sin(i / 70)])  # fmt: skip
        g_c = g_0 @ expmap(a)
        r = target_in_camera(OBJ, g_c, g_t)
        uv = np.column_stack(
            (CAM["fx"] * r[:, 0] / r[:, 2] + CAM["cx"], CAM["fy"] * r[:, 1] / r[:, 2] + CAM["cy"])
        )
        uv += rng.standard_normal(uv.shape) * (40.0 if i in outliers else 1.0)
        if i in pose_error:
            eps = np.concatenate((rng.normal(0, 0.004, 3), rng.normal(0, 0.003, 3)))
            g_c = g_c @ expmap(eps)
        yield uv, g_c


def test_zero_camera_covariance_is_the_exact_pose_and_a_world_row_is_the_block():
    """:func:`filter_update` with a camera-pose covariance of zeros, called on world 1's row
    of two worlds' stacked records (the batched engine's call), equals
    :meth:`TargetFilter.update` without a covariance (the block loop's) bit for bit: every
    field of the state after every frame, through gated outliers and the restart they cause."""
    from tdacm._records import replicate, stack, take
    from tdacm.vision.camera import PinholeCamera
    from tdacm.vision.target_filter import TargetFilter, TargetFilterState, filter_update

    f = TargetFilter(PinholeCamera(**CAM), OBJ, 1.0, level_prior=np.radians(0.5), window=60)
    params = stack([f.params, f.params])
    states = replicate(TargetFilterState.initial(60), 2)
    outliers = set(range(60, 66))  # gated out, then (reset_after = 5) a restart
    restarted = False
    for i, (uv, g_c) in enumerate(_frames(150, outliers)):
        updates = f.updates
        fused = f.update(uv, g_c)
        restarted |= i in outliers and f.updates <= updates
        assert filter_update(take(params, 1), take(states, 1), uv, g_c, np.zeros((6, 6))) == fused
        for name, a, b in zip(f.state._fields, f.state, take(states, 1), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=name)
        assert not take(states, 0).count[0]  # the other world untouched
    assert f.rejected >= 5 and restarted
    assert f.state.diagonal[: f.state.count[0]].all()  # exact poses: the diagonal weights


def test_camera_covariance_weights_frames_by_their_pose_noise():
    """A frame with a camera-pose covariance ``Sigma_c`` is stored with the weight
    ``(R + G Sigma_c G^T)^-1`` (:func:`pose_noise` at the estimate before the frame; at the
    better PnP pose for the first), a frame without one with ``R^-1`` (diagonal)."""
    from tdacm.vision.camera import PinholeCamera
    from tdacm.vision.target_filter import TargetFilter, planar_pnp_poses, target_in_camera

    cam = PinholeCamera(**CAM)
    f = TargetFilter(cam, OBJ, 1.0, level_prior=np.radians(0.5), window=30)
    r_pixel = np.diag(np.tile([(1.0 / cam.fx) ** 2, (1.0 / cam.fy) ** 2], 4))
    uncertain = 0
    uncertain_frames = {i for i in range(80) if i % 3}
    for i, (uv, g_c) in enumerate(_frames(80, pose_error=uncertain_frames)):
        cov = POSE_COV if i in uncertain_frames else None
        at = f.pose if f.initialized else planar_pnp_poses(OBJ, cam.normalize(uv), g_c)[0]
        slot = int(f.state.slot[0])
        assert f.update(uv, g_c, cov)  # every frame fused (none gated)
        w = f.state.w[slot]
        if cov is None:
            np.testing.assert_array_equal(w, np.diag(np.tile([cam.fx**2, cam.fy**2], 4)))
            assert f.state.diagonal[slot]
            continue
        extra = f.pose_noise(target_in_camera(OBJ, g_c, at), cov)
        assert np.abs(extra).max() > 0.1 * r_pixel.max()  # the pose noise matters here
        expected = np.linalg.inv(r_pixel + extra)
        np.testing.assert_allclose(w, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
        np.testing.assert_array_equal(w, w.T)
        assert not f.state.diagonal[slot]
        uncertain += 1
    assert uncertain > 40 and f.rejected == 0


def test_rescue_adopts_the_other_branch_of_the_ambiguity():
    """The periodic rescue (module docstring): from the estimate on the wrong branch of the
    planar ambiguity, refining the latest frame's PnP poses on the window adopts the right
    one (lower cost by more than 1) and counts a switch; from the right estimate it keeps it."""
    from tdacm.lie.se3 import rotation_angle
    from tdacm.vision.camera import PinholeCamera
    from tdacm.vision.target_filter import (
        TargetFilter,
        _rescue,
        _solve_window,
        planar_pnp_poses,
    )

    cam = PinholeCamera(**CAM)
    f = TargetFilter(cam, OBJ, 1.0, level_prior=0.0, window=100, recheck=0)
    frames = list(_frames(100))
    for uv, g_c in frames:
        assert f.update(uv, g_c)
    right = f.pose
    uv, g_c = frames[-1]
    xy = np.ascontiguousarray(cam.normalize(uv))
    # the wrong branch: the latest frame's PnP pose farther from the estimate (its tilt
    # mirrored about the line of sight)
    angles = [rotation_angle(right[:3, :3].T @ h[:3, :3]) for h in planar_pnp_poses(OBJ, xy, g_c)]
    wrong = planar_pnp_poses(OBJ, xy, g_c)[int(np.argmax(angles))]
    assert len(angles) == 2 and max(angles) > np.radians(10)
    for start, switches in ((right, 0), (wrong, 1)):
        f.state.pose[:, :] = start
        f.state.switches[0] = 0
        cost = _solve_window(f.params, f.state, f.state.pose, 0)[2]
        _rescue(f.params, f.state, xy, g_c, cost)
        assert f.switches == switches
        # the same minimum of the window: the rescue's 4 Gauss-Newton steps and the filter's
        # 2 a frame stop 2e-5 apart (measured), the other branch is more than 10 deg away
        np.testing.assert_allclose(f.pose, right, atol=1e-4)
