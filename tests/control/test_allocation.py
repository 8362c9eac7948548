import numpy as np
import pytest

from tdacm import paper_system
from tdacm.control import allocate_tensions, allocate_thrusts


@pytest.fixture(scope="module")
def b_s():
    s = paper_system()
    return s.tendon_matrix(np.array([0, 0, 0, 0, 0, 3, 0.2, -0.1]))


def test_tensions_exact_and_nonnegative(b_s):
    rng = np.random.default_rng(0)
    for _ in range(200):
        tau = rng.uniform(-0.15, 0.15, 2)
        a = allocate_tensions(b_s, tau, 20.0, pretension=0.5)
        assert np.all(a.tensions >= 0.0) and np.all(a.tensions <= 20.0)
        assert not a.saturated
        assert np.allclose(b_s @ a.tensions, tau, atol=1e-6)


def test_pretension_on_common_mode(b_s):
    a = allocate_tensions(b_s, np.zeros(2), 20.0, pretension=0.8)
    assert np.allclose(a.tensions, 0.8, atol=1e-6)


def test_saturation_reported(b_s):
    a = allocate_tensions(b_s, np.array([1.0, 0.0]), 20.0)  # needs 100 N differential
    assert a.saturated and a.at_max and a.residual > 0.5
    assert np.all(a.tensions >= 0.0) and np.all(a.tensions <= 20.0)


def test_thrusts_through_gamma():
    s = paper_system()
    a = allocate_thrusts(s.base.gamma, np.array([0.1, -0.05, 0.01]), 7.5, s.base.max_thrust)
    g = s.base.gamma[[0, 1, 2, 5]]
    assert not a.saturated
    assert np.allclose(g @ a.thrusts, [0.1, -0.05, 0.01, 7.5])
    a = allocate_thrusts(s.base.gamma, np.array([5.0, 0.0, 0.0]), 7.5, s.base.max_thrust)
    assert a.saturated and np.all(a.thrusts >= 0) and np.all(a.thrusts <= 15.0)
