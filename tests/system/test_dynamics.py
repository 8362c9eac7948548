"""Mass matrix, Coriolis matrix, forces and conservation laws of the coupled model."""

import numpy as np
import pytest

import tdacm
from tdacm.system import kernels as K

from .conftest import random_state


@pytest.mark.parametrize("which", ["paper", "rich"])
def test_mass_matrix_symmetric_positive_definite(which, request):
    system = request.getfixturevalue(which)
    for seed in range(3):
        q, qd = random_state(system, seed)
        m = system.terms(q, qd).M
        assert np.allclose(m, m.T, atol=1e-15)
        assert np.linalg.eigvalsh(m).min() > 0


@pytest.mark.parametrize("which", ["paper", "rich"])
def test_mdot_minus_2c_is_skew_symmetric(which, request):
    system = request.getfixturevalue(which)
    q, qd = random_state(system, seed=11)
    h = 1e-6
    mdot = (system.terms(q + h * qd, qd).M - system.terms(q - h * qd, qd).M) / (2 * h)
    n = mdot - 2 * system.terms(q, qd).C
    assert np.abs(n).max() > 1e-3  # not trivially zero
    assert np.allclose(n + n.T, 0.0, atol=1e-8)


@pytest.mark.parametrize("which", ["paper", "rich"])
def test_coriolis_matches_lagrangian(which, request):
    """C qdot = Mdot qdot - dT/dq with T = 1/2 qdot^T M(q) qdot (Euler-Lagrange)."""
    system = request.getfixturevalue(which)
    q, qd = random_state(system, seed=4)
    h = 1e-6
    mdot = (system.terms(q + h * qd, qd).M - system.terms(q - h * qd, qd).M) / (2 * h)
    dtdq = np.zeros(system.n)
    for i in range(system.n):
        dq = np.zeros(system.n)
        dq[i] = h
        dtdq[i] = (system.energy(q + dq, qd)["kinetic"] - system.energy(q - dq, qd)["kinetic"]) / (
            2 * h
        )
    expected = mdot @ qd - dtdq
    got = system.terms(q, qd).C @ qd
    assert np.allclose(got, expected, atol=1e-7 * max(1.0, np.abs(expected).max()))


@pytest.mark.parametrize("which", ["paper", "rich"])
def test_conservative_forces_are_energy_gradients(which, request):
    """tau_ext (gravity, dead loads) = -dV/dq and K(q) = dV_el/dq."""
    system = request.getfixturevalue(which)
    system.loads.tip_force = np.array([0.3, -0.2, 0.1])
    system.loads.rod_force = np.array([0.05, 0.1, 0.0])
    try:
        q, qd = random_state(system, seed=8)
        h = 1e-6
        grad = np.zeros(system.n)
        for i in range(system.n):
            dq = np.zeros(system.n)
            dq[i] = h
            e_p, e_m = system.energy(q + dq, qd), system.energy(q - dq, qd)
            grad[i] = ((e_p["gravity"] + e_p["loads"]) - (e_m["gravity"] + e_m["loads"])) / (2 * h)
        t = system.terms(q, qd)
        assert np.allclose(t.tau_ext, -grad, atol=1e-7)
        assert np.allclose(t.K, system.model_arrays.stiffness @ q)
    finally:
        system.loads.tip_force = np.zeros(3)
        system.loads.rod_force = np.zeros(3)


def test_energy_is_conserved_without_damping_and_inputs():
    system = tdacm.paper_system(damping=0.0)
    q0 = np.array([0.1, -0.05, 0.3, 0.0, 0.0, 5.0, 0.8, -0.6])
    qd0 = np.array([0.5, -0.3, 0.2, 0.1, 0.2, 0.0, 1.0, -2.0])
    res = tdacm.simulate(system, q0, qd0, duration=5.0, dt=1e-3, record_dt=0.1)
    e = np.array([system.energy(q, qd)["total"] for q, qd in zip(res.q, res.qd, strict=True)])
    ke = np.array([system.energy(q, qd)["kinetic"] for q, qd in zip(res.q, res.qd, strict=True)])
    assert res.completed
    assert ke.max() > 10.0  # it free-falls: a real exchange of energy happens
    assert np.abs(e - e[0]).max() < 1e-6 * ke.max()


def test_damping_dissipates_energy():
    system = tdacm.paper_system(damping=1e5, fixed_base_pose=np.eye(4))
    res = tdacm.simulate(system, [0.5, -0.5], [0.0, 0.0], duration=1.0, dt=1e-3, record_dt=0.05)
    e = np.array([system.energy(q, qd)["total"] for q, qd in zip(res.q, res.qd, strict=True)])
    assert np.all(np.diff(e) <= 1e-12)
    assert e[-1] < e[0]


def test_linear_momentum_conserved_with_tendon_forces_only():
    loads = tdacm.Loads(gravity=np.zeros(3))
    system = tdacm.paper_system(damping=0.0, loads=loads)
    q0 = np.zeros(8)
    q0[5] = 3.0
    qd0 = np.array([0.2, 0.1, -0.3, 0.4, -0.2, 0.1, 0.5, 0.0])
    u = np.array([0, 0, 0, 0, 2.0, 0.0, 0.0, 1.0])  # tendons 0 and 3 pulled, motors off
    res = tdacm.simulate(system, q0, qd0, duration=2.0, dt=1e-3, u=u, record_dt=0.1)
    p = np.array([system.momentum(q, qd) for q, qd in zip(res.q, res.qd, strict=True)])
    assert np.abs(res.q[:, 6:] - q0[6:]).max() > 0.3  # the rod really bends
    assert np.abs(p - p[0]).max() < 1e-8 * max(1.0, np.abs(p[0]).max())


def test_hover_keeps_hanging_rod_at_rest(paper):
    q0 = np.zeros(8)
    q0[5] = 3.0
    u = np.r_[np.full(4, paper.total_mass * 9.81 / 4), np.zeros(4)]
    assert np.abs(paper.forward_dynamics(q0, np.zeros(8), u)).max() < 1e-12
    res = tdacm.simulate(paper, q0, np.zeros(8), duration=2.0, dt=5e-3, u=u)
    assert np.abs(res.q[-1] - q0).max() < 1e-10


def test_kernel_forward_dynamics_is_consistent_with_terms(rich):
    q, qd = random_state(rich, seed=9)
    u = np.r_[np.full(4, 3.0), [1.0, 0.0, 2.0, 0.5]]
    t = rich.terms(q, qd)
    qdd = np.linalg.solve(t.M, t.B @ u + t.tau_ext - (t.C + t.D) @ qd - t.K)
    assert np.allclose(rich.forward_dynamics(q, qd, u), qdd, atol=1e-9)
    _, _, cqd, _, _, _, _ = K.coupled_terms(q, qd, rich.model_arrays, rich.loads.packed(), False)
    assert np.allclose(cqd, t.C @ qd, atol=1e-12)


def test_adaptive_and_rk4_agree(paper):
    q0 = np.array([0, 0, 0, 0, 0, 3.0, 0.5, -0.4])
    u = np.r_[np.full(4, paper.total_mass * 9.81 / 4), [1.0, 0, 0, 0]]
    a = tdacm.simulate(paper, q0, None, duration=1.0, dt=1e-3, u=u, record_dt=0.1)
    b = tdacm.simulate(paper, q0, None, duration=1.0, u=u, method="adaptive", record_dt=0.1)
    assert np.allclose(a.q, b.q, atol=1e-7)
