"""Contact: geometry, the law, the kernels against exact answers (elastica, friction angle,
energy)."""

import numpy as np
import pytest
from scipy.integrate import solve_bvp
from scipy.optimize import root

from tdacm.contact import Box, ContactModel, Cylinder, Plane, Sphere, rotation_about
from tdacm.contact import layout as CL
from tdacm.contact.geometry import sdf, segment_contact
from tdacm.rod import StrainBasis
from tdacm.system import Loads, paper_system
from tdacm.system import kernels as K
from tdacm.system.contact import (
    contact_array,
    contact_generalized_force,
    contact_state,
)
from tdacm.system.tdacm import default_attachment

SHAPES = [
    Plane((0.1, 0.2, 0.3), (0.3, -0.2, 1.0)),
    Sphere((0.1, 0.0, -0.2), 0.3),
    Box((0.0, 0.1, 0.0), (0.4, 0.3, 0.2), rotation_about("z", 30) @ rotation_about("x", 20)),
    Cylinder((0.0, 0.0, 0.1), 0.2, 0.5, rotation_about("y", 40)),
]


def _packed(*shapes, **kw):
    m = ContactModel(obstacles=tuple(shapes), **kw)
    return np.concatenate([m.header(), *(s.row() for s in shapes)])


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: type(s).__name__)
def test_sdf_normal_is_the_distance_gradient(shape):
    c = _packed(shape)
    base = c.shape[0] - CL.SHAPE_SIZE
    rng = np.random.default_rng(1)
    eps = 1e-6
    for p in rng.uniform(-0.6, 0.6, (200, 3)):
        d, *n = sdf(c, base, *p)
        grad = [
            (sdf(c, base, *(p + eps * e))[0] - sdf(c, base, *(p - eps * e))[0]) / (2 * eps)
            for e in np.eye(3)
        ]
        # the distance has kinks (medial axis inside a box, cylinder rims): skip those points
        if abs(np.linalg.norm(grad) - 1) > 1e-4:
            continue
        np.testing.assert_allclose(n, grad, atol=1e-5)


def test_sdf_exact_values():
    c = _packed(Box((0, 0, 0), (0.4, 0.2, 0.2)))
    base = c.shape[0] - CL.SHAPE_SIZE
    assert sdf(c, base, 0.5, 0.0, 0.0)[0] == pytest.approx(0.3)
    assert sdf(c, base, 0.5, 0.4, 0.0)[0] == pytest.approx(np.hypot(0.3, 0.3))
    assert sdf(c, base, 0.1, 0.0, 0.0)[0] == pytest.approx(-0.1)
    c = _packed(Cylinder((0, 0, 0), 0.1, 1.0))
    base = c.shape[0] - CL.SHAPE_SIZE
    assert sdf(c, base, 0.3, 0.0, 0.2)[0] == pytest.approx(0.2)
    assert sdf(c, base, 0.0, 0.0, 0.7)[0] == pytest.approx(0.2)


def test_a_capsule_cannot_pass_through_a_box_edge_between_its_nodes():
    """Both nodes 5 cm clear of the box, the segment crossing its edge 1 mm deep."""
    c = _packed(Box((0, 0, 0), (0.2, 0.2, 0.2)))
    r = 0.002
    d = 0.1 + r - 0.001  # the segment's midline 1 mm inside the capsule's reach of the edge
    a = np.array([d + 0.3, d - 0.3, 0.0])
    b = np.array([d - 0.3, d + 0.3, 0.0])
    out = np.zeros(6)
    z = np.zeros(3)
    assert segment_contact(c, r, *a, *b, z, z, out)
    f = out[:3] + out[3:]
    # the normal of the edge, (1, 1, 0)/sqrt2, and the penetration r - (2d/sqrt2 - 0.1 sqrt2)
    np.testing.assert_allclose(f / np.linalg.norm(f), [2**-0.5, 2**-0.5, 0], atol=1e-6)
    # the nodes are 0.3 m from the edge: a node-only contact would miss it
    node_clear = sdf(c, c.shape[0] - CL.SHAPE_SIZE, *a)[0]
    assert node_clear > 0.1
    np.testing.assert_allclose(out[:3], out[3:], rtol=1e-6)  # the edge is at the midpoint


def test_empty_contact_is_bit_identical():
    s = paper_system()
    rng = np.random.default_rng(0)
    q, qd = rng.normal(0, 0.1, s.n), rng.normal(0, 0.1, s.n)
    u = np.r_[np.full(4, 2.5), np.ones(4)]
    m, loads, e = s.model_arrays, s.loads.packed(), np.empty(0)
    a0, _ = K.forward_dynamics(q, qd, u, m, loads)
    a1, _ = K.forward_dynamics_env(q, qd, u, m, loads, e, e)
    assert np.array_equal(a0, a1)
    # an obstacle far away: the same accelerations too
    far = contact_array(s, ContactModel(obstacles=(Sphere((5.0, 5.0, 5.0), 0.1),)))
    a2, _ = K.forward_dynamics_env(q, qd, u, m, loads, e, far)
    assert np.array_equal(a0, a2)


def _penalty_energy(system, q, c, k_tip, k_rod, r_tip, plane_p, plane_n):
    """Potential of the undamped, frictionless penalty contact with a plane: ``k d^2/2`` for
    the tip sphere, ``k L int max(0, r - sdf)^2 / 2`` along each capsule (linear profile)."""
    st = contact_state(system, q, np.zeros(system.n), c)
    d = (st.points - plane_p) @ plane_n
    e = 0.5 * k_tip * max(0.0, r_tip - d[-1]) ** 2
    r = 0.5 * system.arms[0].rod.diameter
    for i in range(len(d) - 1):
        length = np.linalg.norm(st.points[i + 1] - st.points[i])
        t = np.linspace(0, 1, 20001)
        p = np.maximum(0.0, r - ((1 - t) * d[i] + t * d[i + 1]))
        e += k_rod * length * 0.5 * np.trapezoid(p**2, t)
    return e


def test_frictionless_contact_force_is_the_gradient_of_its_potential():
    s = paper_system(fixed_base_pose=np.eye(4), basis=StrainBasis.bending(2))
    rng = np.random.default_rng(3)
    q = rng.normal(0, 0.3, s.n)
    tip = s.tip_pose(q)[:3, 3]
    n = np.array([0.3, 0.1, 1.0])
    n /= np.linalg.norm(n)
    p = tip - 0.004 * n
    cm = ContactModel(obstacles=(Plane(tuple(p), tuple(n)),), damping=0.0, mu_static=0.0,
                      mu_kinetic=0.0, tip_radius=0.01)  # fmt: skip
    c = contact_array(s, cm)
    tau = contact_generalized_force(s, q, np.zeros(s.n), c)
    assert np.linalg.norm(tau) > 0
    eps = 1e-6
    grad = np.array([
        (_penalty_energy(s, q + eps * e, c, 1e3, 2e4, 0.01, p, n)
         - _penalty_energy(s, q - eps * e, c, 1e3, 2e4, 0.01, p, n)) / (2 * eps)
        for e in np.eye(s.n)
    ])  # fmt: skip
    np.testing.assert_allclose(tau, -grad, rtol=2e-4, atol=1e-7 * np.abs(tau).max())


# --------------------------------------------------------------------- the elastica
EI = 5e10 * np.pi * (2e-3) ** 4 / 64  # the paper's rod


def elastica_wall(alpha, h, length=1.0):
    """A rod clamped at angle ``alpha`` to a frictionless wall parallel to its clamp axis,
    its tip held at height ``h`` by the wall: ``EI theta'' = F cos(theta)``, ``theta(0) =
    alpha``, ``theta'(L) = 0`` (a point force normal to the wall), ``y(L) = h``.  Returns the
    wall force ``F`` and the tip ``(x, y)``."""

    def f(s, y, p):
        return np.vstack([y[1], p[0] * np.cos(y[0]) / EI, np.cos(y[0]), np.sin(y[0])])

    def bc(ya, yb, p):
        return np.array([ya[0] - alpha, ya[2], ya[3], yb[1], yb[3] - h])

    s = np.linspace(0, length, 101)
    y0 = np.vstack([alpha * (1 - s / length), 0 * s, s * np.cos(alpha), s * h / length])
    sol = solve_bvp(f, bc, s, y0, p=[0.05], tol=1e-10, max_nodes=100000)
    assert sol.success, sol.message
    return sol.p[0], sol.y[2, -1], sol.y[3, -1]


def _clamped_at(alpha, order=4):
    a = default_attachment()
    rz = np.eye(4)
    rz[:3, :3] = rotation_about("z", np.degrees(alpha))
    pose = a @ rz @ np.linalg.inv(a)
    s = paper_system(basis=StrainBasis.bending(order), fixed_base_pose=pose,
                     loads=Loads(gravity=(0, 0, 0)))  # fmt: skip
    return s, a[:3, 0], a[:3, 1], a[:3, 3]


def _static_against_wall(s, y0, o, wall_from, wall_to, cm_kw):
    """Static equilibrium ``K q = tau_contact(q)`` with the wall moved from ``wall_from``
    (touching the straight rod) to ``wall_to`` by continuation (adaptive steps)."""
    n = s.n
    kk = s.model_arrays.stiffness

    def solve(w, q):
        cm = ContactModel(obstacles=(Plane(tuple(o + w * y0), tuple(-y0)),), **cm_kw)
        c = contact_array(s, cm)
        res = root(lambda x: contact_generalized_force(s, x, np.zeros(n), c) - kk @ x, q,
                   method="hybr", options={"xtol": 1e-12})  # fmt: skip
        return res.success, res.x, c

    q, w, step = np.zeros(n), wall_from, (wall_to - wall_from) / 20
    while w != wall_to:
        wn = max(w + step, wall_to)
        ok, qn, c = solve(wn, q)
        if ok:
            w, q, step = wn, qn, step * 1.5
        else:
            step *= 0.3
            assert abs(step) > 1e-9, "continuation stalled"
    return q, c


@pytest.mark.parametrize("alpha_deg, frac", [(10, 0.8), (60, 0.4)], ids=["small", "large"])
def test_clamped_rod_against_a_wall_matches_the_elastica(alpha_deg, frac):
    alpha = np.radians(alpha_deg)
    s, x0, y0, o = _clamped_at(alpha)
    r_tip = 0.01
    h = np.sin(alpha) * frac  # the tip sphere's centre on the deflected rod
    q, c = _static_against_wall(s, y0, o, np.sin(alpha) + r_tip, h + r_tip, {"tip_radius": r_tip})
    st = contact_state(s, q, np.zeros(s.n), c)
    f_el, x_el, y_el = elastica_wall(alpha, h)
    # the wall pushes along -y0 only (frictionless), on the tip sphere only
    np.testing.assert_allclose(st.tip @ y0, -f_el, rtol=0.02)
    assert np.linalg.norm(st.rod) == 0.0
    tip = s.tip_pose(q)[:3, 3] - o
    assert abs(tip @ x0 - x_el) < 0.01 and abs(tip @ y0 - y_el) < 0.01
    # measured: force within 1e-4 relative, tip within 1e-4 L (docs/contact.md)
    assert abs(-st.tip @ y0 / f_el - 1) < 1e-3
    assert np.hypot(tip @ x0 - x_el, tip @ y0 - y_el) < 1e-3


# ------------------------------------------------------------ friction and energy (dynamics)
H = 2.5e-4  # s, RK4 step: resolves the tip contact (316 rad/s) and the friction's damping


def _horizontal_rod(**rod_kw):
    """A 0.3 m rod of the paper's section, clamped horizontally along +x, a 20 g tip."""
    pose = np.eye(4)
    pose[:3, :3] = rotation_about("y", -90)
    return paper_system(length=0.3, tip_mass=0.02, basis=StrainBasis.bending(2),
                        fixed_base_pose=pose, **rod_kw)  # fmt: skip


def _run(s, c, duration, every=20):
    q = np.zeros(s.n)
    n = int(round(duration / H))
    qs, qds, ok = K.rk4_run_env(q, q, np.zeros(s.n_u), H, n, every, s.model_arrays,
                                s.loads.packed(), np.empty(0), c)  # fmt: skip
    assert ok
    return qs, qds


def _slide_on_tilted_plane(beta_deg, duration=0.5, **kw):
    """The straight rod's tip sphere laid on a plane tilted by ``beta`` about the rod axis;
    returns the tip's travel along the plane at every record and the final contact state."""
    s = _horizontal_rod()
    tip0 = s.tip_pose(np.zeros(s.n))[:3, 3]
    n = rotation_about("x", beta_deg)[:, 2]
    cm = ContactModel(obstacles=(Plane(tuple(tip0 - 0.01 * n), tuple(n)),), tip_radius=0.01, **kw)
    c = contact_array(s, cm)
    qs, qds = _run(s, c, duration)
    d = np.array([s.tip_pose(x)[:3, 3] for x in qs]) - tip0
    travel = np.linalg.norm(d - np.outer(d @ n, n), axis=1)
    return travel, contact_state(s, qs[-1], qds[-1], c), n


def test_tip_sticks_below_the_friction_angle_and_slides_above():
    """mu_s = 0.5 (26.6 deg): at 15 deg the tip only creeps at the regularization speed
    (measured 0.68 mm in 0.5 s with slip_speed 2 mm/s, 0.21 mm at 0.5 mm/s); at 35 deg
    it slides 24.6 mm in 0.2 s, to where the rod's bending holds it."""
    travel, st, n = _slide_on_tilted_plane(15)
    assert travel[-1] < 0.5 * 2e-3 * 1.0  # below half the slip speed on average
    ft = np.linalg.norm(st.tip - (st.tip @ n) * n)
    assert ft / (st.tip @ n) < 0.5  # inside the friction cone
    slow, _, _ = _slide_on_tilted_plane(15, slip_speed=5e-4)
    # the creep is the regularization's, not a slide: 4x slower slip, measured 3.2x less creep
    assert slow[-1] < 0.4 * travel[-1]
    slid, _, _ = _slide_on_tilted_plane(35)
    assert slid[int(0.2 / (20 * H))] > 0.02


def _bouncing(duration, **kw):
    """The rod falls from straight onto a plane tilted 20 deg, 3 cm below its tip sphere:
    returns the total energy (with the penalty's potential) and whether it touches."""
    s = _horizontal_rod(damping=0.0)
    tip = s.tip_pose(np.zeros(s.n))[:3, 3]
    n = rotation_about("x", 20)[:, 2]
    p = tip - 0.03 * n
    c = contact_array(s, ContactModel(obstacles=(Plane(tuple(p), tuple(n)),), **kw))
    qs, qds = _run(s, c, duration)
    e = np.array([
        s.energy(a, b)["total"] + _penalty_energy(s, a, c, 1e3, 2e4, 0.01, p, n)
        for a, b in zip(qs, qds, strict=True)
    ])  # fmt: skip
    touch = np.array(
        [contact_state(s, a, b, c).clearance < 0 for a, b in zip(qs, qds, strict=True)]
    )
    return e, touch


def _check_energy(duration):
    # frictionless and undamped: conserved (measured 7.7e-7 J over 2 s, 14 impacts, of the
    # 6 mJ of the fall)
    e, touch = _bouncing(duration, damping=0.0, mu_static=0.0, mu_kinetic=0.0)
    assert np.sum(np.diff(touch.astype(int)) == 1) >= 5
    assert np.max(np.abs(e - e[0])) < 1e-5 * duration
    # damped impacts and friction: never created, record to record
    e, touch = _bouncing(duration)
    assert touch.mean() > 0.5
    assert np.max(np.diff(e)) < 1e-9
    assert e[-1] < e[0] - 1e-3


def test_no_energy_created_bouncing_and_sliding():
    _check_energy(2.0)


@pytest.mark.slow
def test_no_energy_created_over_long_runs():
    _check_energy(20.0)


# ------------------------------------------------------------------------ scenario and log
def test_scenario_obstacles_reach_the_plant_and_the_log(tmp_path):
    from tdacm.sim.assemble import contact_plant_options
    from tdacm.sim.config import SceneSection

    s = paper_system()
    scene = SceneSection(
        obstacles=[{"shape": "sphere", "position": [0, 0, -1.2], "radius": 0.2}],
        contact={"target_box": True, "tip_stiffness": 500.0},
    )
    opts = contact_plant_options(scene, s)
    c = opts["contact"]
    assert c[CL.N_SHAPES] == 2 and c[CL.K_TIP] == 500.0
    assert contact_plant_options(SceneSection(), s) == {}
    with pytest.raises(ValueError, match="needs radius"):
        SceneSection(obstacles=[{"shape": "sphere"}])


@pytest.mark.parametrize("beta", [15, 35])
def test_plant_contact_steps_agree_with_a_fine_integration(beta):
    """The plant's default near-contact steps (32 a 0.02 s period) against 0.25 ms steps:
    the tip's travel on the tilted plane after 0.5 s (measured: the same to 0.01 mm from 16
    steps a period on; 8 steps diverge)."""
    from tdacm.loop.plant import Plant

    s = _horizontal_rod()
    tip0 = s.tip_pose(np.zeros(s.n))[:3, 3]
    n = rotation_about("x", beta)[:, 2]
    c = contact_array(s, ContactModel(obstacles=(Plane(tuple(tip0 - 0.01 * n), tuple(n)),)))
    p = Plant(s, np.zeros(s.n), np.zeros(s.n), contact=c)
    for _ in range(25):
        p.advance(np.zeros(s.n_u), 0.02)
    assert p.ok and p.last_substeps == 32
    fine, _, _ = _slide_on_tilted_plane(beta)
    d = s.tip_pose(p.state.q)[:3, 3] - tip0
    travel = np.linalg.norm(d - (d @ n) * n)
    assert abs(travel - fine[-1]) < 1e-4


def test_force_limit_ends_the_run():
    """The plant flags a contact force above ``force_limit``; the closed loop ends the run
    with ``Termination.FORCE_LIMIT`` (checked here on the plant: the hovering arm lowered
    onto a plane, 0.145 N on its tip)."""
    from tdacm.loop.data import Termination
    from tdacm.loop.plant import Plant

    s = paper_system()
    q = np.zeros(s.n)
    q[5] = 3.0
    tip = s.tip_pose(q)[:3, 3]
    c = contact_array(s, ContactModel(obstacles=(Plane(tuple(tip - [0, 0, 0.0101])),)))
    u = np.r_[np.full(4, 9.81 * s.total_mass / 4 - 0.02), 0.0, 0.0, 0.0, 0.0]
    for limit, over in ((0.1, True), (0.3, False)):
        p = Plant(s, q, np.zeros(s.n), contact=c, force_limit=limit)
        for _ in range(50):
            p.advance(u, 0.02)
            if p.over_limit:
                break
        assert p.ok and (p.over_limit is not None) == over
        if over:
            assert "above the limit 0.1 N" in p.over_limit
    assert Termination.FORCE_LIMIT == "force limit"


def test_plant_with_aerodynamics_and_contact_far_from_the_obstacles():
    """Aerodynamics and contact through the one environment hook: far from the obstacles the
    plant is exactly the aerodynamic one; near them both act."""
    from tdacm.loop.plant import Plant
    from tdacm.system.aero import aero_array

    s = paper_system()
    q = np.zeros(s.n)
    q[5] = 3.0
    qd = np.r_[0, 0, 0, 0.1, 0, 0, 0.2, -0.1]
    u = np.r_[np.full(4, 9.81 * s.total_mass / 4), 0.5, 0, 0, 0]
    air = aero_array(s, wind=[1.0, 0.0, 0.0])
    far = contact_array(s, ContactModel(obstacles=(Plane((0, 0, 0)),)))
    a = Plant(s, q, qd, aero=air)
    b = Plant(s, q, qd, aero=air, contact=far)
    for _ in range(5):
        sa, sb = a.advance(u, 0.02), b.advance(u, 0.02)
    assert np.array_equal(sa.q, sb.q) and np.array_equal(sa.qd, sb.qd)
    tip = s.tip_pose(q)[:3, 3]
    near = contact_array(s, ContactModel(obstacles=(Plane(tuple(tip - [0, 0, 0.009])),)))
    c = Plant(s, q, qd, aero=air, contact=near)
    a.reset(q, qd)
    sa, sc = a.advance(u, 0.02), c.advance(u, 0.02)
    assert c.last_substeps == 32 and not np.allclose(sa.q, sc.q)
