"""The analysis examples run and say what the docs quote."""

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_target_information_bounds(capsys):
    """The filter ends at the Cramer-Rao bound of the flown frames; only a trajectory with
    sideways excursions of 0.2 m would lower it substantially (docs/campaigns.md)."""
    bounds, within, summary = _load("target_information").main(seed=3, excursions=(0.2,))
    flown = np.array(bounds["flown trajectory"])
    still = np.array(bounds["all frames at the final pose"])
    wide = np.array(bounds["flown + excursions of +-0.20 m over the last 2 s"])
    assert 0.3 < flown.max() < 0.7  # degrees, 1 px, 251 frames
    assert np.all(np.abs(still / flown - 1) < 0.2)  # the approach adds little
    assert np.all(wide < 0.7 * flown)
    assert abs(summary["final_target_estimate_sigma_deg"] / flown.max() - 1) < 0.15
    assert 0.85 < within < 0.97
    # the level prior (0.5 deg) informs the tilt: 1/sqrt(1/0.49^2 + 1/0.5^2) = 0.35 deg
    prior = np.array(bounds["flown + level prior 0.5 deg"])
    np.testing.assert_allclose(prior, 1 / np.sqrt(1 / flown**2 + 1 / 0.5**2), rtol=0.02)
    assert "Cramer-Rao" in capsys.readouterr().out


def test_train_ppo_smoke(tmp_path):
    """examples/train_ppo.py end to end on a tiny budget (256 steps: two small updates, one
    held-out episode per policy): the figure, the results and the policy are written, the
    saved policy (with its observation scaling) loads and acts, and the IBVS expert
    succeeds."""
    import pytest

    pytest.importorskip("skrl")
    pytest.importorskip("jax")
    ex = _load("train_ppo")
    small = {"rollouts": 64, "learning_epochs": 2, "mini_batches": 2}
    res = ex.main(timesteps=256, eval_episodes=1, out=tmp_path, ppo=small)
    assert (tmp_path / "learning_curve.png").is_file()
    assert (tmp_path / "results.json").is_file()
    assert res["ibvs"]["success_rate"] == 1.0 and res["zero_twist"]["success_rate"] == 0.0
    assert set(res) >= {"ppo", "zero_twist", "ibvs"}
    assert res["training_episodes"] >= 1
    env = ex.make_env()
    obs, _ = env.reset(seed=ex.EVAL_SEED0)
    a = ex.load_policy(tmp_path / "policy.pickle")(env, obs)
    assert a.shape == (6,) and np.all(np.abs(a) <= 1.0)
    again = ex.load_policy(tmp_path / "policy.pickle")(env, obs)
    np.testing.assert_array_equal(a, again)  # deterministic, from the file
    env.close()
