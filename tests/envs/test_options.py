"""The env options: one record for both envs, checked once, randomization refused by name."""

import dataclasses
import inspect

import numpy as np
import pytest

from tdacm.envs import TipServoEnv, TipServoVectorEnv
from tdacm.envs.options import RANDOMIZATION_LIMITS, EnvOptions, Randomization


def test_no_default_is_written_in_the_env_constructors():
    """The defaults live in EnvOptions only: neither constructor repeats a field."""
    fields = {f.name for f in dataclasses.fields(EnvOptions)}
    for cls in (TipServoEnv, TipServoVectorEnv):
        params = set(inspect.signature(cls.__init__).parameters)
        assert not (params & fields), (cls, params & fields)


def test_keywords_replace_the_record_fields():
    o = EnvOptions(max_steps=100)
    p = EnvOptions.of(o, {"success_rmse": 0.02})
    assert (p.max_steps, p.success_rmse, p.scenario) == (100, 0.02, "paper-in-fov")
    assert EnvOptions.of(o, {}) is o


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"max_steps": 0}, "max_steps"),
        ({"init_noise": -0.1}, "init_noise"),
        ({"init_noise": [0.1, float("nan")]}, "init_noise"),
        ({"success_rmse": 0.0}, "success_rmse"),
        ({"action_type": "torques"}, "action_type"),
        ({"randomize": {"stiffness": 0.2}}, "randomize.stiffness"),
        ({"randomize": {"latency": 3}}, "randomize.latency"),
        ({"randomize": {"pixel_noise": -1.0}}, "randomize.pixel_noise"),
        ({"randomize": {"spin": 0.1}}, "randomize.spin"),
    ],
)
def test_bad_values_are_refused_naming_the_option(kw, name):
    with pytest.raises(ValueError, match=name.replace(".", r"\.")) as e:
        EnvOptions(**kw)
    assert "\n" not in str(e.value)


def test_unknown_keyword_is_refused():
    with pytest.raises(ValueError, match="max_stepz"):
        EnvOptions.of(None, {"max_stepz": 3})


def test_randomization_is_off_by_default_and_within_its_limits():
    r = EnvOptions().randomize
    assert r.active == ()
    top = Randomization(**RANDOMIZATION_LIMITS)
    assert set(top.active) == set(RANDOMIZATION_LIMITS)


@pytest.mark.parametrize("name", sorted(RANDOMIZATION_LIMITS))
def test_the_single_env_refuses_a_range_it_cannot_draw(name):
    """The block loop's env refuses ranges with one line naming the option, never ignores
    them (the vector env draws them: tests/envs/test_vector_env.py)."""
    r = {name: RANDOMIZATION_LIMITS[name]}
    with pytest.raises(ValueError, match=f"randomize\\.{name}") as e:
        TipServoEnv(randomize=r)
    assert "\n" not in str(e.value)


def test_draws_are_within_the_ranges_and_only_for_the_active_ones():
    r = Randomization(stiffness=0.1, masses=0.05, pixel_noise=2.0, latency=2)
    rng = np.random.default_rng(0)
    draws = [r.draw(rng) for _ in range(200)]
    assert set(draws[0]) == {"stiffness", "drone_mass", "rod_mass", "pixel_noise", "latency"}
    k = np.array([d["stiffness"][0] for d in draws])
    m = np.array([d["drone_mass"][0] for d in draws])
    lat = {d["latency"][0] for d in draws}
    px = np.array([d["pixel_noise"][0] for d in draws])
    assert 0.9 <= k.min() < 0.92 and 1.08 < k.max() <= 1.1
    assert 0.95 <= m.min() and m.max() <= 1.05
    assert lat == {0, 1, 2} and 0 <= px.min() and px.max() <= 2.0
    assert Randomization().draw(rng) == {}


def test_initial_spread_per_coordinate():
    spread = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)
    o = EnvOptions(init_noise=list(spread))
    assert o.init_noise == spread
    np.testing.assert_array_equal(o.initial_std(8), spread)
    np.testing.assert_array_equal(EnvOptions().initial_std(3), [0.02] * 3)
    with pytest.raises(ValueError, match="init_noise: one standard deviation per coordinate"):
        o.initial_std(6)
