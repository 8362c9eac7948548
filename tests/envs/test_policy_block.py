"""A saved policy is a block of the loop: trained (a tiny one), saved, loaded by ``[servo]
policy``, run by ``tdacm run``; its observation is the env's; a policy of another robot or
observation size is refused with one line."""

import json

import gymnasium as gym
import numpy as np
import pytest

import tdacm.envs  # noqa: F401  (registers the id)
from tdacm.cli import main
from tdacm.loop.policy import PolicyServo, load_policy, save_policy
from tdacm.sim import load_scenario
from tdacm.sim.assemble import build_loop
from tdacm.sim.blocks import robot_signature

#: the robustness campaigns' initial spread of paper-in-fov (examples/train_ppo.py)
SPREAD = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)


def _train_tiny(env, steps: int = 300):
    """A tiny policy of the ``"linear+mlp"`` format, ``clip(clip(x L + c, -1, 1) + tanh(x W0 +
    b0) W1 + b1, -1, 1)``, fitted to the IBVS twist over ``steps`` periods of the single env
    (behaviour cloning, numpy only): the linear path by least squares, then the MLP's output
    layer (8 random tanh features) by least squares on what it leaves; a few seconds."""
    obs, acts = [], []
    seed = 0
    while len(obs) < steps:
        env.reset(seed=seed)
        seed += 1
        for _ in range(100):
            o, *_ = env._observe()
            st = env.loop.act(env._sensed)  # the servo's own IBVS twist
            obs.append(o)
            acts.append(st.command.twist / env.scale)
            if st.done:
                break
    X = np.asarray(obs, float)
    mean, var = X.mean(axis=0), X.var(axis=0) + 1e-4
    Xs = np.clip((X - mean) / (np.sqrt(var) + 1e-8), -5, 5)
    Y = np.clip(np.asarray(acts), -1.0, 1.0)
    A = np.c_[Xs, np.ones(len(Xs))]
    lin = np.linalg.lstsq(A, Y, rcond=None)[0]
    rng = np.random.default_rng(0)
    W0, b0 = rng.normal(0, 0.3, (X.shape[1], 8)), rng.normal(0, 0.1, 8)
    H = np.c_[np.tanh(Xs @ W0 + b0), np.ones(len(Xs))]
    out = np.linalg.lstsq(H, Y - np.clip(A @ lin, -1, 1), rcond=None)[0]
    return [W0, out[:-1]], [b0, out[-1]], mean, var, (lin[:-1], lin[-1])


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    env = gym.make("tdacm/TipServo-v0", init_noise=SPREAD, max_steps=50).unwrapped
    W, b, mean, var, lin = _train_tiny(env)
    meta = {
        "robot": robot_signature(env.scenario.config, env.n, env.scenario.name),
        "action_scale": {"max_angular": float(env.scale[0]), "max_linear": float(env.scale[3])},
    }
    path = save_policy(tmp_path_factory.mktemp("policy") / "tiny.npz", W, b, mean, var, meta,
                       linear=lin)  # fmt: skip
    yield env, path, (W, b, mean, var, meta, lin)
    env.close()


def test_policy_runs_in_tdacm_run(saved, tmp_path, capsys):
    _, path, _ = saved
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(f'[servo]\npolicy = "{path}"\n')
    out = tmp_path / "run"
    code = main(["run", "paper-in-fov", "--duration", "0.5", "--config", str(cfg), "--out",
                 str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["terminated"] is False
    tw = np.load(out / "timeseries.npz")
    # the logged twists are the policy's (bounded by its action scale), not zero
    twist = next(tw[k] for k in tw.files if "twist" in k)
    assert np.isfinite(twist).all() and np.abs(twist).max() > 0


def test_env_and_block_loop_see_the_same_observation(saved):
    """The env acting with the policy and the block loop running the policy as its servo
    follow the same trajectory from the same seed and initial state: one observation."""
    env, path, _ = saved
    policy = load_policy(path)
    obs, _ = env.reset(seed=7)
    q0, seed = env.loop.plant.state.q.copy(), env._seed
    env_q, env_obs = [], []
    for _ in range(25):
        env_obs.append(obs)
        obs, *_ = env.step(policy(obs))
        env_q.append(env.loop.plant.state.q.copy())
    sc = env.scenario.with_overrides({"servo": {"policy": str(path)}}, "test")
    a = build_loop(sc, seed)
    loop = a.loop
    assert isinstance(loop.servo, PolicyServo)
    loop.reset(q0, env.world.qd0)
    for k in range(25):
        loop.step()
        np.testing.assert_array_equal(loop.servo.last_observation, env_obs[k])
        np.testing.assert_allclose(loop.plant.state.q, env_q[k], rtol=0, atol=1e-12)
    loop.close()


def test_saved_policy_is_the_fitted_map(saved):
    """The loaded file computes ``clip(clip(x L + c, -1, 1) + mlp(x), -1, 1)`` of the fitted
    arrays (the
    linear path kept in float64), and a file of the one-MLP format still loads."""
    env, path, (W, b, mean, var, meta, (L, c)) = saved
    p = load_policy(path)
    assert p.meta["architecture"] == "linear+mlp" and p.meta["format"] == 2
    obs = np.random.default_rng(1).normal(size=(7, mean.size))
    # the scaling and the MLP are stored in float32, the linear path in float64
    m32, v32, W0, b0, W1, b1 = (
        np.float32(a).astype(float) for a in (mean, var, W[0], b[0], W[1], b[1])
    )
    xs = np.clip((obs - m32) / (np.sqrt(v32) + 1e-8), -5, 5)
    expect = np.clip(np.clip(xs @ L + c, -1, 1) + np.tanh(xs @ W0 + b0) @ W1 + b1, -1, 1)
    np.testing.assert_allclose(p(obs), expect, rtol=0, atol=1e-12)
    old = load_policy(save_policy(path.with_name("old.npz"), [L], [c], mean, var, meta))
    assert old.linear is None and old.meta["architecture"] == "tanh-mlp"
    L32, c32 = np.float32(L).astype(float), np.float32(c).astype(float)
    np.testing.assert_allclose(old(obs), np.tanh(xs @ L32 + c32), rtol=0, atol=1e-12)


def test_mismatched_policy_refused(saved, tmp_path, capsys):
    _, _, (W, b, mean, var, meta, (L, c)) = saved
    wide = save_policy(tmp_path / "wide.npz", [np.vstack([W[0], np.zeros((2, 8))]), W[1]], b,
                       np.r_[mean, 0, 0], np.r_[var, 1, 1], meta,
                       linear=(np.vstack([L, np.zeros((2, 6))]), c))  # fmt: skip
    other = dict(meta, robot=dict(meta["robot"], signature="0123456789abcdef"))
    alien = save_policy(tmp_path / "alien.npz", W, b, mean, var, other, linear=(L, c))
    for path, needle in ((wide, "observations of 33 entries"), (alien, "another robot"),
                         (tmp_path / "none.npz", "no such file")):  # fmt: skip
        cfg = tmp_path / "cfg.toml"
        cfg.write_text(f'[servo]\npolicy = "{path}"\n')
        code = main(["run", "paper-in-fov", "--duration", "0.1", "--config", str(cfg), "--out",
                     str(tmp_path / "o")])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2, err
        assert "servo.policy" in err and needle in err, err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_batched_engine_refuses_policy(saved):
    from tdacm.sim.batch import build_batch
    from tdacm.sim.scenario import ScenarioError

    env, path, _ = saved
    sc = load_scenario("paper-in-fov").with_overrides({"servo": {"policy": str(path)}}, "t")
    with pytest.raises(ScenarioError, match="servo.policy"):
        build_batch(sc, [0])
