"""Static equilibria against analytic beam solutions."""

import numpy as np
import pytest
from scipy.integrate import solve_bvp

import tdacm

from .conftest import horizontal_cantilever


def test_tip_moment_gives_exact_circular_arc():
    system = horizontal_cantilever(tdacm.StrainBasis.bending(2))
    system.loads.gravity = np.zeros(3)
    ei = system.rod.bending_stiffness
    moment = 0.05  # about local z: curvature k_z = M / EI ~ 1.27 1/m, a large deflection
    system.loads.tip_wrench = np.array([0, 0, moment, 0, 0, 0])
    q = system.static_equilibrium()
    k = moment / ei
    # only the order-0 coefficient of bending_z is excited (Legendre basis)
    assert np.allclose(q, [0, 0, 0, k, 0, 0], atol=1e-9)
    tip = system.tip_pose(q)[:3, 3]
    assert np.allclose(tip, [np.sin(k) / k, (1 - np.cos(k)) / k, 0], atol=1e-10)


@pytest.mark.parametrize(
    "tendon, axis, sign", [(0, 2, 1.0), (2, 2, -1.0), (1, 1, -1.0), (3, 1, 1.0)]
)
def test_tendon_tension_gives_curvature_tr_over_ei(tendon, axis, sign):
    system = horizontal_cantilever(tdacm.StrainBasis.bending(0))
    system.loads.gravity = np.zeros(3)
    tension, r = 2.0, 0.01
    u = np.zeros(4)
    u[tendon] = tension
    q = system.static_equilibrium(u)
    expected = np.zeros(2)
    expected[axis - 1] = sign * tension * r / system.rod.bending_stiffness
    assert np.allclose(q, expected, rtol=1e-10, atol=1e-12)
    # pulling a tendon bends the rod toward it
    tip = system.tip_pose(q)[:3, 3]
    offset = system.tendons.offsets[tendon]
    assert tip @ offset > 0


def test_own_weight_cantilever_converges_to_wl4_over_8ei():
    """Small deflection (gravity scaled down to stay linear): the exact curvature is quadratic
    in s, so the error drops with the bending order and vanishes at order 2."""
    g = 0.0981
    errors = []
    for order in range(3):
        system = horizontal_cantilever(tdacm.StrainBasis.bending(order))
        system.loads.gravity = np.array([0, 0, -g])
        rod = system.rod
        w = rod.density * rod.area * g
        expected = w * rod.length**4 / (8 * rod.bending_stiffness)
        q = system.static_equilibrium()
        deflection = -system.tip_pose(q)[2, 3]
        errors.append(abs(deflection - expected) / expected)
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] > 0.05
    assert errors[2] < 1e-4  # geometric nonlinearity at this load is ~1e-5


def elastica_tip(load, ei, length):
    """Tip of a cantilever under a vertical dead load at its tip (Bisshopp and Drucker's problem),
    solved as the boundary-value problem th'' = -(P/EI) cos th, th(0) = 0, th'(L) = 0."""

    def rhs(s, y):
        th, k, x, z = y
        return np.vstack([k, -(load / ei) * np.cos(th), np.cos(th), -np.sin(th)])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    s = np.linspace(0, length, 201)
    guess = np.zeros((4, s.size))
    guess[2] = s
    sol = solve_bvp(rhs, bc, s, guess, tol=1e-10, max_nodes=100000)
    assert sol.success
    return sol.sol(length)[2], sol.sol(length)[3]


def test_large_deflection_under_tip_dead_load_matches_elastica():
    system = horizontal_cantilever(tdacm.StrainBasis.bending(6), n_gauss=16)
    system.loads.gravity = np.zeros(3)
    ei = system.rod.bending_stiffness
    load = 2.0 * ei  # P L^2 / EI = 2: the tip drops by about half the length
    system.loads.tip_force = np.array([0, 0, -load])
    q = system.static_equilibrium(load_steps=4)
    x_ref, z_ref = elastica_tip(load, ei, 1.0)
    tip = system.tip_pose(q)[:3, 3]
    assert z_ref < -0.4
    assert abs(tip[0] - x_ref) < 1e-6 and abs(tip[2] - z_ref) < 1e-6
