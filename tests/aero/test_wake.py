"""Rotor wake: momentum theory near the disc, the jet downstream, the four rotors on the drone."""

import math

import numpy as np
import pytest

import tdacm
from tdacm.aero import Aerodynamics, RotorWake, induced_velocity, jet_speed, wake_field
from tdacm.system.aero import aero_array

RHO = 1.225
R = 0.1905
A = math.pi * R**2
S, B = 0.094, 5.8


def test_induced_velocity_hover_and_momentum_balance():
    t = 1.87  # N, a quarter of the paper's TD-ACM weight
    vh = math.sqrt(t / (2 * RHO * A))
    assert induced_velocity(t, RHO, A, 0.0) == pytest.approx(vh, rel=1e-14)
    # climb and windmill-brake branches satisfy the momentum balance T = 2 rho A |V_c + v_i| v_i
    for vc in (0.5, 2.0, 10.0, -2.5 * vh, -6.0 * vh):
        vi = induced_velocity(t, RHO, A, vc)
        assert 2 * RHO * A * abs(vc + vi) * vi == pytest.approx(t, rel=1e-12)
    # the vortex-ring fit joins hover exactly and the windmill branch within 3 % (Leishman)
    assert induced_velocity(t, RHO, A, -1e-9) == pytest.approx(vh, rel=1e-8)
    assert induced_velocity(t, RHO, A, -2 * vh + 1e-9) == pytest.approx(vh, rel=0.03)
    assert induced_velocity(0.0, RHO, A, 0.0) == 0.0


def _edge(z, vi, vc, core):
    """Radius of the top-hat slipstream at depth z (bisection on the jet's support)."""
    lo, hi = 0.0, 2 * R
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if jet_speed(mid, z, vi, vc, R, S, B, core) > 0 else (lo, mid)
    return lo


@pytest.mark.parametrize("vc", [0.0, 1.5])
def test_contracted_wake_conserves_mass_and_reaches_twice_induced_velocity(vc):
    vi = induced_velocity(2.0, RHO, A, vc)
    core = 1e3 * R  # a long near wake: the far wake of momentum theory
    flow = math.pi * R**2 * (vc + vi)  # volume flow through the disc (rotor frame)
    for z in (0.0, 0.1 * R, R, 3 * R, 50 * R):
        rw = _edge(z, vi, vc, core)
        w = jet_speed(0.0, z, vi, vc, R, S, B, core)
        assert math.pi * rw**2 * (vc + w) == pytest.approx(flow, rel=1e-12)
    far = jet_speed(0.0, 900 * R, vi, vc, R, S, B, core)
    assert far == pytest.approx(2 * vi, rel=1e-6)  # far wake: 2 v_i
    assert jet_speed(0.0, 0.0, vi, vc, R, S, B, core) == pytest.approx(vi, rel=1e-14)
    if vc == 0.0:  # hover: the slipstream contracts to R / sqrt(2)
        assert _edge(900 * R, vi, vc, core) == pytest.approx(R / math.sqrt(2), rel=1e-5)


def _jet_integrals(z, vi, core):
    r = np.linspace(0.0, 3.0, 300001)
    u = np.array([jet_speed(x, z, vi, 0.0, R, S, B, core) for x in r[::100]])
    rr = r[::100]
    return np.trapezoid(u * 2 * np.pi * rr, rr), np.trapezoid(u**2 * 2 * np.pi * rr, rr)


def test_jet_far_field_momentum_flux_and_entrainment():
    """The jet's mean momentum flux is constant downstream; its volume flow grows linearly at
    ``4 B S^2 / ln 2 = 0.296`` times the nozzle flow per nozzle diameter, against the measured
    0.32 of Ricou & Spalding (1961, J. Fluid Mech. 11): within 10 %, the spread of the round-jet
    spreading rates from which S is taken (Pope 2000, Table 5.1: 0.086 to 0.102)."""
    vi = induced_velocity(1.87, RHO, A, 0.0)
    core = 2 * R
    w = jet_speed(0.0, core, vi, 0.0, R, S, B, core)
    rj = _edge(core, vi, 0.0, core)
    dj = 2 * rj
    q_j, m_j = math.pi * rj**2 * w, math.pi * rj**2 * w**2
    fluxes = [_jet_integrals(core + x * dj, vi, core) for x in (5.0, 10.0, 15.0)]
    for _, mom in fluxes:
        assert mom == pytest.approx(m_j * 2 * B**2 * S**2 / math.log(2), rel=2e-3)
    slope = (fluxes[2][0] - fluxes[0][0]) / (10.0 * dj) * dj / q_j
    assert slope == pytest.approx(4 * B * S**2 / math.log(2), rel=2e-3)
    assert slope == pytest.approx(0.32, rel=0.10)


def test_four_rotor_wake_follows_pose_and_thrust():
    s = tdacm.paper_system()
    a = aero_array(s, Aerodynamics(rotor=RotorWake(layout="+")))
    g = np.eye(4)
    g[:3, 3] = [1.0, 2.0, 3.0]
    t = np.full(4, 1.87)
    vi = induced_velocity(1.87, RHO, A, 0.0)
    below_rotor0 = [1.0 + 0.325, 2.0, 3.0 - 0.1]
    v = wake_field(below_rotor0, g, t, a)[0]
    assert v == pytest.approx([0.0, 0.0, -jet_speed(0.0, 0.1, vi, 0.0, R, S, B, 2 * R)], abs=1e-12)
    assert np.all(wake_field([[1.0, 2.0, 3.5]], g, t, a) == 0.0)  # nothing above the discs
    # rotor 0 off: no jet below it; thrust doubled on rotor 1: sqrt(2) more induced velocity
    t2 = np.array([0.0, 3.74, 1.87, 1.87])
    assert wake_field(below_rotor0, g, t2, a)[0, 2] == 0.0
    p1 = [1.0, 2.0 + 0.325, 2.9]
    ratio = wake_field(p1, g, t2, a)[0, 2] / wake_field(p1, g, t, a)[0, 2]
    assert ratio == pytest.approx(math.sqrt(2), rel=1e-12)
    # the field turns with the drone: rolled 90 deg about x, the wake blows along +y
    gr = g.copy()
    gr[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    p = gr[:3, 3] + gr[:3, :3] @ np.array([0.325, 0.0, -0.1])
    v = wake_field(p, gr, t, a)[0]
    assert v[1] > 0 and abs(v[0]) < 1e-12 and abs(v[2]) < 1e-12
    # "x" layout: rotor 0 at +45 deg
    ax = aero_array(s, Aerodynamics(rotor=RotorWake(layout="x")))
    c = 0.325 / math.sqrt(2)
    assert wake_field([1.0 + c, 2.0 + c, 2.9], g, t, ax)[0, 2] < 0


def test_merged_far_wake_is_the_jet_of_the_total_momentum():
    """Far below, the four overlapping jets add their momentum: twice one jet on the axis."""
    s = tdacm.paper_system()
    a = aero_array(s)
    g = np.eye(4)
    t = np.full(4, 1.87)
    vi = induced_velocity(1.87, RHO, A, 0.0)
    z = 40.0
    one = jet_speed(0.325, z, vi, 0.0, R, S, B, 2 * R)
    assert -wake_field([0.0, 0.0, -z], g, t, a)[0, 2] == pytest.approx(2 * one, rel=1e-12)


def test_validation():
    with pytest.raises(ValueError, match="layout"):
        RotorWake(layout="h")
    with pytest.raises(ValueError, match="rotor_radius"):
        RotorWake(rotor_radius=-1)
    with pytest.raises(ValueError, match="rod_drag"):
        Aerodynamics(rod_drag=False)


def test_crosswind_skews_the_wake_downwind():
    """Glauert's skew: the wake centreline leans downwind at ``tan chi = W / v_i`` (hover)."""
    s = tdacm.paper_system()
    wind = 1.5
    a = aero_array(s, wind=[wind, 0.0, 0.0])
    g = np.eye(4)
    t = np.array([1.87, 0.0, 0.0, 0.0])  # rotor 0 alone (the others' jet tails reach here)
    vi = induced_velocity(1.87, RHO, A, 0.0)
    z = 0.3  # inside the near wake, whose radius there is 0.14 m
    c = np.array([0.325, 0.0, 0.0])  # rotor 0
    d = np.array([wind, 0.0, -vi]) / math.hypot(wind, vi)
    on = wake_field(c + z * d, g, t, a)[0]
    assert on == pytest.approx([0, 0, -jet_speed(0.0, z, vi, 0.0, R, S, B, 2 * R)], abs=1e-12)
    # the unskewed point below the rotor is outside the slipstream, upwind of it
    assert wake_field(c + [0.0, 0.0, -z * math.hypot(wind, vi) / vi], g, t, a)[0, 2] == 0.0
    # flying at the wind's speed through still air is the same skew
    still = aero_array(s)
    moving = wake_field(c + z * d, g, t, still, velocity=[-wind, 0.0, 0.0])[0]
    assert moving == pytest.approx(on, abs=1e-12)
