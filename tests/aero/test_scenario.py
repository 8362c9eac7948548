"""The scenario keys of the aerodynamics ([aerodynamics], [wind], the rotors of [robot.drone])
and their wiring into the plant by build_loop."""

import numpy as np
import pytest

from tdacm.aero.config import WIND_STREAM
from tdacm.sim import build_loop
from tdacm.sim.robot import DroneConfig
from tdacm.sim.scenario import ScenarioError, load_scenario

FAST = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}


@pytest.fixture(scope="module")
def ground():
    return load_scenario("ground-test-a").with_overrides(FAST, "fast")


def _with(scenario, over):
    return scenario.with_overrides(over, "test")


@pytest.mark.parametrize(
    "over, message",
    [
        ({"aerodynamics": {"air_density": 0.0}}, "aerodynamics.air_density must be > 0, got 0"),
        ({"aerodynamics": {"rod_cd": -1.0}}, "aerodynamics.rod_cd must be > 0"),
        ({"aerodynamics": {"tip_cda": [1e-3, 1e-3]}}, "aerodynamics.tip_cda must have 3 entries"),
        ({"aerodynamics": {"drone_cda": [0.0, -1.0, 0.0]}}, "drone_cda must be non-negative"),
        ({"aerodynamics": {"enabled": True, "rod_drag": False}}, "wake = true needs rod_drag"),
        ({"aerodynamics": {"enable": True}}, "unknown key aerodynamics.enable"),
        ({"wind": {"velocity": [3.0, 0.0, 0.0]}}, "set aerodynamics.enabled = true"),
        ({"wind": {"turbulence_wind20": -1.0}}, "wind.turbulence_wind20 must be >= 0"),
        ({"wind": {"turbulence_height": 400.0}}, "wind.turbulence_height must be in (0, 304.8)"),
        ({"wind": {"gust_duration": 0.0}}, "wind.gust_duration must be > 0"),
        ({"robot": {"drone": {"rotor_radius": 0.0}}}, "robot.drone.rotor_radius must be > 0"),
        ({"robot": {"drone": {"rotor_radius": 0.25}}}, "the rotors overlap"),
        ({"robot": {"drone": {"layout": "h"}}}, "robot.drone.layout must be one of"),
    ],
)
def test_keys_are_validated_with_one_line_errors(over, message):
    sc = load_scenario("paper-in-fov")
    with pytest.raises(ScenarioError) as err:
        sc.with_overrides(over, "test")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_rotor_defaults_come_from_the_aero_record():
    from tdacm.aero import RotorWake

    d = DroneConfig()
    assert d.rotor_radius == RotorWake().rotor_radius and d.layout == RotorWake().layout


def test_fixed_thrusts_only_for_a_fixed_base():
    sc = load_scenario("paper-in-fov")
    with pytest.raises(ScenarioError, match="fixed_thrusts is for a fixed base"):
        _with(sc, {"aerodynamics": {"enabled": True, "fixed_thrusts": [1.0] * 4}})


def test_off_builds_the_plain_plant(ground):
    a = build_loop(ground).loop.plant
    assert a.aero is None and a.wind is None
    # the other keys of the sections do nothing while aerodynamics.enabled is false
    b = build_loop(_with(ground, {"aerodynamics": {"air_density": 2.0}})).loop.plant
    assert b.aero is None


def _tip_x_after(scenario, seconds=1.0):
    """The tip's x (m) after ``seconds`` of the plant alone, tendons slack."""
    plant = build_loop(scenario).loop.plant
    s = plant.system
    u = np.zeros(s.n_u)
    for _ in range(int(round(seconds / 0.02))):
        st = plant.advance(u, 0.02)
    assert plant.ok
    return float(s.tip_pose(st.q)[0, 3])


def test_wind_moves_the_arm_downwind(ground):
    straight = {"initial": {"q": [0.0, 0.0]}}
    calm = _tip_x_after(_with(ground, {**straight, "aerodynamics": {"enabled": True}}))
    for wx in (4.0, -4.0):
        windy = _with(
            ground,
            {**straight, "aerodynamics": {"enabled": True}, "wind": {"velocity": [wx, 0, 0]}},
        )
        dx = _tip_x_after(windy) - calm
        # 4 m/s on the hanging arm: about 25 mN on rod and camera, a tip offset of centimetres
        assert np.sign(dx) == np.sign(wx) and 0.005 < abs(dx) < 0.2


def test_turbulence_is_seeded_reproducible_and_on_its_own_stream(ground):
    sc = _with(ground, {"aerodynamics": {"enabled": True}, "wind": {"turbulence_wind20": 5.0}})

    def winds(seed):
        plant = build_loop(sc, seed=seed).loop.plant
        return np.array([plant.wind.velocity(0.02 * k) for k in range(100)]), plant

    a, pa = winds(3)
    b, _ = winds(3)
    c, _ = winds(4)
    assert np.array_equal(a, b) and not np.allclose(a, c)
    assert np.std(a[:, 0]) > 0.05  # sigma_u ~ 1 m/s at 2.2 m for W20 = 5 m/s
    # the plant's own generator (the disturbances) is the run's seed, untouched by the wind
    assert pa.rng.random() == np.random.default_rng(3).random()
    assert WIND_STREAM not in (1, 11, 12, 13)  # the sensors' streams
    # a reset of the plant replays the same turbulence
    pa.reset(pa.state.q, pa.state.qd)
    assert np.array_equal(pa.wind.velocity(0.0), a[0])


def test_aerodynamics_damp_the_swinging_arm(ground):
    """The wiring carries the drag into the plant: a swinging rod in still air loses more
    energy with the aerodynamics on than with the material damping alone."""
    bent = {"initial": {"q": [2.0, 0.0]}}

    def energy(over):
        plant = build_loop(_with(ground, {**bent, **over})).loop.plant
        s = plant.system
        u = np.zeros(s.n_u)
        for _ in range(50):
            st = plant.advance(u, 0.02)
        e = s.energy(st.q, st.qd)
        return e["total"]

    assert energy({"aerodynamics": {"enabled": True}}) < energy({})


def test_reseeded_loop_has_the_turbulence_of_its_seed():
    """reseed (the env's reset without rebuilding) redraws the turbulence from the new seed's
    stream: the run is the one of a loop built with that seed, sample for sample."""
    from tdacm.sim.assemble import reseed

    sc = load_scenario("paper-in-fov").with_overrides(
        {**FAST, "aerodynamics": {"enabled": True}, "wind": {"turbulence_wind20": 5.0}}, "t"
    )
    fresh = build_loop(sc, 7).loop.run(0.3).arrays
    a = build_loop(sc, 3)
    a.loop.run(0.1)  # used with another seed first
    a.loop.plant.reset(a.world.q0, a.world.qd0)
    again = reseed(a, 7).loop.run(0.3).arrays
    for k in ("q", "u", "points_local"):
        assert np.array_equal(fresh[k], again[k], equal_nan=True), k
