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
def test_both_envs_refuse_a_range_the_engines_cannot_draw_per_world(name):
    """Per-world ranges are refused with one line naming the option, never ignored."""
    r = {name: RANDOMIZATION_LIMITS[name]}
    for make in (lambda: TipServoEnv(randomize=r), lambda: TipServoVectorEnv(2, randomize=r)):
        with pytest.raises(ValueError, match=f"randomize\\.{name}") as e:
            make()
        assert "\n" not in str(e.value)


def test_initial_spread_per_coordinate():
    spread = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)
    o = EnvOptions(init_noise=list(spread))
    assert o.init_noise == spread
    np.testing.assert_array_equal(o.initial_std(8), spread)
    np.testing.assert_array_equal(EnvOptions().initial_std(3), [0.02] * 3)
    with pytest.raises(ValueError, match="init_noise: one standard deviation per coordinate"):
        o.initial_std(6)
