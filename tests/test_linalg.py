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
