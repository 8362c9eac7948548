"""Magnus integration of g' = g xi(X) converges at its order (paper eq. (7), NOTES)."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tdacm.lie.magnus import MAGNUS_POINTS, magnus_step
from tdacm.lie.se3 import expmap, hat


def strain(x):
    """A smooth, strongly varying strain twist (all six components)."""
    return np.array(
        [0.8 * np.sin(3 * x), 1.5 * x**2 - 0.4, 2.0 * np.cos(2 * x), 1.0 + 0.1 * x, 0.2 * x, -0.1]
    )


def reference_tip(length=1.0):
    def rhs(s, y):
        g = y.reshape(4, 4)
        return (g @ hat(strain(s / length))).ravel()

    sol = solve_ivp(rhs, (0, length), np.eye(4).ravel(), method="DOP853", rtol=1e-13, atol=1e-14)
    return sol.y[:, -1].reshape(4, 4)


def magnus_tip(order, n_steps, length=1.0):
    g = np.eye(4)
    h = length / n_steps
    frac = MAGNUS_POINTS[order]
    zero = np.zeros(1)
    for k in range(n_steps):
        xs = (k + frac) / n_steps
        xi0 = np.array([strain(x) for x in xs])
        bs = np.zeros((len(xs), 6, 1))
        omega, _, _, _ = magnus_step(h, xi0, bs, zero, zero)
        g = g @ expmap(omega)
    return g


@pytest.mark.parametrize("order", [2, 4])
def test_magnus_converges_at_its_order(order):
    ref = reference_tip()
    steps = np.array([4, 8, 16, 32])
    errors = np.array([np.abs(magnus_tip(order, n) - ref).max() for n in steps])
    slopes = -np.diff(np.log(errors)) / np.diff(np.log(steps))
    # observed order within 0.3 of the theoretical one on the last refinements
    assert np.all(np.abs(slopes[1:] - order) < 0.3), (errors, slopes)
    # absolute accuracy at 32 steps for this strongly varying strain (|xi'| up to ~4 /m^2)
    assert errors[-1] < (1e-3 if order == 2 else 1e-7)
