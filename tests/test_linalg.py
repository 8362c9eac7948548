"""tdacm._linalg.solve: np.linalg.solve's results (bit for bit) and errors, less overhead."""

import numpy as np
import pytest

from tdacm._linalg import solve


@pytest.mark.parametrize("n", [3, 4, 6, 8])
def test_solve_bit_identical_to_numpy(n):
    rng = np.random.default_rng(n)
    a = rng.standard_normal((n, n)) + n * np.eye(n)
    for b in (rng.standard_normal(n), rng.standard_normal((n, 4))):
        assert np.array_equal(solve(a, b), np.linalg.solve(a, b))
    at = a.T  # a non-contiguous view, as the controller passes it
    b = rng.standard_normal(n)
    assert np.array_equal(solve(at, b), np.linalg.solve(at, b))


def test_solve_singular_raises_like_numpy():
    with pytest.raises(np.linalg.LinAlgError, match="Singular matrix"):
        solve(np.zeros((3, 3)), np.ones(3))


def test_solve_other_inputs_go_to_numpy():
    a = [[2, 0], [0, 4]]  # lists and integers: np.linalg.solve's handling
    assert np.array_equal(solve(a, [2, 4]), np.linalg.solve(a, [2, 4]))
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.ones((2, 3)), np.ones(2))


def test_solve_small_matches_lapack_and_flags_singular():
    """The numba LU solve (target filter, stiff integrators) against LAPACK's, and a zero
    pivot reported instead of raised."""
    from tdacm._linalg import solve_small

    rng = np.random.default_rng(2)
    for n in (2, 6, 9):
        a = rng.standard_normal((n, n)) + n * np.eye(n)
        b = rng.standard_normal(n)
        x, ok = solve_small(a, b)
        assert ok
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-12, atol=1e-14)
    a = np.ones((3, 3))
    x, ok = solve_small(a, np.ones(3))
    assert not ok and not x.any()
    with np.testing.assert_raises(np.linalg.LinAlgError):
        np.linalg.solve(a, np.ones(3))  # what LAPACK does with the same matrix


@pytest.mark.parametrize("shape", [(6, 6), (6, 4), (6, 8)])
def test_svd_solve_matches_numpy(shape):
    """``svd_solve`` (the servo's twist, the joint rates) against numpy: the pseudo-inverse
    (``np.linalg.pinv(a, rcond) @ b``, also rank-deficient: the same singular values cut),
    and the floored and damped inverses written with numpy's SVD."""
    from tdacm._linalg import SVD_DAMPED, SVD_FLOOR, SVD_PINV, svd_solve

    rng = np.random.default_rng(7)
    a = rng.standard_normal(shape)
    b = rng.standard_normal(6)
    np.testing.assert_allclose(
        svd_solve(a, b, SVD_PINV, 1e-8), np.linalg.pinv(a, rcond=1e-8) @ b, rtol=1e-12, atol=1e-13
    )
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    for kind, inv in ((SVD_FLOOR, 1.0 / np.maximum(s, 0.5)), (SVD_DAMPED, s / (s * s + 0.25))):
        np.testing.assert_allclose(
            svd_solve(a, b, kind, 0.5), vt.T @ (inv * (u.T @ b)), rtol=1e-12, atol=1e-13
        )
    a[:, 1] = a[:, 0]  # rank-deficient
    np.testing.assert_allclose(
        svd_solve(a, b, SVD_PINV, 1e-8), np.linalg.pinv(a, rcond=1e-8) @ b, rtol=1e-10, atol=1e-12
    )
