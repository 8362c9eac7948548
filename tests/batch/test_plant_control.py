"""The compiled controller and plant of one world (:mod:`tdacm.batch.control`,
:mod:`tdacm.batch.plant`) against the blocks they are packed from: the same periods on the
same inputs, side by side.

The block loop (the Python controller on the plant's true state, the Python plant on the
controller's inputs) runs 100 periods with a reference drifting around the initial
configuration; the compiled controller is fed the same estimate and reference each period,
the compiled plant the same inputs from its own state. Tolerances: 1e-12, relative where a
value exceeds 1, except the tendon tensions (see :func:`_tension_tolerance`).
"""

import copy

import numpy as np
import pytest
from numba import njit, prange

from tdacm.aero.wind import DrydenTurbulence, _Sum
from tdacm.batch.control import (
    N_WORK,
    P_MAX_TILT,
    ControllerArrays,
    controller_arrays,
    controller_period,
    controller_state,
    controller_work,
)
from tdacm.batch.plant import (
    D_DOWNWASH_ON,
    N_WIND_NORMALS,
    W_TURB_ON,
    PlantArrays,
    model_of_world,
    plant_accelerations,
    plant_arrays,
    plant_period,
    plant_state,
    wind_start,
    wind_velocity,
)
from tdacm.loop.ablation import TruthAblation
from tdacm.loop.lowlevel import PDGravityController
from tdacm.sim.assemble import build_loop
from tdacm.sim.scenario import load_scenario
from tdacm.system.kernels import N_LOADS

PERIODS = 100
TOL = 1e-12

#: flight-test-c (aerodynamics on: rotor wake, drag of the arm and the drone, the model knows
#: the rotor drag) with a steady wind, a gust inside the run, the base wrench and the
#: downwash with its noise; the turbulence off
AIR = {
    "wind": {
        "velocity": [1.0, 0.5, 0.0],
        "gust_amplitude": [0.5, -0.3, 0.2],
        "gust_start": 0.4,
        "gust_duration": 0.8,
        "turbulence_wind20": 0.0,
    },
    "disturbances": {
        "base_wrench_amplitude": [0.01, 0.02, 0.0, 0.1, 0.0, 0.2],
        "base_wrench_frequency": 3.0,
        "downwash": [0.0, 0.0, -0.2],
        "downwash_noise": 0.05,
    },
}
#: the same with Dryden turbulence (W20 = 1 m/s) on the steady wind
AIR_DRYDEN = {**AIR, "wind": {**AIR["wind"], "turbulence_wind20": 1.0}}

#: case: (scenario, overrides, the reference's amplitude, the exact attitude inversion)
CASES = {
    "paper-in-fov": ("paper-in-fov", None, 0.05, False),
    "paper-out-of-fov": ("paper-out-of-fov", None, 0.05, False),
    "ground-test-a": ("ground-test-a", None, 0.05, False),
    "ground-test-b": ("ground-test-b", None, 0.05, False),
    "custom-robot-example": ("custom-robot-example", None, 0.05, False),
    "flight-test-c-air": ("flight-test-c", AIR, 0.05, False),
    "flight-test-c-dryden": ("flight-test-c", AIR_DRYDEN, 0.05, False),
    # the paper's literal model (gravity in Delta_hat), the exact ZYX inversion and a reference
    # swinging enough to saturate the motors and the tendons
    "paper-in-fov-saturating": (
        "paper-in-fov",
        {"model": {"gravity_feedforward": False}},
        0.4,
        True,
    ),
    "ground-test-a-saturating": ("ground-test-a", None, 1.5, False),
    # as paper-in-fov-saturating with a milder swing: the motors and the tendons saturate
    # now and then, the closed loop stays regular (at 0.4 it turns bang-bang within 5 s, and
    # the tensions' last-bit differences grew to 6e-10 in the states: measured)
    "paper-in-fov-swinging": (
        "paper-in-fov",
        {"model": {"gravity_feedforward": False}},
        0.15,
        True,
    ),
}


def _assembly(case):
    name, overrides, _, exact = CASES[case]
    sc = load_scenario(name)
    if overrides is not None:
        sc = sc.with_overrides(overrides)
    asm = build_loop(sc, seed=3)
    asm.loop.controller.controller.exact_attitude = exact
    return asm


def _reference(q0, t, amplitude):
    """A reference drifting around ``q0`` (each coordinate its own phase) with its rates."""
    ph = 0.7 * t + np.arange(q0.size)
    a = amplitude
    return q0 + a * np.sin(ph), 0.7 * a * np.cos(ph), -0.49 * a * np.sin(ph)


def _turbulence(wind):
    parts = [] if wind is None else (list(wind.parts) if type(wind) is _Sum else [wind])
    found = [p for p in parts if type(p) is DrydenTurbulence]
    return found[0] if found else None


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(a)), initial=0.0))


def _tension_tolerance(b_s, tensions) -> float:
    """The tendon allocation solves the normal equations of ``[B_s; w I] T = [tau_s; w T_pre]``
    (w = 1e-3 |B_s|): their condition number is ``kappa^2`` (2e6 for the paper's tendons), so
    inputs equal but for the last bits give tensions equal to about ``kappa^2 eps |T|``, not
    1e-12 (measured 1.7e-11 N on paper-in-fov-saturating: the attitude command's force norm
    and arctan differ from numpy's in the last bit now and then). The bound: that product."""
    w = 1e-3 * np.linalg.norm(b_s, axis=0).max()
    a = np.vstack([b_s, w * np.eye(b_s.shape[1])])
    return float(np.linalg.cond(a) ** 2 * np.finfo(float).eps * max(1.0, np.abs(tensions).max()))


@pytest.mark.parametrize("case", list(CASES))
def test_one_world_equals_the_blocks(case):
    asm = _assembly(case)
    loop, s = asm.loop, asm.world.robot.system
    low, plant = loop.controller, loop.plant
    dt = asm.scenario.data["dt"]
    n, na = s.n, s.n_a
    ca, mc = controller_arrays(low, dt)
    pa, mp = plant_arrays(plant)
    plant.accelerations = True  # and the accelerations an IMU senses, from here on
    qdd = np.zeros(n)
    # the controller's state and outputs
    delta_hat, att, att_rate, att_set = controller_state(n)
    work = controller_work(n)
    u, tau, q_ref = np.zeros(s.n_u), np.zeros(n), np.zeros(n)
    low.controller.reset()
    # the plant's state: the random draws the blocks make, from copies of their streams
    q, qd, wind_state = plant_state(plant)
    turb = _turbulence(plant.wind)
    assert (turb is not None) == (pa.wind[W_TURB_ON] != 0.0) == (case == "flight-test-c-dryden")
    wind_rng = np.random.default_rng(turb.seed) if turb is not None else None
    wind_start(
        pa.wind,
        wind_rng.standard_normal(N_WIND_NORMALS) if turb else np.zeros(N_WIND_NORMALS),
        wind_state,
    )
    dist_rng = copy.deepcopy(plant.rng)
    aero, loads = pa.aero.copy(), np.zeros(N_LOADS)
    q_out, qd_out = np.empty(n), np.empty(n)
    worst = dict(u=0.0, delta_hat=0.0, att=0.0, tau=0.0, q_ref=0.0, V=0.0, q=0.0, qd=0.0, qdd=0.0)
    worst_tension = 0.0
    thrust_saturated = tension_saturated = 0
    for k in range(PERIODS):
        st = plant.state
        q_d, qd_d, qdd_d = _reference(asm.world.q0, st.t, CASES[case][2])
        cs = low.controller.step(st.q, st.qd, q_d, qd_d, qdd_d, dt)
        v, t_sat, s_sat, thrust, resid = controller_period(
            ca, mc, delta_hat, att, att_rate, att_set, st.q, st.qd, q_d, qd_d, qdd_d, dt, u, tau,
            q_ref, work,
        )  # fmt: skip
        off = s.n_u - na
        worst["u"] = max(worst["u"], _rel(cs.u[:off], u[:off]))
        worst_tension = max(worst_tension, float(np.abs(cs.u[off:] - u[off:]).max()))
        assert worst_tension <= _tension_tolerance(s.tendon_matrix(st.q), cs.u[off:]), k
        worst["delta_hat"] = max(worst["delta_hat"], _rel(cs.delta_hat, delta_hat))
        worst["tau"] = max(worst["tau"], _rel(cs.tau, tau))
        worst["q_ref"] = max(worst["q_ref"], _rel(cs.q_ref, q_ref))
        worst["V"] = max(worst["V"], _rel(cs.V, v))
        if s.floating:
            worst["att"] = max(worst["att"], _rel(low.controller._att, att))
            assert thrust == pytest.approx(cs.thrust_total, rel=TOL, abs=TOL)
        assert (t_sat, s_sat) == (cs.thrust_saturated, cs.tension_saturated), k
        thrust_saturated += t_sat
        tension_saturated += s_sat
        # the plant: the same inputs, from its own state
        dist_normals = (
            dist_rng.standard_normal(3) if pa.disturbances[D_DOWNWASH_ON] else np.zeros(3)
        )
        rows = 1 if (turb is not None and k > 0) else 0  # one turbulence sample a period
        wind_normals = (
            wind_rng.standard_normal((rows, N_WIND_NORMALS))
            if rows
            else np.zeros((0, N_WIND_NORMALS))
        )
        ok, tumbled, t_end = plant_period(
            pa, mp, aero, q, qd, wind_state, cs.u, dt, 0.0, k, dist_normals, wind_normals, loads,
            q_out, qd_out,
        )  # fmt: skip
        plant.advance(cs.u, dt)
        q, qd = q_out.copy(), qd_out.copy()
        ps = plant.state
        assert (ok, tumbled, t_end) == (plant.ok, plant.tumbled, ps.t), k
        assert ok and not tumbled
        worst["q"] = max(worst["q"], _rel(ps.q, q))
        worst["qd"] = max(worst["qd"], _rel(ps.qd, qd))
        assert plant_accelerations(mp, aero, loads, q, qd, cs.u, qdd) == plant.ok
        worst["qdd"] = max(worst["qdd"], _rel(ps.qdd, qdd))
        if plant.aero is not None:  # the wind the period was integrated in
            assert np.abs(plant.aero - aero).max() <= TOL, k
    print(case, worst, "tensions", worst_tension, "saturated", thrust_saturated, tension_saturated)
    for key, value in worst.items():
        assert value <= TOL, (key, value)
    if case.endswith("-saturating"):  # the clipping paths ran (the motors, or the tendons)
        assert (thrust_saturated if s.floating else tension_saturated) > 0
    # the plant's wind sequences were consumed alike (the same number of draws)
    if turb is not None:
        assert np.array_equal(turb._rng.standard_normal(4), wind_rng.standard_normal(4))
    if pa.disturbances[D_DOWNWASH_ON]:
        assert np.array_equal(plant.rng.standard_normal(4), dist_rng.standard_normal(4))


def test_turbulence_samples_equal_drydens_on_the_same_draws():
    """The port of the Dryden filters, fed the draws of the block's own stream, gives its
    samples (1,000 periods of 0.02 s from its stationary start; the gust and the steady wind
    added in the block's order)."""
    asm = _assembly("flight-test-c-dryden")
    wind = asm.loop.plant.wind
    turb = _turbulence(wind)
    pa, _ = plant_arrays(asm.loop.plant)
    rng = np.random.default_rng(turb.seed)
    state = np.zeros(6)
    wind_start(pa.wind, rng.standard_normal(N_WIND_NORMALS), state)
    wind.reset()
    out = np.zeros(3)
    dt = turb.dt
    worst = 0.0
    samples = np.empty((1000, 3))
    for k in range(1000):
        t = 0.0 + k * dt
        normals = rng.standard_normal((1 if k else 0, N_WIND_NORMALS))
        wind_velocity(pa.wind, state, t, normals, out)
        ref = wind.velocity(t)
        worst = max(worst, float(np.abs(ref - out).max()))
        samples[k] = out
    assert worst <= TOL
    assert np.std(samples[:, 2]) > 0  # the turbulence is on (sigma_w = 0.1 m/s)
    # two samples due in one period need two rows of draws
    with pytest.raises(ValueError, match="more samples"):
        wind_velocity(pa.wind, state, 1002 * dt, np.zeros((1, 5)), out)


def test_what_the_engine_refuses():
    asm = _assembly("paper-in-fov")
    loop = asm.loop
    # a user's controller class, the PD law and the truth ablation
    pd = copy.copy(loop.controller)
    pd.__class__ = PDGravityController
    with pytest.raises(ValueError, match=r"^controller\.class"):
        controller_arrays(pd, 0.02)
    with pytest.raises(ValueError, match=r"^estimation\.controller_truth"):
        controller_arrays(TruthAblation(loop.controller, loop.plant, [0], []), 0.02)
    # contact
    touching = copy.copy(loop.plant)
    touching.contact = np.zeros(1)
    with pytest.raises(ValueError, match=r"^scene\.obstacles / scene\.contact\.target_box"):
        plant_arrays(touching)


@pytest.mark.parametrize(
    "case", ["paper-in-fov-swinging", "flight-test-c-air", "ground-test-a-saturating"]
)
def test_the_compiled_pair_closes_the_loop_as_the_blocks(case):
    """The compiled controller on the compiled plant's state, 5 s (250 periods), against the
    blocks' closed loop: the states stay within 1e-12 (measured 2e-13 on paper-in-fov-swinging,
    where the tensions differ by up to 1e-11 N in a few periods (:func:`_tension_tolerance`),
    2e-15 with the air, 0 on the ground)."""
    asm = _assembly(case)
    loop, s = asm.loop, asm.world.robot.system
    low, plant = loop.controller.controller, loop.plant
    dt = asm.scenario.data["dt"]
    n = s.n
    (ca, mc), (pa, mp) = controller_arrays(loop.controller, dt), plant_arrays(plant)
    delta_hat, att, att_rate, att_set = controller_state(n)
    work = controller_work(n)
    u, tau, q_ref = np.zeros(s.n_u), np.zeros(n), np.zeros(n)
    q, qd, wind_state = plant_state(plant)
    dist_rng = copy.deepcopy(plant.rng)
    aero, loads = pa.aero.copy(), np.zeros(N_LOADS)
    q_out, qd_out = np.empty(n), np.empty(n)
    low.reset()
    worst = 0.0
    for k in range(250):
        t = k * dt
        q_d, qd_d, qdd_d = _reference(asm.world.q0, t, CASES[case][2])
        st = plant.state
        plant.advance(low.step(st.q, st.qd, q_d, qd_d, qdd_d, dt).u, dt)
        controller_period(
            ca, mc, delta_hat, att, att_rate, att_set, q, qd, q_d, qd_d, qdd_d, dt, u, tau,
            q_ref, work,
        )  # fmt: skip
        dist_normals = dist_rng.standard_normal(3) if pa.disturbances[D_DOWNWASH_ON] else None
        ok, _, _ = plant_period(
            pa, mp, aero, q, qd, wind_state, u, dt, 0.0, k,
            np.zeros(3) if dist_normals is None else dist_normals,
            np.zeros((0, N_WIND_NORMALS)), loads, q_out, qd_out,
        )  # fmt: skip
        q, qd = q_out.copy(), qd_out.copy()
        assert ok and plant.ok
        worst = max(worst, _rel(plant.state.q, q), _rel(plant.state.qd, qd))
    assert plant.state.t == pytest.approx(5.0)
    print(case, "closed loop, 5 s:", worst)
    assert worst <= TOL


@njit(cache=True, parallel=True)
def _worlds(
    ca, mc, pa, mp, mb6, stiffness, damping, step_mass, params, gains, q, qd, q_d, u, q_out
):
    """One controller period and one plant period for each world, every world with its own
    plant masses and stiffness, controller gains and scalars: the records built from rows of
    the stacks inside a ``prange`` loop (:func:`~tdacm.batch.plant.model_of_world`,
    ``ControllerArrays(...)``)."""
    n = q.shape[0]
    for w in prange(stiffness.shape[0]):
        m = model_of_world(
            mp, mb6[w], stiffness[w], damping[w], step_mass[w], mp.tendon_d, mp.tendon_dd
        )
        cw = ControllerArrays(
            ca.loads, params[w], ca.coord, ca.damping, gains[w], ca.g4_lu, ca.g4_piv
        )
        pw = PlantArrays(pa.loads, pa.disturbances, pa.aero, pa.wind, pa.substeps)
        dh, att, rate, aset = np.zeros(n), np.zeros(2), np.zeros(2), np.zeros(1, np.bool_)
        zero = np.zeros(n)
        controller_period(
            cw, mc, dh, att, rate, aset, q, qd, q_d, zero, zero, 0.02, u[w], np.zeros(n),
            np.zeros(n), np.zeros((N_WORK, n)),
        )  # fmt: skip
        plant_period(
            pw, m, pa.aero.copy(), q, qd, np.zeros(6), u[w], 0.02, 0.0, 0, np.zeros(3),
            np.zeros((0, N_WIND_NORMALS)), np.zeros(N_LOADS), q_out[w], np.zeros(n),
        )  # fmt: skip


@pytest.mark.slow
def test_per_world_records_are_built_inside_compiled_code():
    """The engine's per-world parameters: numba builds the NamedTuple records from rows of
    stacked arrays inside a ``prange`` loop, and each world equals the same period run from
    Python with that world's records (to the bit). Slow on an empty cache: compiling the
    parallel loop around both periods took 100-180 s on the 2-core machine (then 1 s)."""
    asm = _assembly("paper-in-fov")
    loop = asm.loop
    (ca, mc), (pa, mp) = controller_arrays(loop.controller, 0.02), plant_arrays(loop.plant)
    worlds = 3
    f = 1.0 + 0.1 * np.arange(worlds)
    mb6 = np.ascontiguousarray(f[:, None] * mp.mb6)
    stiffness = np.ascontiguousarray(f[:, None, None] * mp.stiffness)
    damping = np.ascontiguousarray(f[::-1, None, None] * mp.damping)
    step_mass = np.ascontiguousarray(f[:, None, None] * mp.step_mass)
    params = np.ascontiguousarray(np.tile(ca.params, (worlds, 1)))
    params[:, P_MAX_TILT] = 0.2 + 0.05 * np.arange(worlds)
    gains = np.ascontiguousarray(f[:, None, None, None] * ca.gains)
    q, q_d = asm.world.q0.copy(), asm.world.q_star.copy()
    n = q.size
    qd = np.full(n, 0.1)
    u = np.zeros((worlds, loop.plant.system.n_u))
    q_out = np.zeros((worlds, n))
    _worlds(ca, mc, pa, mp, mb6, stiffness, damping, step_mass, params, gains, q, qd, q_d, u, q_out)
    for w in range(worlds):
        mw = mp._replace(mb6=mb6[w], stiffness=stiffness[w], damping=damping[w])
        mw = mw._replace(step_mass=step_mass[w])
        cw = ca._replace(params=params[w], gains=gains[w])
        dh, att, rate, aset = controller_state(n)
        u_w, q_w, zero = np.zeros(u.shape[1]), np.zeros(n), np.zeros(n)
        controller_period(
            cw, mc, dh, att, rate, aset, q, qd, q_d, zero, zero, 0.02, u_w, np.zeros(n),
            np.zeros(n), controller_work(n),
        )  # fmt: skip
        plant_period(
            pa, mw, pa.aero.copy(), q, qd, np.zeros(6), u_w, 0.02, 0.0, 0, np.zeros(3),
            np.zeros((0, N_WIND_NORMALS)), np.zeros(N_LOADS), q_w, np.zeros(n),
        )  # fmt: skip
        assert np.array_equal(u[w], u_w) and np.array_equal(q_out[w], q_w), w
    assert not np.array_equal(q_out[0], q_out[1])  # the worlds differ
