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


def test_compiled_update_equals_the_filter():
    """:func:`filter_update` (the batched engine's) against :meth:`TargetFilter.update_checked`
    on a moving camera with 1 px of corner noise and outliers (gated out, then a restart):
    the same decisions (fused / rejected, hypotheses) and the same estimate to 1e-12."""
    from tdacm.vision.camera import PinholeCamera
    from tdacm.vision.ippe import canonical_frame
    from tdacm.vision.target_filter import (
        F_NHYP,
        F_REJECTED,
        F_UPDATES,
        N_FSTATE,
        TargetFilter,
        filter_params,
        filter_update,
        target_in_camera,
    )

    cam = PinholeCamera(fx=600.0, fy=600.0, cx=320.0, cy=240.0, width=640, height=480)
    obj = np.array([[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0.0]])
    f = TargetFilter(cam, obj, 1.0, level_prior=np.radians(0.5), window=60)
    obj2d, canon = canonical_frame(obj)
    prm, row = filter_params(f), np.array([cam.fx, cam.fy, cam.cx, cam.cy])
    st, pose, cov, hyp = np.zeros(N_FSTATE), np.zeros((4, 4)), np.zeros((6, 6)), np.zeros((2, 4, 4))
    rc, pc, z = np.zeros((60, 3, 3)), np.zeros((60, 3)), np.zeros((60, 4, 2))
    rng = np.random.default_rng(1)
    g_t = np.eye(4)
    g_t[:3, :3] = expmap(np.array([0.01, -0.008, 0.3, 0, 0, 0]))[:3, :3]
    g_0 = np.eye(4)
    g_0[:3, :3] = np.diag([1.0, -1.0, -1.0])
    g_0[:3, 3] = [0.1, -0.05, 2.5]
    rejected = 0
    for i in range(150):
        a = np.array([0.02 * np.sin(i / 30), 0.03 * np.cos(i / 40), 0.001 * i,
                      0.3 * np.sin(i / 50), 0.2 * np.cos(i / 60), 0.1 * np.sin(i / 70)])  # fmt: skip
        g_c = g_0 @ expmap(a)
        r = target_in_camera(obj, g_c, g_t)
        uv = np.column_stack(
            (cam.fx * r[:, 0] / r[:, 2] + cam.cx, cam.fy * r[:, 1] / r[:, 2] + cam.cy)
        )
        uv += rng.standard_normal(uv.shape) * (40.0 if 60 <= i < 66 else 1.0)  # outliers
        fused = f.update_checked(uv, g_c)
        assert filter_update(prm, row, st, pose, cov, hyp, rc, pc, z, obj, obj2d,
                             np.linalg.inv(canon), f.level_normal, uv, g_c) == fused  # fmt: skip
        assert (st[F_UPDATES], st[F_REJECTED], st[F_NHYP]) == (f.updates, f.rejected, len(f._hyp))
        if f.pose is not None:
            np.testing.assert_allclose(pose, f.pose, rtol=0, atol=1e-12)
            np.testing.assert_allclose(cov, f.P, rtol=1e-9, atol=0)
        rejected = f.rejected
    assert rejected >= 5  # the outliers were gated out and the filter restarted
