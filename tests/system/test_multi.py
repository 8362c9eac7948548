"""Multi-section rods, tendons ending part-way, several rods on one drone."""

import numpy as np
import pytest

import tdacm
from tdacm.lie.se3 import inv_se3, vee


def two_section_cantilever(gravity=(0.0, 0.0, 0.0), damping=0.0, ends=0.4):
    """Clamped along inertial +x: a 0.4 m section (order-2 bending) then a stiffer 0.6 m one
    (order-1 bending, thicker), tendon 0 on +y ending at ``ends``."""
    s1 = tdacm.Rod(length=0.4, diameter=2e-3, damping=damping, basis=tdacm.StrainBasis.bending(2))
    s2 = tdacm.Rod(
        length=0.6,
        diameter=2.5e-3,
        youngs_modulus=7e10,
        damping=damping,
        basis=tdacm.StrainBasis.bending(1),
        tip_mass=0.005,
    )
    rod = tdacm.SectionedRod([s1, s2])
    tendons = tdacm.Tendons(offsets=[[0.0, 0.01, 0.0], [0.0, 0.0, 0.01]], ends=[ends, None])
    return tdacm.TDACM(
        rod,
        tendons,
        tdacm.FixedBase(),
        attachment=np.eye(4),
        loads=tdacm.Loads(gravity=gravity),
    )


@pytest.fixture(scope="module")
def sectioned_floating():
    s1 = tdacm.Rod(length=0.5, basis=tdacm.StrainBasis.bending(1), tip_mass=0.003)
    s2 = tdacm.Rod(
        length=0.5, diameter=1.5e-3, basis=tdacm.StrainBasis((1, 1, 1, None, None, None))
    )
    tendons = tdacm.Tendons.parallel(0.01, count=4, ends=[0.5, 0.5, None, 0.8])
    return tdacm.TDACM(tdacm.SectionedRod([s1, s2]), tendons, tdacm.Quadrotor())


@pytest.fixture(scope="module")
def dual():
    return tdacm.dual_paper_system(basis=tdacm.StrainBasis.bending(1))


def state(system, seed, scale=0.4):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=system.n) * scale
    qd = rng.normal(size=system.n)
    if system.floating:
        q[3:6] += [0.2, -0.1, 3.0]
    return q, qd


def fd_jacobian(system, q, s, rod, eps=1e-6):
    g0 = system.pose(q, s, rod)
    j = np.zeros((6, system.n))
    for i in range(system.n):
        dq = np.zeros(system.n)
        dq[i] = eps
        dg = system.pose(q + dq, s, rod) - system.pose(q - dq, s, rod)
        j[:, i] = vee(inv_se3(g0) @ dg / (2 * eps))
    return j


def test_tendon_ending_at_first_section_gives_exact_arc_and_straight_second_section():
    system = two_section_cantilever()
    tension, r = 1.5, 0.01
    q = system.static_equilibrium(np.array([tension, 0.0]))
    sec1 = system.arms[0].rod.sections[0]
    k = tension * r / sec1.bending_stiffness
    for s in np.linspace(0.0, 0.4, 9):
        xi = system.strain(q, s)
        assert np.allclose(xi, [0, 0, k, 1, 0, 0], rtol=1e-10, atol=1e-12)
    for s in np.linspace(0.41, 1.0, 7):
        assert np.allclose(system.strain(q, s), [0, 0, 0, 1, 0, 0], atol=1e-12)
    # the tip: arc of radius 1/k over 0.4 m, then a straight 0.6 m along the arc's end tangent
    th = k * 0.4
    p1 = np.array([np.sin(th), 1 - np.cos(th), 0.0]) / k
    tip = p1 + 0.6 * np.array([np.cos(th), np.sin(th), 0.0])
    assert np.allclose(system.tip_pose(q)[:3, 3], tip, atol=1e-12)
    assert np.allclose(system.backbone(q, 11)[-1], system.tip_pose(q), atol=1e-12)


def test_tendon_ending_mid_section_acts_only_before_its_end():
    system = two_section_cantilever(ends=0.7)  # inside the second section
    q = system.static_equilibrium(np.array([1.0, 0.0]))
    sec2 = system.arms[0].rod.sections[1]
    k2 = 0.01 / sec2.bending_stiffness
    # section 1 carries the full tendon moment; section 2 (order-1 basis) bends where the tendon
    # runs and relaxes after its end
    assert (
        abs(system.strain(q, 0.2)[2] - 0.01 / system.arms[0].rod.sections[0].bending_stiffness)
        < 1e-10
    )
    assert system.strain(q, 0.55)[2] > 0.5 * k2
    # tendon lengths: B_s = -dl/dq, and the tendon ending at 0.7 m is 0.7 m long when straight
    assert np.allclose(system.tendon_lengths(np.zeros(system.n)), [0.7, 1.0], atol=1e-14)
    q1 = np.random.default_rng(0).normal(size=system.n) * 0.3
    eps = 1e-6
    grad = np.array(
        [
            (system.tendon_lengths(q1 + eps * e) - system.tendon_lengths(q1 - eps * e)) / (2 * eps)
            for e in np.eye(system.n)
        ]
    )
    assert np.allclose(system.tendon_matrix(q1), -grad, atol=1e-8)


@pytest.mark.parametrize("which", ["sectioned_floating", "dual"])
def test_jacobians_match_finite_differences(which, request):
    system = request.getfixturevalue(which)
    q, qd = state(system, 3)
    for rod in range(system.n_rods):
        length = system.arms[rod].length
        for s in (0.0, 0.31 * length, 0.5 * length, 0.77 * length, length):
            assert np.allclose(
                system.jacobian(q, s, rod), fd_jacobian(system, q, s, rod), atol=1e-8
            )
        h = 1e-6
        fd = (system.tip_jacobian(q + h * qd, rod) - system.tip_jacobian(q - h * qd, rod)) / (2 * h)
        assert np.allclose(system.tip_jacobian_dot(q, qd, rod), fd, atol=1e-7)
    if system.n_rods == 2:
        # rod 1's pose does not depend on rod 0's strains and vice versa
        j0 = system.tip_jacobian(q, 0)
        j1 = system.tip_jacobian(q, 1)
        assert np.all(j0[:, system.arms[1].strains] == 0.0)
        assert np.all(j1[:, system.arms[0].strains] == 0.0)


@pytest.mark.parametrize("which", ["sectioned_floating", "dual"])
def test_mdot_minus_2c_is_skew_and_forces_are_energy_gradients(which, request):
    system = request.getfixturevalue(which)
    q, qd = state(system, 11)
    h = 1e-6
    mdot = (system.terms(q + h * qd, qd).M - system.terms(q - h * qd, qd).M) / (2 * h)
    n = mdot - 2 * system.terms(q, qd).C
    assert np.abs(n).max() > 1e-3
    assert np.allclose(n + n.T, 0.0, atol=1e-8)
    # gravity + elastic forces are minus the gradient of the potential energy
    t = system.terms(q, qd)
    grad = np.array(
        [
            (system.energy(q + h * e, qd)["potential"] - system.energy(q - h * e, qd)["potential"])
            / (2 * h)
            for e in np.eye(system.n)
        ]
    )
    assert np.allclose(t.tau_ext - t.K, -grad, atol=1e-6)


def test_undamped_two_rod_system_in_free_fall_conserves_energy():
    system = tdacm.dual_paper_system(damping=0.0)
    q0 = np.zeros(system.n)
    q0[:6] = [0.1, -0.05, 0.3, 0.0, 0.0, 5.0]
    q0[6:] = [0.8, -0.6, -0.4, 0.5]
    qd0 = np.zeros(system.n)
    qd0[:6] = [0.5, -0.3, 0.2, 0.1, 0.2, 0.0]
    qd0[6:] = [1.0, -2.0, 0.5, 1.5]
    res = tdacm.simulate(system, q0, qd0, duration=2.0, dt=1e-3, record_dt=0.1)
    e = np.array([system.energy(q, qd)["total"] for q, qd in zip(res.q, res.qd, strict=True)])
    ke = np.array([system.energy(q, qd)["kinetic"] for q, qd in zip(res.q, res.qd, strict=True)])
    assert res.completed
    assert ke.max() > 1.0
    assert np.abs(e - e[0]).max() < 1e-6 * ke.max()


def test_two_rods_with_internal_tendon_forces_conserve_linear_momentum():
    system = tdacm.dual_paper_system(damping=0.0, loads=tdacm.Loads(gravity=np.zeros(3)))
    q0 = np.zeros(system.n)
    q0[5] = 3.0
    qd0 = np.array([0.2, 0.1, -0.3, 0.4, -0.2, 0.1, 0.5, 0.0, -0.3, 0.2])
    u = np.zeros(system.n_u)
    u[4] = 2.0  # rod 0, tendon 0
    u[4 + 4 + 3] = 1.0  # rod 1, tendon 3
    res = tdacm.simulate(system, q0, qd0, duration=1.0, dt=1e-3, u=u, record_dt=0.1)
    p = np.array([system.momentum(q, qd) for q, qd in zip(res.q, res.qd, strict=True)])
    assert np.abs(res.q[:, 6:8]).max() > 0.3 and np.abs(res.q[:, 8:]).max() > 0.1
    assert np.abs(p - p[0]).max() < 1e-8 * max(1.0, np.abs(p[0]).max())


def test_dual_system_layout_and_single_rod_views():
    system = tdacm.dual_paper_system()
    assert (system.n, system.n_s, system.n_a, system.n_u, system.n_rods) == (10, 4, 8, 12, 2)
    assert system.arms[0].strains == slice(6, 8) and system.arms[1].tensions == slice(8, 12)
    q = np.zeros(10)
    q[5] = 3.0
    t0, t1 = system.tip_pose(q, 0)[:3, 3], system.tip_pose(q, 1)[:3, 3]
    assert np.allclose(t0, [0.15, 0.0, 1.9]) and np.allclose(t1, [-0.15, 0.0, 1.9])
    with pytest.raises(AttributeError, match="2 rods"):
        _ = system.rod
    with pytest.raises(ValueError, match="rod must be an index"):
        system.tip_pose(q, 2)
    assert "rod 1" in system.summary()


def test_constructor_validation():
    with pytest.raises(ValueError, match="one per rod"):
        tdacm.TDACM([tdacm.Rod(), tdacm.Rod()], attachment=np.eye(4))
    with pytest.raises(ValueError, match="beyond the rod length"):
        tdacm.TDACM(tdacm.Rod(length=0.5), tdacm.Tendons.parallel(ends=[0.6] * 4))
    with pytest.raises(ValueError, match="same magnus_order"):
        tdacm.SectionedRod([tdacm.Rod(), tdacm.Rod(magnus_order=2)])
    with pytest.raises(ValueError, match="at least 9 Gauss points"):
        tdacm.Rod(basis=tdacm.StrainBasis.bending(7), n_gauss=8)
    with pytest.raises(ValueError, match="legendre"):
        tdacm.StrainBasis.bending(7, kind="monomial")
    with pytest.warns(UserWarning, match="magnus_order=4"):
        tdacm.Rod(basis=tdacm.StrainBasis.bending(2), magnus_order=2)
    rod = tdacm.Rod(basis=tdacm.StrainBasis.bending(7))
    assert (rod.n_gauss, rod.magnus_order) == (16, 4)
    rich = tdacm.paper_system(basis=tdacm.StrainBasis.bending(3))
    assert (rich.rod.n_gauss, rich.rod.magnus_order) == (8, 4)
    paper = tdacm.paper_system()
    assert (paper.rod.n_gauss, paper.rod.magnus_order) == (5, 2)
