"""Per-world parameters (domain randomization) in the batched engine.

A world with its own robot (stiffness, damping, masses, tendon moment arms), target pose and C_L
imperfections equals the block loop built on a scenario with those parameters (noise off,
states and image error to 1e-9: the scaled rows and the scaled scenario's arrays differ by
rounding); worlds without parameters are the engine's worlds as before;
with noise and per-world parameters, a world's run depends only on its own seed and parameters.
"""

import numpy as np
import pytest

from tdacm.batch.params import WorldParams
from tdacm.sim.assemble import build_loop
from tdacm.sim.batch import build_batch
from tdacm.sim.scenario import ScenarioError, load_scenario
from tdacm.system.worlds import robot_rows

ENGINE = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
    "ibvs": {"features": "measured"},
}

#: one world's parameters and the scenario keys that give the block loop the same world
FACTORS = {"stiffness": 1.08, "damping": 0.9, "drone_mass": 0.95, "rod_mass": 1.06,
           "moment_arm": 1.07}  # fmt: skip
TILT = (0.4, -0.3)


def _scenario(features="measured", duration=1.5, extra=None):
    ov = {**ENGINE, "ibvs": {"features": features}, "duration": duration, **(extra or {})}
    return load_scenario("paper-in-fov").with_overrides(ov, "engine configuration")


def _as_scenario(sc):
    """``sc`` with FACTORS and TILT written as its own keys."""
    r = sc.config.robot
    ov = {
        "robot": {
            "rod": {
                "youngs_modulus": r.rod.youngs_modulus * FACTORS["stiffness"],
                "damping": r.rod.damping * FACTORS["damping"],
                "density": r.rod.density * FACTORS["rod_mass"],
            },
            "drone": {"mass": r.drone.mass * FACTORS["drone_mass"]},
            "tendons": {"radius": r.tendons.radius * FACTORS["moment_arm"]},
        },
        "scene": {"target_tilt_deg": list(TILT)},
    }
    return sc.with_overrides(ov, "the world's parameters")


@pytest.mark.parametrize("features", ["measured", "predicted"])
def test_a_world_with_its_parameters_equals_the_block_loop_of_its_scenario(features):
    """World 1 (stiffer, lighter drone, heavier rod, longer moment arms, a tilted target)
    against ClosedLoop built on the scenario with those keys; world 0 (the scenario's own
    parameters) against the plain scenario's loop: states and image error to 1e-9 over 1.5 s
    (measured: about 1e-13)."""
    sc = _scenario(features)
    params = WorldParams(
        **{k: [1.0, v] for k, v in FACTORS.items()}, target_tilt_deg=[(0.0, 0.0), TILT]
    )
    res = build_batch(sc, [4, 4], params=params).run(log_states=True)
    for w, s in enumerate((sc, _as_scenario(sc))):
        r = build_loop(s, 4).loop.run(s.data["duration"])
        assert res.termination[w] is None and r.termination is None
        np.testing.assert_allclose(res.q[:, w], r.arrays["q"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.rmse[:, w], r.arrays["rmse"], rtol=0, atol=1e-9)
    assert np.abs(res.q[:, 1] - res.q[:, 0]).max() > 1e-3  # the parameters act


def test_robot_rows_are_the_model_of_the_scaled_scenario():
    """The rows of the factors equal the model arrays of the scenario with the scaled keys
    (to rounding), and factors of 1 give the scenario's arrays bit for bit."""
    sc = _scenario()
    m = build_loop(sc, 0).world.robot.system.model_arrays
    m2 = build_loop(_as_scenario(sc), 0).world.robot.system.model_arrays
    f = np.array([[1.0] * 5, [FACTORS[k] for k in FACTORS]])
    rows = robot_rows(m, f)
    for field, stack in zip(rows._fields, rows, strict=True):
        np.testing.assert_array_equal(stack[0], getattr(m, field))
        ref = getattr(m2, field)
        np.testing.assert_allclose(stack[1], ref, rtol=1e-14, atol=1e-14 * np.abs(ref).max())
        if np.any(ref):
            assert not np.allclose(stack[1], stack[0], rtol=1e-6, atol=0)


def test_no_parameters_and_the_scenario_parameters_are_the_same_worlds():
    """Per-world parameters equal to the scenario's (its pixel noise, latency, a level target)
    give bit-identical worlds to a batch without parameters, with noise on."""
    sc = _scenario(duration=0.6, extra={"sensors": {"pixel_noise": 1.0, "latency_steps": 1}})
    plain = build_batch(sc, [2, 9], threads=1).run(log_states=True)
    same = WorldParams(stiffness=[1.0, 1.0], pixel_noise=[1.0, 1.0], latency=[1, 1],
                       target_tilt_deg=[(0.0, 0.0)] * 2)  # fmt: skip
    res = build_batch(sc, [2, 9], threads=1, params=same).run(log_states=True)
    np.testing.assert_array_equal(res.q, plain.q)
    np.testing.assert_array_equal(res.rmse, plain.rmse)


@pytest.mark.parametrize("features", ["measured", "predicted"])
def test_a_randomized_world_does_not_depend_on_the_batch_size_its_index_or_threads(features):
    """Each world with its own robot, target tilt, pixel noise, dropout and latency: world of
    seed 11 gives bit-identical arrays alone, at index 4 of 7 and with 1 or 2 threads."""
    sc = _scenario(features, duration=0.8)
    rng = np.random.default_rng(7)
    n = 7

    def draw():
        return {
            **{k: rng.uniform(0.9, 1.1, n) for k in FACTORS},
            "pixel_noise": rng.uniform(0.0, 2.0, n),
            "dropout": rng.uniform(0.0, 0.1, n),
            "latency": rng.integers(0, 3, n),
            "target_tilt_deg": rng.normal(0.0, 0.5, (n, 2)),
        }

    p7 = WorldParams(**draw())
    seeds = [3, 4, 5, 6, 11, 8, 9]
    alone = build_batch(sc, [11], threads=1, params=p7.take([4])).run(log_states=True)
    runs = [build_batch(sc, seeds, threads=t, params=p7).run(log_states=True) for t in (1, 2)]
    for r in runs:
        np.testing.assert_array_equal(r.q[:, 4], alone.q[:, 0])
        np.testing.assert_array_equal(r.rmse[:, 4], alone.rmse[:, 0])
    np.testing.assert_array_equal(runs[0].q, runs[1].q)


def test_bad_parameters_are_refused_naming_the_field():
    with pytest.raises(ValueError, match="stiffness"):
        WorldParams(stiffness=[1.0, -1.0])
    with pytest.raises(ValueError, match="latency"):
        WorldParams(latency=[0.5])
    with pytest.raises(ValueError, match="dropout"):
        WorldParams(stiffness=[1.0, 1.0], dropout=[0.1])
    with pytest.raises(ScenarioError, match="params"):
        build_batch(_scenario(duration=0.1), [0, 1, 2], params=WorldParams(damping=[1.0]))
