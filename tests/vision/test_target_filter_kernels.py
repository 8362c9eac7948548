"""The target filter's normal-equation kernel against the matrix-product form (its diagonal-
weight path skips exact zeros only)."""

import numpy as np
import pytest

from tdacm.lie.se3 import expmap
from tdacm.vision.target_filter import _frame_residuals, _normal_equations, _target_points


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
    info, grad, cost, ok = _normal_equations(rt, pt, rc, pc, z, obj, w)
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
