"""The target filter's normal-equation kernel: the diagonal-weight path gives the same sums,
bit for bit, as the full 8 x 8 products (it only skips exact zeros)."""

import numpy as np

from tdacm.lie.se3 import expmap
from tdacm.vision.target_filter import _normal_equations


def test_diagonal_path_equals_full_products():
    rng = np.random.default_rng(3)
    n = 40
    obj = np.array([[-0.1, -0.1, 0], [-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0.0]])
    rt = np.ascontiguousarray(expmap(0.1 * rng.standard_normal(6))[:3, :3])
    pt = 0.05 * rng.standard_normal(3)
    rc = np.array([expmap(0.05 * rng.standard_normal(6))[:3, :3] for _ in range(n)])
    pc = np.array([0, 0, -2.0]) + 0.01 * rng.standard_normal((n, 3))
    z = obj[None, :, :2] / 2.0 + 1e-3 * rng.standard_normal((n, 4, 2))
    w = np.tile(np.diag(rng.uniform(1e4, 1e5, 8)), (n, 1, 1))
    fast = _normal_equations(rt, pt, rc, pc, z, obj, w, np.ones(n, np.bool_))
    full = _normal_equations(rt, pt, rc, pc, z, obj, w, np.zeros(n, np.bool_))
    assert fast[3] and full[3]
    for a, b in zip(fast[:3], full[:3], strict=True):
        assert np.array_equal(a, b)
