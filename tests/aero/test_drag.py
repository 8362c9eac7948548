"""Drag on the rod, the tip body and the drone inside the coupled dynamics (eq. (16))."""

import math

import numpy as np
import pytest

import tdacm
from tdacm.aero import Aerodynamics, Drag
from tdacm.aero.drag import cylinder_cd
from tdacm.system import Loads
from tdacm.system import kernels as K
from tdacm.system.aero import aero_array, aero_generalized_force, section_air_loads


@pytest.fixture(scope="module")
def paper():
    return tdacm.paper_system()


def hover(system):
    q = np.zeros(system.n)
    q[5] = 3.0
    u = np.r_[np.full(4, 9.81 * system.total_mass / 4), np.zeros(system.n_a)]
    return q, np.zeros(system.n), u


def test_switched_off_aerodynamics_change_nothing(paper):
    q, qd, u = hover(paper)
    rng = np.random.default_rng(1)
    q = q + 0.3 * rng.standard_normal(paper.n)
    qd = rng.standard_normal(paper.n)
    off = aero_array(
        paper, Aerodynamics(wake=False, rod_drag=False, drone_drag=False), wind=[3, 1, 0]
    )
    m, loads = paper.model_arrays, paper.loads.packed()
    ref = K.forward_dynamics(q, qd, u, m, loads)[0]
    assert np.array_equal(K.forward_dynamics_aero(q, qd, u, m, loads, off)[0], ref)
    assert np.array_equal(K.forward_dynamics_aero(q, qd, u, m, loads, np.empty(0))[0], ref)
    on = aero_array(paper, wind=[3, 1, 0])
    assert not np.array_equal(K.forward_dynamics_aero(q, qd, u, m, loads, on)[0], ref)


def test_straight_vertical_rod_in_vertical_wake_feels_only_axial_force(paper):
    q, qd, u = hover(paper)
    a = aero_array(paper)
    pts, dens, tip = section_air_loads(paper, q, qd, u, a)
    assert np.all(dens[:, :2] == 0.0) and tip[:2] == pytest.approx([0, 0], abs=0)
    assert np.all(dens[:, 2] <= 0.0) and dens[-1, 2] < 0.0  # pulled down along the axis
    tau = aero_generalized_force(paper, q, qd, u, a)
    assert np.all(tau[6:] == 0.0)  # no bending
    assert tau[5] < 0.0


def test_crossflow_drag_in_steady_wind_matches_cylinder_formula(paper):
    q, qd, u = hover(paper)
    w = 4.0
    a = aero_array(paper, Aerodynamics(wake=False), wind=[w, 0.0, 0.0])
    _, dens, tip = section_air_loads(paper, q, qd, u, a)
    rho, mu, d = 1.225, 1.789e-5, paper.rod.diameter
    cd = cylinder_cd(rho * w * d / mu)
    assert cd == pytest.approx(1 + 10 * (rho * w * d / mu) ** (-2 / 3), rel=1e-14)
    assert dens[:, 0] == pytest.approx(np.full(5, 0.5 * rho * cd * d * w * w), rel=1e-12)
    assert tip == pytest.approx([0.5 * rho * 6.7e-4 * w * w, 0, 0], rel=1e-12)


def test_drone_drag_is_rotor_drag_plus_body_drag(paper):
    q, qd, u = hover(paper)
    qd[3:6] = [2.0, -1.0, 0.5]
    a = aero_array(paper, Aerodynamics(wake=False, rod_drag=False))
    tau = aero_generalized_force(paper, q, qd, u, a)
    v = qd[3:6]
    lin = np.array([0.29, 0.29, 0.0])
    cda = np.array([0.015, 0.015, 0.04])
    expect = -lin * v - 0.5 * 1.225 * np.linalg.norm(v) * cda * v
    assert tau[3:6] == pytest.approx(expect, rel=1e-12)
    assert np.all(tau[6:] == 0.0)


def test_drag_never_creates_energy_in_still_air(paper):
    rng = np.random.default_rng(7)
    a = aero_array(paper, Aerodynamics(wake=False))
    for _ in range(200):
        q = 0.6 * rng.standard_normal(paper.n)
        q[3:6] += [0.0, 0.0, 3.0]
        qd = 2.0 * rng.standard_normal(paper.n)
        u = np.r_[rng.uniform(0, 4, 4), rng.uniform(0, 5, paper.n_a)]
        tau = aero_generalized_force(paper, q, qd, u, a)
        assert tau @ qd <= 1e-15
        assert tau @ qd < 0.0


def _peaks(t, x):
    """Times and values of the local maxima of x (parabolic interpolation)."""
    i = np.nonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:]))[0] + 1
    y0, y1, y2 = x[i - 1], x[i], x[i + 1]
    den = y0 - 2 * y1 + y2
    dt = t[1] - t[0]
    off = 0.5 * (y0 - y2) / den
    return t[i] + off * dt, y1 - 0.25 * (y0 - y2) * off


def test_swinging_rod_decays_as_quadratic_drag_predicts():
    """A clamped rod (no gravity, no material damping) swinging in still air with a constant
    ``C_d``: the modal amplitude of ``m a'' + k a = -c |a'| a'``, averaged over a cycle, obeys
    ``1/A = 1/A_0 + (4 / (3 pi)) (c / m) omega t`` with ``c = int 1/2 rho C_d d |phi|^3 ds``.
    Tolerance 3 %: the cycle-averaging error is of the order of the decrement per cycle (0.5 %),
    the geometric nonlinearity of the 0.1 m tip swing of the order of (kappa L)^2 / 12 = 0.3 %."""
    s = tdacm.paper_system(fixed_base_pose=np.eye(4), damping=0.0, loads=Loads(gravity=(0, 0, 0)))
    cd, rho = 1.2, 1.225
    drag = Drag(rod_cd=cd, rod_cf=0.0, tip_cda=(0.0, 0.0, 0.0))
    a = aero_array(s, Aerodynamics(wake=False, drone_drag=False, drag=drag))
    m = s.model_arrays
    terms = s.terms(np.zeros(2), np.zeros(2))
    mass, k = terms.M[0, 0], s.model_arrays.stiffness[0, 0]
    omega = math.sqrt(k / mass)
    # lateral velocity per unit rate of the first coordinate at the Gauss points
    phi = np.array(
        [np.linalg.norm(s.jacobian(np.zeros(2), x)[4:6, 0]) for x in s.quadrature_points]
    )
    c = 0.5 * rho * cd * s.rod.diameter * np.sum(m.wq * phi**3)
    a0, dt, n = 0.2, 0.005, 8000
    qs, _, ok = K.rk4_run_aero(
        np.array([a0, 0.0]), np.zeros(2), np.zeros(4), dt, n, 1, m, s.loads.packed(), a
    )
    assert ok
    t = dt * np.arange(n + 1)
    tp, ap = _peaks(t, qs[:, 0])
    assert len(tp) >= 15
    slope = np.polyfit(tp, 1.0 / ap, 1)[0]
    assert slope == pytest.approx(4 / (3 * math.pi) * c / mass * omega, rel=0.03)
    # without the drag the amplitude stays
    none = aero_array(s, Aerodynamics(wake=False, rod_drag=False, drone_drag=False))
    qs0, _, _ = K.rk4_run_aero(
        np.array([a0, 0.0]), np.zeros(2), np.zeros(4), dt, n, 1, m, s.loads.packed(), none
    )
    assert _peaks(t, qs0[:, 0])[1] == pytest.approx(a0, rel=1e-6)
