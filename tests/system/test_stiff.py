"""The stiff integrators (Rosenbrock-W, Radau IIA in mass-matrix form) for stiff strain
bases."""

import numpy as np
import pytest

import tdacm
from tdacm.system import kernels as K
from tdacm.system.integrate import is_stiff


@pytest.fixture(scope="module")
def rod18():
    """The 18-DoF rod of ``tdacm bench``: torsion + 2 bendings of order 3, 8 Gauss points,
    Magnus order 4, on the floating base."""
    return tdacm.paper_system(
        basis=tdacm.StrainBasis((3, 3, 3, None, None, None)), n_gauss=8, magnus_order=4
    )


def released_state(system):
    """Rod held in equilibrium by tendons 0 and 1 (2 N, 1 N) below a held drone at 3 m."""
    q0 = np.zeros(system.n)
    q0[5] = 3.0
    u = np.zeros(system.n_u)
    u[4:6] = [2.0, 1.0]
    return system.static_equilibrium(u, q0=q0, load_steps=4)


def test_auto_method_picks_a_stiff_integrator_only_for_stiff_bases(rod18):
    assert is_stiff(rod18)
    assert not is_stiff(tdacm.paper_system())
    assert not is_stiff(tdacm.paper_system(basis=tdacm.StrainBasis.bending(7)))


@pytest.fixture(scope="module")
def released18(rod18):
    """The released 18-DoF rod and its DOP853 reference (rtol 1e-10) over 0.1 s."""
    q0 = released_state(rod18)
    u = np.r_[np.full(4, rod18.total_mass * 9.81 / 4), np.zeros(rod18.n_a)]
    ref = tdacm.simulate(
        rod18, q0, None, 0.1, u=u, method="adaptive", rtol=1e-10, atol=1e-12, record_dt=0.05
    )
    assert ref.completed
    return q0, u, np.array([rod18.tip_pose(q)[:3, 3] for q in ref.q])


# ~40 s each: slow. The default suite keeps Radau against DOP853 on this rod
# (test_radau_converges_to_dop853_with_the_step) and Rosenbrock's order on the paper system.
@pytest.mark.slow
@pytest.mark.parametrize("method", ["auto", "rosenbrock"])  # auto -> radau (10 ms steps)
def test_stiff_integrators_match_dop853_on_the_18_dof_rod(rod18, released18, method):
    q0, u, tref = released18
    res = tdacm.simulate(rod18, q0, None, 0.1, u=u, method=method, record_dt=0.05)
    assert res.completed and res.q.shape[0] == tref.shape[0]
    tip = np.array([rod18.tip_pose(q)[:3, 3] for q in res.q])
    assert np.abs(tref - tref[0]).max() > 2e-3  # the released rod really swings
    assert np.abs(tip - tref).max() < 1e-4


def test_rosenbrock_is_third_order_on_the_paper_system():
    system = tdacm.paper_system()
    q0 = np.zeros(8)
    q0[5] = 3.0
    q0[6:] = [0.3, -0.2]
    qd0 = np.r_[np.full(6, 0.1), 0.0, 0.0]
    u = np.r_[np.full(4, system.total_mass * 9.81 / 4), np.zeros(4)]
    ref = tdacm.simulate(system, q0, qd0, 1.0, dt=1e-3, u=u, method="rk4").q[-1]
    errs = [
        np.abs(
            tdacm.simulate(system, q0, qd0, 1.0, dt=h, u=u, method="rosenbrock").q[-1] - ref
        ).max()
        for h in (0.02, 0.01)
    ]
    assert 2.7 < np.log2(errs[0] / errs[1]) < 3.3


def test_rosenbrock_adaptive_and_callable_inputs():
    system = tdacm.paper_system(fixed_base_pose=np.eye(4), basis=tdacm.StrainBasis.full(0))
    assert is_stiff(system)
    q0 = np.zeros(system.n)
    q0[1:3] = [0.5, -0.3]
    ad = tdacm.simulate(system, q0, None, 0.2, dt=5e-3, method="rosenbrock", rtol=1e-4, atol=1e-7)
    fx = tdacm.simulate(system, q0, None, 0.2, dt=1e-3, method="rosenbrock", record_dt=5e-3)
    assert ad.completed and fx.completed and ad.q.shape == fx.q.shape
    assert np.abs(ad.q[:, 1:3] - fx.q[:, 1:3]).max() < 1e-3
    cb = tdacm.simulate(
        system,
        q0,
        None,
        0.2,
        dt=1e-3,
        method="rosenbrock",
        record_dt=5e-3,
        u=lambda t, q, qd: np.zeros(4),
    )
    assert np.allclose(cb.q, fx.q, atol=1e-12)
    with pytest.raises(ValueError, match="multiple"):
        tdacm.simulate(system, q0, None, 0.2, dt=2e-3, method="rosenbrock", record_dt=5e-3)
    with pytest.raises(ValueError, match="method must be"):
        tdacm.simulate(system, q0, None, 0.2, method="euler")


def test_radau_on_a_clamped_stiff_rod_with_callable_inputs():
    system = tdacm.paper_system(fixed_base_pose=np.eye(4), basis=tdacm.StrainBasis.full(0))
    q0 = np.zeros(system.n)
    q0[1:3] = [0.5, -0.3]
    const = tdacm.simulate(system, q0, None, 0.2, record_dt=0.02)  # auto -> radau
    fine = tdacm.simulate(system, q0, None, 0.2, method="rosenbrock", dt=2.5e-4, record_dt=0.02)
    cb = tdacm.simulate(system, q0, None, 0.2, record_dt=0.02, u=lambda t, q, qd: np.zeros(4))
    assert const.completed and cb.completed
    # the held-input path restarts the iteration every interval (fresh Jacobian, no
    # extrapolated start): the two agree to the Newton tolerance, not bit for bit
    assert np.allclose(cb.q, const.q, atol=1e-5)
    assert np.abs(const.q[:, 1:3] - fine.q[:, 1:3]).max() < 1e-3


def test_radau_converges_to_dop853_with_the_step(rod18, released18):
    """The mass-matrix Radau scheme is a convergent order-5 method, not only a damped
    approximation: at 2.5 ms the tip follows DOP853 to 1e-5 m; at the default 10 ms to 1e-4 m
    (above), the difference being the damped torsion transient."""
    q0, u, tref = released18
    res = tdacm.simulate(rod18, q0, None, 0.1, u=u, method="radau", dt=2.5e-3, record_dt=0.05)
    tip = np.array([rod18.tip_pose(q)[:3, 3] for q in res.q])
    assert res.completed and np.abs(tip - tref).max() < 1e-5


def test_radau_dense_output_and_error_control(rod18, released18):
    q0, u, tref = released18
    coarse = tdacm.simulate(rod18, q0, None, 0.1, u=u, method="radau", record_dt=0.01)
    dense = tdacm.simulate(rod18, q0, None, 0.1, u=u, method="radau", record_dt=0.0025)
    # the same 10 ms steps: at the step ends the collocation polynomial is the step's state
    assert dense.q.shape[0] == 41 and np.allclose(dense.t[::4], coarse.t)
    assert np.allclose(dense.q[::4], coarse.q, rtol=0, atol=1e-12)
    assert np.allclose(dense.qd[::4], coarse.qd, rtol=0, atol=1e-9)
    # between them it interpolates: the tip stays on the DOP853 path at 0.05 s
    tip = rod18.tip_pose(dense.q[20])[:3, 3]
    assert np.abs(tip - tref[1]).max() < 1e-4
    ad = tdacm.simulate(
        rod18, q0, None, 0.1, u=u, method="radau", rtol=1e-4, atol=1e-6, record_dt=0.05
    )
    tip = np.array([rod18.tip_pose(q)[:3, 3] for q in ad.q])
    assert ad.completed and np.abs(tip - tref).max() < 1e-4


def test_radau_on_shear_and_extension_against_resolved_rk4():
    """A clamped rod with all six strains (constant basis: shear and extension modes up to
    27,000 rad/s in the bent state): Radau at 10 ms against RK4 at a stable 38 us step."""
    system = tdacm.paper_system(fixed_base_pose=np.eye(4), basis=tdacm.StrainBasis.full(0))
    q0 = np.zeros(system.n)
    q0[1:3] = [0.5, -0.3]
    every = 264  # 10 ms / 264 = 38 us, 1.0 / w_max in the bent state
    ref, _, ok = K.rk4_run(
        q0,
        np.zeros(system.n),
        np.zeros(system.n_u),
        0.01 / every,
        10 * every,
        every,
        system.model_arrays,
        system.loads.packed(),
    )
    assert ok
    res = tdacm.simulate(system, q0, None, 0.1, method="radau", record_dt=0.01)
    tip = np.array([system.tip_pose(q)[:3, 3] for q in res.q])
    tref = np.array([system.tip_pose(q)[:3, 3] for q in ref])
    assert np.abs(tref - tref[0]).max() > 0.02
    assert res.completed and np.abs(tip - tref).max() < 1e-5


def test_radau_dissipates_and_never_creates_energy():
    """Undamped, gravity-free 18-DoF rod released from a tendon-bent equilibrium: the L-stable
    scheme damps the unresolved torsion and high bending modes (about 8 % of the energy at
    10 ms, docs/benchmarks.md) and never adds energy beyond 0.1 % of the initial value."""
    system = tdacm.paper_system(
        basis=tdacm.StrainBasis((3, 3, 3, None, None, None)),
        n_gauss=8,
        magnus_order=4,
        damping=0.0,
        loads=tdacm.Loads(gravity=(0.0, 0.0, 0.0)),
    )
    q0 = released_state(system)
    res = tdacm.simulate(system, q0, None, 1.0, u=np.zeros(system.n_u), record_dt=0.05)
    e = np.array([system.energy(a, b)["total"] for a, b in zip(res.q, res.qd, strict=True)])
    assert res.completed and e[0] > 0
    assert e[-1] < e[0] and -0.1 < (e[-1] - e[0]) / e[0]
    assert (e - np.minimum.accumulate(e)).max() < 1e-3 * e[0]


def test_suggested_dt_over_the_configurations_of_a_run():
    """A clamped six-strain rod: its highest mode rises when bent, so the step suggested for
    the straight rod is too large; ``q`` (one configuration or several) takes that into
    account (the step is the one for the highest frequency over them)."""
    system = tdacm.paper_system(fixed_base_pose=np.eye(4), basis=tdacm.StrainBasis.full(0))
    bent = np.zeros(system.n)
    bent[1:3] = [0.5, -0.3]
    straight = system.suggested_dt()
    at_bent = system.suggested_dt(q=bent)
    w_bent = system.natural_frequencies(bent).max()
    assert at_bent == pytest.approx(1.5 / w_bent) and at_bent < 0.6 * straight
    assert system.suggested_dt(q=[np.zeros(system.n), bent]) == at_bent
