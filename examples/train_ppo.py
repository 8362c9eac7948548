"""Train a servoing policy with PPO (skrl on JAX) on the twist action of
``tdacm/TipServo-v0``, save it, and compare its success rate with the zero-twist and the IBVS
policies on held-out seeds.

Needs the ``rl`` extra (``pip install 'tdacm[rl]'``: skrl, JAX and Flax, CPU wheels from PyPI,
no torch). Run::

    python examples/train_ppo.py --timesteps 40000 --out out/ppo

It writes into ``--out``: ``learning_curve.png`` (the training episodes' return and final RMSE
against the environment steps), ``results.json`` (success rates and final RMSE of the three
policies on the held-out seeds) and ``policy.pickle``, the trained agent (the policy, its value
function and the running mean and variance that scale the observations;
:func:`load_policy` gives back the deterministic policy). The task (:data:`TASK`): servo the
paper-in-fov scenario from its initial pose (noise 0.02 on q) until the normalized RMSE of the
four points falls below ``success_rmse`` within ``max_steps`` control periods. Training seeds
are drawn from ``--seed``'s generator; evaluation uses seeds 10_000 and up, never seen in
training.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

#: The env's arguments for training and evaluation (docs/env.md, "Learning").
TASK = {"max_steps": 150, "success_rmse": 0.05}
EVAL_SEED0 = 10_000
#: PPO's settings (skrl's PPO_CFG names): 512 steps per env and 2 envs per update
PPO = {
    "rollouts": 512,
    "learning_epochs": 10,
    "mini_batches": 8,
    "discount_factor": 0.98,
    "gae_lambda": 0.95,
    "learning_rate": 3e-4,
    "grad_norm_clip": 0.5,
    "ratio_clip": 0.2,
    "value_clip": 0.2,
    "entropy_loss_scale": 0.0,
    "value_loss_scale": 0.5,
}
N_ENVS = 2


class _Episodes:
    """The training episodes, recorded by the envs themselves:
    ``(env steps at the end, return, final rmse, success)``."""

    def __init__(self):
        self.steps = 0
        self.rows = []


def make_env(episodes: _Episodes | None = None):
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    env = gym.make("tdacm/TipServo-v0", **TASK)
    if episodes is None:
        return env

    class Record(gym.Wrapper):
        def reset(self, **kw):
            self.ret = 0.0
            return self.env.reset(**kw)

        def step(self, action):
            obs, r, term, trunc, info = self.env.step(action)
            episodes.steps += 1
            self.ret += float(r)
            if term or trunc:
                episodes.rows.append((episodes.steps, self.ret, info["rmse"], info["success"]))
            return obs, r, term, trunc, info

    return Record(env)


def _models(env):
    """The policy (Gaussian, MLP 64-64, tanh mean) and the value function (MLP 64-64)."""
    import flax.linen as nn
    import jax.numpy as jnp
    from skrl.models.jax import DeterministicMixin, GaussianMixin, Model

    spaces = dict(
        observation_space=env.observation_space,
        state_space=getattr(env, "state_space", None),
        action_space=env.action_space,
        device=env.device,
    )

    class Policy(GaussianMixin, Model):
        def __init__(self, **kw):
            Model.__init__(self, **kw)
            GaussianMixin.__init__(self, clip_actions=True, reduction="sum")

        @nn.compact
        def __call__(self, inputs, role):
            x = nn.tanh(nn.Dense(64)(inputs["observations"]))
            x = nn.tanh(nn.Dense(64)(x))
            mean = nn.tanh(nn.Dense(self.num_actions)(x))
            log_std = self.param(
                "log_std", lambda _: jnp.full(self.num_actions, -0.5, dtype=jnp.float32)
            )
            return mean, {"log_std": log_std}

    class Value(DeterministicMixin, Model):
        def __init__(self, **kw):
            Model.__init__(self, **kw)
            DeterministicMixin.__init__(self)

        @nn.compact
        def __call__(self, inputs, role):
            x = nn.tanh(nn.Dense(64)(inputs["observations"]))
            x = nn.tanh(nn.Dense(64)(x))
            return nn.Dense(1)(x), {}

    models = {"policy": Policy(**spaces), "value": Value(**spaces)}
    for role, model in models.items():
        model.init_state_dict(role=role)
    return models


def make_agent(env, directory: Path | None = None, ppo: dict | None = None):
    """skrl's PPO with :data:`PPO`'s settings (``ppo`` replaces some) on ``env`` (a wrapped
    skrl env); the observations scaled by their running mean and variance (saved with the
    agent)."""
    from skrl.agents.jax.ppo import PPO as Agent
    from skrl.agents.jax.ppo import PPO_CFG
    from skrl.memories.jax import RandomMemory
    from skrl.resources.preprocessors.jax import RunningStandardScaler

    settings = {**PPO, **(ppo or {})}
    cfg = PPO_CFG(**settings)
    cfg.observation_preprocessor = RunningStandardScaler
    cfg.observation_preprocessor_kwargs = {"size": env.observation_space, "device": env.device}
    cfg.value_preprocessor = RunningStandardScaler
    cfg.value_preprocessor_kwargs = {"size": 1, "device": env.device}
    cfg.experiment.write_interval = 0  # no TensorBoard files
    cfg.experiment.checkpoint_interval = 0
    cfg.experiment.directory = str(directory or Path("out") / "ppo")
    memory = RandomMemory(
        memory_size=settings["rollouts"], num_envs=env.num_envs, device=env.device
    )
    return Agent(
        models=_models(env),
        memory=memory,
        cfg=cfg,
        observation_space=env.observation_space,
        state_space=getattr(env, "state_space", None),
        action_space=env.action_space,
        device=env.device,
    )


def _cpu():
    from skrl import config

    config.jax.device = "cpu"  # the CPU wheels: no GPU to look for


def train(timesteps: int, seed: int = 0, log=print, directory: Path | None = None, ppo=None):
    """PPO on the twist action (:data:`N_ENVS` envs; ``ppo`` replaces some of :data:`PPO`);
    returns the agent and the training episodes ``(env steps at the end, return, final rmse,
    success)``."""
    import gymnasium as gym
    from skrl.envs.wrappers.jax import wrap_env
    from skrl.trainers.jax import SequentialTrainer
    from skrl.utils import set_seed

    _cpu()
    set_seed(seed)
    episodes = _Episodes()
    venv = gym.vector.SyncVectorEnv([lambda: make_env(episodes)] * N_ENVS)
    venv.reset(seed=seed)
    env = wrap_env(venv, wrapper="gymnasium", verbose=False)
    agent = make_agent(env, directory, ppo)
    trainer = SequentialTrainer(
        cfg={
            "timesteps": timesteps // N_ENVS,
            "headless": True,
            "disable_progressbar": True,
            "close_environment_at_exit": False,  # closed below
        },
        env=env,
        agents=agent,
    )
    t0 = time.perf_counter()
    trainer.train()
    log(f"trained {episodes.steps} steps in {time.perf_counter() - t0:.0f} s")
    env.close()
    return agent, episodes.rows


def policy_of(agent):
    """The agent's deterministic policy ``(env, obs) -> action`` (its mean action, on the
    scaled observation)."""
    agent.enable_training_mode(False)

    def act(env, obs):
        _, out = agent.act(np.asarray(obs, np.float32)[None], None, timestep=0, timesteps=0)
        return np.asarray(out["mean_actions"][0], np.float32)

    return act


def load_policy(path):
    """The deterministic policy ``(env, obs) -> action`` saved by :func:`main` at ``path``
    (``policy.pickle``: the agent with its observation scaling)."""
    from skrl.envs.wrappers.jax import wrap_env

    _cpu()
    env = wrap_env(make_env(), wrapper="gymnasium", verbose=False)
    agent = make_agent(env, Path(path).parent)
    agent.init()
    agent.load(str(path))
    env.close()
    return policy_of(agent)


def ibvs_action(env, obs) -> np.ndarray:
    """The servo's own IBVS law on the observed points (the expert the agent competes with)."""
    e = env.unwrapped
    if obs[14] < 0.5:
        return np.zeros(6, np.float32)
    pts = obs[6:14].reshape(4, 2).astype(float) * e.point_scale
    twist = e.loop.servo.ibvs.twist(pts, e.desired_depths)
    return np.clip(np.asarray(twist) / e.scale, -1, 1).astype(np.float32)


def evaluate(policy, episodes: int) -> dict:
    """Success rate, final RMSE and return of ``policy(env, obs) -> action`` over the
    held-out seeds ``EVAL_SEED0 ...``."""
    env = make_env()
    succ, final, returns, ends = [], [], [], {}
    for k in range(episodes):
        obs, info = env.reset(seed=EVAL_SEED0 + k)
        ret, done = 0.0, False
        while not done:
            obs, r, term, trunc, info = env.step(policy(env, obs))
            ret += r
            done = term or trunc
        why = str(info["termination"]) if info["termination"] is not None else "truncated"
        ends[why] = ends.get(why, 0) + 1
        succ.append(bool(info["success"]))
        final.append(info["rmse"])
        returns.append(ret)
    env.close()
    f = np.asarray(final, float)
    return {
        "episodes": episodes,
        "success_rate": float(np.mean(succ)),
        "final_rmse_median": float(np.nanmedian(f)) if np.isfinite(f).any() else None,
        "return_mean": float(np.mean(returns)),
        "endings": ends,
    }


def plot_curve(episodes, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not episodes:
        return
    steps, ret, rmse, _ = (np.asarray(x, float) for x in zip(*episodes, strict=True))
    w = max(1, len(steps) // 20)
    smooth = lambda x: np.convolve(x, np.ones(w) / w, mode="valid")  # noqa: E731
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
    ax[0].plot(steps, ret, ".", alpha=0.3)
    ax[0].plot(steps[w - 1 :], smooth(ret))
    ax[0].set(xlabel="environment steps", ylabel="episode return", title="PPO, twist action")
    ok = np.isfinite(rmse)
    ax[1].semilogy(steps[ok], rmse[ok], ".", alpha=0.3)
    if ok.sum() >= w:
        ax[1].semilogy(steps[ok][w - 1 :], smooth(rmse[ok]))
    ax[1].axhline(TASK["success_rmse"], ls="--", c="k", lw=0.8)
    ax[1].set(xlabel="environment steps", ylabel="final RMSE (normalized)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(timesteps: int = 40_000, eval_episodes: int = 20, out="out/ppo", seed: int = 0, ppo=None):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    agent, episodes = train(timesteps, seed, directory=out, ppo=ppo)
    train_s = time.perf_counter() - t0
    agent.save(str(out / "policy.pickle"))
    ppo = policy_of(agent)
    results = {
        "task": TASK,
        "timesteps": timesteps,
        "train_wall_s": train_s,
        "training_episodes": len(episodes),
        "held_out_seeds": [EVAL_SEED0, EVAL_SEED0 + eval_episodes - 1],
        "ppo": evaluate(ppo, eval_episodes),
        "zero_twist": evaluate(lambda env, obs: np.zeros(6, np.float32), eval_episodes),
        "ibvs": evaluate(ibvs_action, eval_episodes),
    }
    plot_curve(episodes, out / "learning_curve.png")
    (out / "results.json").write_text(json.dumps(results, indent=2))
    for name in ("ppo", "zero_twist", "ibvs"):
        r = results[name]
        print(
            f"{name:10s} success {r['success_rate']:.2f}  final rmse (median) "
            f"{r['final_rmse_median']}  return {r['return_mean']:.1f}  {r['endings']}"
        )
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description="Train PPO (skrl on JAX) on the twist action of tdacm/TipServo-v0, save "
        "the policy and compare it with the zero twist and the IBVS law on held-out seeds.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--timesteps", type=int, default=40_000, help="environment steps")
    ap.add_argument("--eval-episodes", type=int, default=20, help="held-out episodes per policy")
    ap.add_argument("--out", default="out/ppo", help="output folder")
    ap.add_argument("--seed", type=int, default=0, help="seed of training")
    a = ap.parse_args()
    main(a.timesteps, a.eval_episodes, a.out, a.seed)
