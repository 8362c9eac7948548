"""Train a servoing policy with PPO (skrl on JAX) on the twist action of ``tdacm/TipServo-v0``
in its vector form on the batched engine, save it, and measure its success rate on held-out
seeds.

Needs the ``rl`` extra (``pip install 'tdacm[rl]'``: skrl, JAX and Flax, CPU wheels from PyPI,
no torch). Run::

    python examples/train_ppo.py --out out/ppo      # 13 minutes of training (--minutes)

The task (:data:`TASK`, the paper's): ``paper-in-fov`` from random initial poses (the
robustness campaigns' spread), success when the normalized RMSE is at or below 0.01 at the end
of the 5 s episode and has stayed there since it first got there (``hold_success``). The policy
maps the observation to the twist by itself (no IBVS twist in its input or output). The
servo is the shipped one (the robust servo's predicted features in the observation); the
training reward is :data:`SHAPING`'s (docs/env.md, "Learning").

It writes into ``--out``: ``learning_curve.png`` (the training episodes' success rate and final
RMSE against the environment steps and the wall time), ``results.json`` (the held-out success
rate and final RMSE), ``policy.pickle`` (the skrl agent) and ``policy.npz`` (the deterministic
policy as a policy file, run with numpy alone and by a scenario's ``[servo] policy``:
:func:`load_npz`). Training
seeds are ``--seed`` + world index; evaluation uses seeds ``EVAL_SEED0`` and up, never seen in
training.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

#: The robustness campaigns' initial spread of paper-in-fov (std on q; roll and pitch level),
#: ``examples/campaigns/paper-in-fov-200.toml``.
SPREAD = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)
#: The env's options for training and evaluation (docs/env.md, "Learning").
TASK = {"max_steps": 250, "success_rmse": 0.01, "hold_success": True, "init_noise": SPREAD}
EVAL_SEED0 = 10_000
#: worlds of the vector env stepped together
N_ENVS = 128
#: PPO's settings (skrl's PPO_CFG names): 32 steps per world per update (4,096 transitions),
#: the learning rate adapted to a KL divergence of 0.01 per update
PPO = {
    "rollouts": 32,
    "learning_epochs": 5,
    "mini_batches": 4,
    "discount_factor": 0.99,
    "gae_lambda": 0.95,
    "learning_rate": 1e-3,
    "kl_threshold": 0.0,
    "grad_norm_clip": 1.0,
    "ratio_clip": 0.2,
    "value_clip": 0.2,
    "entropy_loss_scale": 0.0,
    "value_loss_scale": 1.0,
    "time_limit_bootstrap": True,
}
#: the training's wall-time budget (minutes): the set-up, JAX's compilation and the training
#: within 15 minutes on two cores
MINUTES = 13.0
#: imitation before PPO: environment steps of the servo's own IBVS law (the teacher; the
#: policy then maps the observation to the twist by itself), the fit's Adam steps
IMITATION_STEPS = 32_000
IMITATION_ITERATIONS = 3_000
#: the learning rate's KL target (skrl's KLAdaptiveLR)
KL_TARGET = 0.01
#: the initial log standard deviation of the Gaussian policy's actions (in [-1, 1] units)
INIT_LOG_STD = -1.0
#: The training reward (docs/env.md, "Learning"), computed from each step's ``info`` by
#: :class:`Recorder`'s wrapper in place of the env's reward: per step ``-rmse / rmse_scale``
#: while the target is seen, plus ``near_bonus`` at or below ``near`` and ``inside_bonus`` at
#: or below the success threshold; ``-lost`` per step without the target; a failure ending
#: pays ``-lost`` for each step left; a successful end adds ``success_bonus``.
SHAPING = {
    "rmse_scale": 0.05,
    "near": 0.02,
    "near_bonus": 0.5,
    "inside_bonus": 1.0,
    "lost": 4.0,
    "success_bonus": 20.0,
}


def shaped_reward(info, steps, max_steps: int) -> np.ndarray:
    """:data:`SHAPING`'s reward of one vector step from its ``info`` (the worlds being reset
    this step get 0, as the env's own reward) and the worlds' step counts."""
    sh = SHAPING
    rmse = np.asarray(info["rmse"], float)
    seen = np.asarray(info["detected"], bool) & np.isfinite(rmse)
    r_ok = np.nan_to_num(rmse, nan=1.0)
    r = np.where(seen, -np.minimum(r_ok, 1.0) / sh["rmse_scale"], -sh["lost"])
    r += np.where(seen & (r_ok <= sh["near"]), sh["near_bonus"], 0.0)
    r += np.where(seen & (r_ok <= TASK["success_rmse"]), sh["inside_bonus"], 0.0)
    success = np.asarray(info["success"], bool)
    failed = np.array([t is not None for t in info["termination"]]) & ~success
    r += np.where(success, sh["success_bonus"], 0.0)
    r -= np.where(failed, sh["lost"] * (max_steps - np.asarray(steps)), 0.0)
    return np.where(np.asarray(info["_success"], bool), r, 0.0)


def make_env(num_envs: int = N_ENVS, **task):
    """The vector env of :data:`TASK` (``task`` replaces some of it)."""
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    return gym.make_vec(
        "tdacm/TipServo-v0",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        **{**TASK, **task},
    )


class OutOfTime(Exception):
    """The training's wall-time budget is spent (raised by :class:`Recorder`'s wrapper)."""


class Recorder:
    """The training episodes as the vector env ends them: ``(env steps, wall s, success,
    final rmse)``, read from the ``info`` of each step (a gymnasium wrapper that also gives
    :func:`shaped_reward` and stops the training after ``budget_s`` seconds)."""

    def __init__(self, env, budget_s: float = float("inf")):
        self.env = env
        self.rows = []
        self.steps = 0
        self.budget_s = budget_s
        self.t0 = time.perf_counter()

    def wrap(self):
        import gymnasium as gym

        rec = self

        class Record(gym.vector.VectorWrapper):
            def step(self, actions):
                obs, _, term, trunc, info = self.env.step(actions)
                u = self.env.unwrapped
                r = shaped_reward(info, u.steps, u.max_steps)
                rec.steps += len(r)
                wall = time.perf_counter() - rec.t0
                for w in np.flatnonzero(term | trunc):
                    rec.rows.append((rec.steps, wall, bool(info["success"][w]), info["rmse"][w]))
                if rec.steps // 50_000 != (rec.steps - len(r)) // 50_000 and rec.rows:
                    last = np.array([row[2] for row in rec.rows[-100:]], float)
                    print(
                        f"{rec.steps} steps, {wall:.0f} s: success {last.mean():.2f} "
                        f"(last {last.size} episodes)",
                        flush=True,
                    )
                if wall > rec.budget_s:
                    raise OutOfTime
                return obs, r, term, trunc, info

        return Record(self.env)


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
                "log_std", lambda _: jnp.full(self.num_actions, INIT_LOG_STD, dtype=jnp.float32)
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
    from skrl.resources.schedulers.jax import KLAdaptiveLR

    settings = {**PPO, **(ppo or {})}
    cfg = PPO_CFG(**settings)
    cfg.learning_rate_scheduler = KLAdaptiveLR
    cfg.learning_rate_scheduler_kwargs = {"kl_threshold": KL_TARGET}
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


def train(
    timesteps: int,
    seed: int = 0,
    log=print,
    directory: Path | None = None,
    ppo=None,
    num_envs: int = N_ENVS,
    minutes: float = float("inf"),
    imitation_steps: int = 0,
):
    """PPO on the twist action of :data:`TASK` on ``num_envs`` worlds (``ppo`` replaces some
    of :data:`PPO`) for ``timesteps`` environment steps or ``minutes`` of wall time, whichever
    ends first; returns the agent and the training episodes ``(env steps, wall s, success,
    final rmse)``. ``imitation_steps`` > 0: :func:`imitate` first (a warm start)."""
    from skrl.envs.wrappers.jax import wrap_env
    from skrl.trainers.jax import SequentialTrainer
    from skrl.utils import set_seed

    _cpu()
    set_seed(seed)
    t0 = time.perf_counter()
    venv = make_env(num_envs)
    rec = Recorder(venv, 60.0 * minutes)
    wrapped = rec.wrap()
    env = wrap_env(wrapped, wrapper="gymnasium", verbose=False)
    agent = make_agent(env, directory, ppo)
    if imitation_steps > 0:
        imitate(agent, venv, imitation_steps, IMITATION_ITERATIONS, seed, log)
        if directory is not None:
            probe = make_env(1)
            export_policy(agent, Path(directory) / "imitation.npz", probe.unwrapped, {})
            probe.close()
    wrapped.reset(seed=seed)
    trainer = SequentialTrainer(
        cfg={
            "timesteps": max(1, timesteps // num_envs),
            "headless": True,
            "disable_progressbar": True,
            "close_environment_at_exit": False,  # closed below
        },
        env=env,
        agents=agent,
    )
    rec.t0 = t0  # the budget counts the imitation too
    try:
        trainer.train()
    except OutOfTime:
        log(f"wall-time budget of {minutes:g} min spent")
    log(f"trained {rec.steps} steps in {time.perf_counter() - rec.t0:.0f} s")
    venv.close()
    return agent, rec.rows


def imitate(agent, venv, steps: int, iterations: int, seed: int, log=print) -> float:
    """Fit the policy's mean to the servo's IBVS twist (behaviour cloning, a warm start for
    PPO): ``steps`` environment steps of ``venv`` with the servo's own twist (NaN actions),
    the observation scaler updated with their observations, then ``iterations`` Adam steps
    (mini-batches of 1,024) on the squared error of the action in ``[-1, 1]`` units (the
    teacher's twist over the action scale, clipped to +-0.97). Returns the final loss."""
    import jax
    import jax.numpy as jnp
    import optax

    u = venv.unwrapped
    N = u.num_envs
    obs, _ = venv.reset(seed=seed)
    nan = np.full((N, 6), np.nan)
    X, Y = [], []
    for _ in range(max(1, steps // N)):
        stepping = ~u._autoreset
        o = obs.copy()
        obs, *_ = venv.step(nan)
        X.append(o[stepping])
        Y.append(u.batch.data.twist[stepping] / u.scale)
    X = jnp.asarray(np.concatenate(X), jnp.float32)
    Y = jnp.asarray(np.clip(np.concatenate(Y), -0.97, 0.97), jnp.float32)
    sc = agent._observation_preprocessor
    sc(X, train=True)
    Xs = sc(X)
    model = agent.models["policy"]
    opt = optax.adam(1e-3)
    params = model.state_dict.params
    state = opt.init(params)

    def loss(p, x, y):
        mean, _ = model.apply(p, {"observations": x}, "policy")
        return jnp.mean((mean - y) ** 2)

    @jax.jit
    def update(p, s, x, y):
        val, g = jax.value_and_grad(loss)(p, x, y)
        upd, s = opt.update(g, s, p)
        return optax.apply_updates(p, upd), s, val

    rng = np.random.default_rng(seed)
    val = float("nan")
    for i in range(iterations):
        idx = rng.integers(0, X.shape[0], 1024)
        params, state, val = update(params, state, Xs[idx], Y[idx])
        if i % 1000 == 0:
            log(f"imitation: {X.shape[0]} samples, iteration {i}, loss {float(val):.4g}")
    model.state_dict = model.state_dict.replace(params=params)
    log(f"imitation: final loss {float(val):.4g}")
    return float(val)


def export_policy(agent, path: Path, env_unwrapped, options: dict) -> Path:
    """The deterministic policy as a policy file (:func:`tdacm.loop.policy.save_policy`: the
    MLP's layers, tanh between and on the output, the observation scaling, the robot it was
    trained for, the action scale and the env options), loaded with numpy alone by
    :func:`tdacm.loop.policy.load_policy` or by a scenario's ``[servo] policy``."""
    from tdacm.loop.policy import save_policy
    from tdacm.sim.blocks import robot_signature

    params = agent.models["policy"].state_dict.params["params"]
    k = sum(1 for name in params if name.startswith("Dense_"))
    W = [np.asarray(params[f"Dense_{i}"]["kernel"]) for i in range(k)]
    b = [np.asarray(params[f"Dense_{i}"]["bias"]) for i in range(k)]
    sc = agent._observation_preprocessor
    u = env_unwrapped
    meta = {
        "robot": robot_signature(u.scenario.config, u.n, u.scenario.name),
        "action_scale": {"max_angular": float(u.scale[0]), "max_linear": float(u.scale[3])},
        "features": u.scenario.config.ibvs.features,
        "env_options": options,
    }
    return save_policy(path, W, b, sc.running_mean, sc.running_variance, meta)


def load_npz(path):
    """The deterministic policy ``obs (.., m) -> action (.., 6)`` of :func:`export_policy`'s
    file, numpy only (:func:`tdacm.loop.policy.load_policy`); and its metadata."""
    from tdacm.loop.policy import load_policy

    p = load_policy(path)
    return p, p.meta


def policy_of(agent):
    """The agent's deterministic policy ``obs (N, m) -> action (N, 6)`` (its mean action, on
    the scaled observation)."""
    agent.enable_training_mode(False)

    def act(obs):
        _, out = agent.act(np.asarray(obs, np.float32), None, timestep=0, timesteps=0)
        return np.asarray(out["mean_actions"], np.float32)

    return act


def evaluate(policy, episodes: int, seed0: int = EVAL_SEED0) -> dict:
    """Success rate and final RMSE of ``policy(obs) -> actions`` over the held-out seeds
    ``seed0 ... seed0 + episodes - 1``: one world per seed, its first episode."""
    env = make_env(episodes)
    obs, _ = env.reset(seed=seed0)
    done = np.zeros(episodes, bool)
    success = np.zeros(episodes, bool)
    final = np.full(episodes, np.nan)
    ends = {}
    while not done.all():
        obs, r, term, trunc, info = env.step(np.clip(policy(obs), -1, 1))
        for w in np.flatnonzero((term | trunc) & ~done):
            done[w] = True
            success[w] = bool(info["success"][w])
            final[w] = info["rmse"][w]
            t = info["termination"][w]
            why = str(t) if t is not None else "truncated"
            ends[why] = ends.get(why, 0) + 1
    env.close()
    return {
        "episodes": episodes,
        "seeds": [seed0, seed0 + episodes - 1],
        "success_rate": float(success.mean()),
        "final_rmse_median": float(np.nanmedian(final)) if np.isfinite(final).any() else None,
        "endings": ends,
    }


def evaluate_ibvs(episodes: int, seed0: int = EVAL_SEED0) -> dict:
    """The servo's own IBVS law on the held-out seeds of :func:`evaluate` (each world the
    same loop seed and initial pose as the env draws from seed ``seed0 + i``), on the batched
    engine, judged by the same criterion: RMSE at or below ``success_rmse`` at the last of the
    ``max_steps`` periods and at every period since it first got there."""
    from gymnasium.utils import seeding

    from tdacm.sim.batch import build_batch

    env = make_env(1)
    u = env.unwrapped
    seeds, q0 = [], []
    for i in range(episodes):
        rng, _ = seeding.np_random(seed0 + i)
        seeds.append(int(rng.integers(2**31)))
        q = u.q0 + rng.normal(0.0, u.init_noise, size=u.n)
        q[:2] = u.q0[:2]
        q0.append(q)
    steps = u.max_steps
    batch = build_batch(u.scenario, seeds, steps * float(u.scenario.data["dt"]), np.array(q0))
    env.close()
    res = batch.run()
    rmse = res.rmse[1 : steps + 1]  # the RMSE after each of the periods, as the env's steps
    thr = TASK["success_rmse"]
    success = np.zeros(episodes, bool)
    for w in range(episodes):
        r = rmse[:, w]
        inside = np.isfinite(r) & (r <= thr)
        if inside[-1] and res.termination[w] is None:
            success[w] = inside[np.argmax(inside) :].all()
    final = res.final_rmse
    return {
        "episodes": episodes,
        "seeds": [seed0, seed0 + episodes - 1],
        "success_rate": float(success.mean()),
        "final_rmse_median": float(np.nanmedian(final)),
        "terminated": int(sum(t is not None for t in res.termination)),
    }


def plot_curve(rows, path: Path) -> None:
    """Success rate and final RMSE of the training episodes against the env steps and the
    wall time (a moving window of 1/20 of the episodes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps, wall, ok, rmse = np.asarray(rows, float).reshape(-1, 4).T  # no rows: empty axes
    w = max(1, len(steps) // 20)

    def smooth(x):
        return np.convolve(x, np.ones(w) / w, mode="valid") if x.size >= w else x[:0]

    fig, ax = plt.subplots(2, 2, figsize=(9, 6))
    for j, (x, label) in enumerate(((steps, "environment steps"), (wall, "wall time (s)"))):
        ax[0, j].plot(x[w - 1 :], smooth(ok))
        ax[0, j].set(xlabel=label, ylabel="success rate", ylim=(-0.02, 1.02))
        fin = np.isfinite(rmse)
        ax[1, j].semilogy(x[fin], rmse[fin], ".", alpha=0.2)
        ax[1, j].axhline(TASK["success_rmse"], ls="--", c="k", lw=0.8)
        ax[1, j].set(xlabel=label, ylabel="final RMSE (normalized)")
    ax[0, 0].set_title(f"PPO, twist action, {len(rows)} training episodes")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(
    timesteps: int = 2_000_000,
    eval_episodes: int = 100,
    out="out/ppo",
    seed: int = 0,
    ppo=None,
    num_envs: int = N_ENVS,
    minutes: float = float("inf"),
    imitation_steps: int = 0,
):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    agent, rows = train(timesteps, seed, directory=out, ppo=ppo, num_envs=num_envs,
                        minutes=minutes, imitation_steps=imitation_steps)  # fmt: skip
    train_s = time.perf_counter() - t0
    agent.save(str(out / "policy.pickle"))
    env = make_env(1)
    export_policy(agent, out / "policy.npz", env.unwrapped, {"scenario": "paper-in-fov", **TASK})
    env.close()
    results = {
        "task": TASK,
        "timesteps": timesteps,
        "num_envs": num_envs,
        "steps_trained": int(rows[-1][0]) if rows else 0,
        "train_wall_s": train_s,
        "training_episodes": len(rows),
        "ppo": evaluate(policy_of(agent), eval_episodes),
        "imitation": evaluate(load_npz(out / "imitation.npz")[0], eval_episodes)
        if imitation_steps > 0
        else None,
        "ibvs": evaluate_ibvs(eval_episodes),
    }
    plot_curve(rows, out / "learning_curve.png")
    (out / "results.json").write_text(json.dumps(results, indent=2))
    for name in ("ppo", "imitation", "ibvs"):
        r = results[name]
        if r is None:
            continue
        print(
            f"{name}: success {r['success_rate']:.2f} on seeds {r['seeds']}, final rmse "
            f"(median) {r['final_rmse_median']}"
        )
    print(f"trained {train_s:.0f} s")
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description="Train PPO (skrl on JAX) on the twist action of tdacm/TipServo-v0 (vector "
        "env, batched engine), save the policy and measure it on held-out seeds.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--timesteps", type=int, default=2_000_000, help="environment steps")
    ap.add_argument(
        "--minutes", type=float, default=MINUTES, help="wall-time budget of the training"
    )
    ap.add_argument("--num-envs", type=int, default=N_ENVS, help="worlds stepped together")
    ap.add_argument("--eval-episodes", type=int, default=100, help="held-out episodes")
    ap.add_argument("--out", default="out/ppo", help="output folder")
    ap.add_argument("--seed", type=int, default=0, help="seed of training")
    ap.add_argument(
        "--imitation-steps", type=int, default=IMITATION_STEPS,
        help="steps of the servo's IBVS twist imitated before PPO (0: none)",
    )  # fmt: skip
    a = ap.parse_args()
    main(
        a.timesteps,
        a.eval_episodes,
        a.out,
        a.seed,
        num_envs=a.num_envs,
        minutes=a.minutes,
        imitation_steps=a.imitation_steps,
    )
