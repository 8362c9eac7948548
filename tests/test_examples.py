"""The analysis examples run and say what the docs quote."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

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


@pytest.mark.slow  # JAX's compilation and skrl's set-up: 1-2 min on the shared 2-core machine
def test_train_ppo_smoke(tmp_path, monkeypatch):
    """examples/train_ppo.py end to end on a tiny budget (8 worlds: two DAgger rounds of 256
    steps, two small PPO updates; 4 validation and 4 held-out episodes): the figure, the
    results and the policy files are written, and the numpy-only policy of ``ppo.npz`` acts
    as the agent's deterministic policy."""
    pytest.importorskip("skrl")
    pytest.importorskip("jax")
    ex = _load("train_ppo")
    monkeypatch.setitem(ex.DAGGER, "steps", 256)
    monkeypatch.setitem(ex.DAGGER, "iterations", 20)
    small = {"rollouts": 16, "learning_epochs": 2, "mini_batches": 2}
    res = ex.main(timesteps=256, eval_episodes=4, out=tmp_path, ppo=small, num_envs=8,
                  dagger_rounds=2, val_episodes=4)  # fmt: skip
    assert (tmp_path / "learning_curve.png").is_file()
    assert (tmp_path / "results.json").is_file()
    r = res["policy"]
    assert r["episodes"] == 4 and r["seeds"] == [ex.EVAL_SEED0, ex.EVAL_SEED0 + 3]
    assert sum(r["endings"].values()) == 4
    assert res["kept"] in ("ppo", "dagger") and set(res["validation_success"]) == {"ppo", "dagger"}
    act, meta = ex.load_npz(tmp_path / "ppo.npz")
    assert meta["env_options"]["hold_success"] is True and meta["observation_size"] == 31
    assert meta["architecture"] == "linear+mlp"
    obs = np.random.default_rng(0).normal(size=(5, 31)).astype(np.float32)
    # the same policy in float64 (numpy) and float32 (JAX): equal to float32 rounding
    agent = ex.policy_of(_agent_of(ex, tmp_path, act))
    np.testing.assert_allclose(act(obs), np.clip(agent(obs), -1, 1), atol=1e-4)


def _agent_of(ex, path, policy):
    """The PPO agent saved in ``path`` (its models built with the policy file's scaling)."""
    from skrl.envs.wrappers.jax import wrap_env

    ex._cpu()
    venv = ex.make_env(2)
    env = wrap_env(venv, wrapper="gymnasium", verbose=False)
    agent = ex.make_agent(env, policy.obs_mean, policy.obs_std, path)
    agent.init()
    agent.load(str(path / "policy.pickle"))
    venv.close()
    return agent
