"""Strain bases and tendon actuation."""

import numpy as np
import pytest

import tdacm


def test_basis_shapes_and_orthogonality():
    b = tdacm.StrainBasis.from_modes({"torsion": 1, "bending_y": 3, "shear_z": 0})
    assert b.n == 2 + 4 + 1
    x, w = np.polynomial.legendre.leggauss(10)
    vals = b(0.5 * (x + 1))  # (10, 6, n)
    assert vals.shape == (10, 6, b.n)
    # Legendre columns of one mode are orthogonal on [0, 1]
    by = vals[:, 1, 2:6]
    gram = (0.5 * w[:, None, None] * by[:, :, None] * by[:, None, :]).sum(0)
    assert np.allclose(gram - np.diag(np.diag(gram)), 0, atol=1e-14)
    mono = tdacm.StrainBasis.from_modes({"bending_z": 2}, kind="monomial")
    assert np.allclose(mono(0.5)[2], [1, 0.5, 0.25])
    with pytest.raises(ValueError, match="X must lie"):
        b(1.5)
    with pytest.raises(ValueError, match="unknown strain mode"):
        tdacm.StrainBasis.from_modes({"twist": 1})


def helical_tendons(radius=0.01, turns=0.5):
    """Two tendons spiralling half a turn around the rod: non-parallel routing (d' != 0)."""

    def offset(x):
        a = 2 * np.pi * turns * x
        return np.array(
            [
                [0, radius * np.cos(a), radius * np.sin(a)],
                [0, -radius * np.cos(a), -radius * np.sin(a)],
            ]
        )

    return tdacm.Tendons(offset_function=offset)


@pytest.mark.parametrize("tendons", [tdacm.Tendons.parallel(0.01), helical_tendons()])
def test_tendon_matrix_is_minus_length_gradient(tendons):
    rod = tdacm.Rod(basis=tdacm.StrainBasis.full(1), n_gauss=6)
    system = tdacm.TDACM(rod, tendons, tdacm.FixedBase())
    rng = np.random.default_rng(2)
    q = rng.normal(size=system.n) * 0.2
    h = 1e-6
    grad = np.array(
        [
            (system.tendon_lengths(q + h * e) - system.tendon_lengths(q - h * e)) / (2 * h)
            for e in np.eye(system.n)
        ]
    )
    assert np.allclose(system.tendon_matrix(q), -grad, atol=1e-9)
    # a straight, unstretched rod: every tendon as long as the rod (parallel) or longer (helix)
    lengths = system.tendon_lengths(np.zeros(system.n))
    assert np.all(lengths >= rod.length - 1e-12)


def test_tensions_pull_and_statics_hold_the_drone():
    """With the drone held, tendon 1 (+z offset) bends the rod toward +z of its section."""
    system = tdacm.paper_system()
    system.loads.gravity = np.zeros(3)
    base_q = [0.1, -0.05, 0.3, 1.0, 2.0, 3.0]
    q = system.static_equilibrium([0, 0, 0, 0, 0, 1.5, 0, 0], base_q=base_q)
    assert np.allclose(q[:6], base_q)
    assert np.isclose(q[6], -1.5 * 0.01 / system.rod.bending_stiffness, rtol=1e-9)
    assert abs(q[7]) < 1e-12
