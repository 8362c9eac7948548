"""The constant-curvature Lagrangian baseline: derivation, code cache, and coherence with the
GVS model (bending-only order-0 basis, the paper's system).

Both models describe the same mechanics: a drone plus a constant-curvature rod whose kinetic
energy (translational and rotational section inertia) and gravity are integrated with the same
five Gauss-Legendre sections, plus a tip point mass.  The baseline's distributed gravity is
therefore the same quadrature as the GVS model's ``int J^T Wbar ds`` and agrees to rounding; a
closed-form integral of the rod's weight along the arc would differ from both by the 5-point
quadrature error (1e-14 relative for this system, see :func:`tdacm.paper_system`).  What cannot
agree entry by entry is the Coriolis matrix itself: ``C`` is not unique, the baseline's is the
Christoffel one, the GVS one is ``J^T (Mbar Jdot + coad(eta) Mbar J)``.  Both give the same
``C qdot`` and both make ``Mdot - 2C`` skew-symmetric, which is what is tested.
"""

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import tdacm
from tdacm.baselines import CCLagrangian, rk4_simulate
from tdacm.baselines.stumpff import NUMERIC, stumpff_all

from .conftest import random_state

TOL = 1e-12  # relative to the largest entry


def _close(a, b, tol=TOL):
    scale = max(np.abs(a).max(), np.abs(b).max(), 1e-300)
    return np.abs(a - b).max() <= tol * scale


def test_stumpff_functions_match_closed_forms_and_series():
    for z in (0.0, 1e-12, 1e-4, 0.3, 3.999, 4.0, 4.001, 25.0, 400.0):
        c = stumpff_all(z)
        th = np.sqrt(z)
        if z > 1e-3:
            assert np.isclose(c[0], np.cos(th), rtol=1e-14, atol=1e-15)
            assert np.isclose(c[1], np.sin(th) / th, rtol=1e-13, atol=1e-15)
            assert np.isclose(c[2], (1 - np.cos(th)) / z, rtol=1e-12, atol=1e-15)
            assert np.isclose(c[3], (th - np.sin(th)) / th**3, rtol=1e-9, atol=1e-15)
        # identity c_k = 1/k! - z c_{k+2}
        fact = np.cumprod([1.0, *range(1, 12)])
        for k in range(8):
            assert np.isclose(c[k], 1 / fact[k] - z * c[k + 2], rtol=1e-12, atol=1e-14)
    assert [NUMERIC[k](0.0) for k in range(4)] == [1.0, 1.0, 0.5, 1.0 / 6.0]


@pytest.mark.parametrize("floating", [False, True])
def test_terms_agree_with_gvs(floating, request):
    gvs = request.getfixturevalue("gvs_floating" if floating else "gvs_fixed")
    cc = request.getfixturevalue("cc_floating" if floating else "cc_fixed")
    for seed in range(4):
        q, qd = random_state(gvs.n, seed)
        a, b = gvs.terms(q, qd), cc.terms(q, qd)
        assert _close(a.M, b.M)
        assert _close(a.C @ qd, b.C @ qd)
        assert _close(a.tau_ext, b.tau_ext)  # gravity (same 5-point quadrature)
        assert _close(a.K, b.K)  # elastic force
        assert _close(a.D, b.D)
        assert _close(a.B, b.B)
        ea, eb = gvs.energy(q, qd), cc.energy(q, qd)
        for key in ("kinetic", "gravity", "elastic", "total"):
            assert np.isclose(ea[key], eb[key], rtol=1e-12, atol=1e-14)
        assert np.allclose(gvs.tip_pose(q), cc.tip_pose(q), atol=1e-14)


def test_gravity_and_kinetic_energy_consistent_with_derivation(cc_floating):
    """``G = dV/dq`` and ``T = 1/2 qd^T M qd`` at a random state (finite differences)."""
    q, qd = random_state(8, 3)
    e = cc_floating.energy(q, qd)
    m = cc_floating.terms(q, qd).M
    assert np.isclose(e["kinetic"], 0.5 * qd @ m @ qd, rtol=1e-13)
    h = 1e-6
    grad = np.array(
        [
            (
                cc_floating.energy(q + h * ei, qd)["gravity"]
                - cc_floating.energy(q - h * ei, qd)["gravity"]
            )
            / (2 * h)
            for ei in np.eye(8)
        ]
    )
    assert np.allclose(grad, cc_floating.gravity_force(q), atol=1e-7)


def test_tip_load_agrees_with_gvs(gvs_fixed, cc_fixed):
    old = gvs_fixed.loads.tip_force.copy()
    try:
        gvs_fixed.loads.tip_force = np.array([0.05, -0.02, -0.1])
        q, qd = random_state(2, 7)
        assert _close(gvs_fixed.terms(q, qd).tau_ext, cc_fixed.terms(q, qd).tau_ext)
        assert np.isclose(gvs_fixed.energy(q, qd)["loads"], cc_fixed.energy(q, qd)["loads"])
    finally:
        gvs_fixed.loads.tip_force = old


@pytest.mark.parametrize("floating", [False, True])
def test_zero_curvature_is_finite_and_agrees(floating, request):
    gvs = request.getfixturevalue("gvs_floating" if floating else "gvs_fixed")
    cc = request.getfixturevalue("cc_floating" if floating else "cc_fixed")
    q, qd = random_state(gvs.n, 5)
    for ks in ([0.0, 0.0], [0.0, 0.7], [-0.4, 0.0], [1e-9, -1e-9]):
        q[-2:] = ks
        b = cc.terms(q, qd)
        for arr in (b.M, b.C, b.tau_ext, b.B):
            assert np.all(np.isfinite(arr))
        a = gvs.terms(q, qd)
        assert _close(a.M, b.M)
        assert _close(a.C @ qd, b.C @ qd)
        assert _close(a.tau_ext, b.tau_ext)
        assert np.all(np.isfinite(cc.forward_dynamics(q, qd)))
    q[-2:] = 0.0
    assert np.allclose(cc.tip_pose(q)[:3, 3], gvs.tip_pose(q)[:3, 3], atol=1e-15)


@pytest.mark.parametrize("floating", [False, True])
def test_mdot_minus_2c_is_skew_symmetric(floating, request):
    cc = request.getfixturevalue("cc_floating" if floating else "cc_fixed")
    q, qd = random_state(cc.n, 11)
    h = 1e-6
    mdot = (cc.terms(q + h * qd, qd).M - cc.terms(q - h * qd, qd).M) / (2 * h)
    n = mdot - 2 * cc.terms(q, qd).C
    assert np.abs(n).max() > 1e-4  # not trivially zero
    assert np.allclose(n + n.T, 0.0, atol=1e-8)


@pytest.mark.parametrize("floating", [False, True])
def test_trajectories_agree(floating, request):
    """Same initial state, same RK4 and step: the two trajectories coincide."""
    gvs = request.getfixturevalue("gvs_floating" if floating else "gvs_fixed")
    cc = request.getfixturevalue("cc_floating" if floating else "cc_fixed")
    if floating:
        q0 = np.array([0.0, 0.0, np.pi / 18, -0.5, 0.5, 5.0, 0.3, 0.4])
        u = np.r_[np.full(4, gvs.total_mass * 9.81 / 4) + [0.05, 0.0, -0.05, 0.0], 0, 2.0, 0, 0]
    else:
        q0 = np.array([0.3, 0.4])
        u = np.array([0.0, 2.0, 0.0, 0.0])
    qd0 = np.zeros(gvs.n)
    dt = 0.01
    _, qa, _ = rk4_simulate(gvs, q0, qd0, 1.0, dt, u)
    _, qb, _ = rk4_simulate(cc, q0, qd0, 1.0, dt, u)
    assert np.abs(qa[-1] - q0).max() > 0.05  # it moved
    assert np.abs(qa - qb).max() < 1e-9
    # and the GVS numba integrator is the same RK4
    res = tdacm.simulate(gvs, q0, qd0, duration=1.0, dt=dt, u=u)
    assert np.abs(res.q - qa).max() < 1e-9


def test_cache_is_reused(cc_floating_timed, gvs_floating, cc_cache):
    cc, first = cc_floating_timed
    t0 = time.perf_counter()
    again = CCLagrangian.from_system(gvs_floating)
    second = time.perf_counter() - t0
    assert again.build_info["from_cache"]
    assert again.build_info["path"] == cc.build_info["path"]
    assert str(cc_cache) in again.build_info["path"]
    if not cc.build_info["from_cache"]:
        assert cc.derivation_seconds > 1.0
        assert second < 0.1 * first
    q, qd = random_state(8, 2)
    assert np.array_equal(again.terms(q, qd).M, cc.terms(q, qd).M)


def test_unchecked_forward_dynamics_is_the_same(cc_floating):
    q, qd = random_state(8, 9)
    u = np.array([2.0, 2.1, 1.9, 2.0, 0.0, 1.0, 0.5, 0.0])
    a = cc_floating.forward_dynamics(q, qd, u)
    b = cc_floating.forward_dynamics_unchecked(q, qd, u, cc_floating._params())
    assert np.allclose(a, b, rtol=1e-13, atol=1e-13)


def test_invalid_inputs(cc_fixed):
    with pytest.raises(ValueError):
        cc_fixed.forward_dynamics([0.0], [0.0, 0.0])
    with pytest.raises(ValueError):
        cc_fixed.forward_dynamics([0.0, 0.0], [0.0, 0.0], [-1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        CCLagrangian.from_system(tdacm.paper_system(basis=tdacm.StrainBasis.bending(1)))


def test_rotated_clamp_agrees_with_gvs(cc_cache):
    """A clamp at a general pose: the baseline rotates gravity and the tip load into the clamp
    frame (one derivation serves every clamp pose)."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("zyx", [0.3, -0.7, 1.1]).as_matrix()
    pose[:3, 3] = [0.2, -0.4, 1.5]
    gvs = tdacm.paper_system(fixed_base_pose=pose)
    gvs.loads.tip_force = np.array([0.05, -0.02, -0.1])
    cc = CCLagrangian.from_system(gvs)
    q, qd = random_state(2, 13)
    a, b = gvs.terms(q, qd), cc.terms(q, qd)
    assert _close(a.M, b.M) and _close(a.tau_ext, b.tau_ext) and _close(a.C @ qd, b.C @ qd)
    assert np.allclose(gvs.tip_pose(q), cc.tip_pose(q), atol=1e-14)
    ea, eb = gvs.energy(q, qd), cc.energy(q, qd)
    for key in ("gravity", "loads", "total"):
        assert np.isclose(ea[key], eb[key], rtol=1e-12, atol=1e-14)
