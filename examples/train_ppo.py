"""Train a servoing policy on the twist action of ``tdacm/TipServo-v0`` in its vector form on
the batched engine: imitation of the servo's IBVS law (DAgger) as a warm start, then PPO
(skrl on JAX); save it and measure it on held-out seeds.

Needs the ``rl`` extra (``pip install 'tdacm[rl]'``: skrl, JAX and Flax, CPU wheels from PyPI,
no torch). Run::

    python examples/train_ppo.py --out out/ppo      # 12 minutes of training (--minutes)

The task (:data:`TASK`, the paper's): ``paper-in-fov`` from random initial poses (the
robustness campaigns' spread), success when the normalized RMSE is at or below 0.01 at the end
of the 5 s episode and has stayed there since it first got there (``hold_success``). The policy
maps the observation to the twist by itself (no IBVS twist in its input or added to its
output): ``a = clip(clip(x L + c, -1, 1) + mlp(x), -1, 1)`` on the standardized observation
``x``, an exact linear path beside an MLP whose last layer starts at zero (docs/learning.md
says why).

The recipe (docs/learning.md):

1. **DAgger** (:func:`dagger`, :data:`DAGGER`): the IBVS law is the teacher. Round 0 runs the
   teacher itself; each later round runs the current policy on the domain-randomized worlds
   (:data:`RANDOMIZE`) and labels every state it visits with the twist the servo would command
   there (:func:`tdacm.envs.teacher.teacher_twists`); the policy is refitted on all the labels
   so far (Adam on the MLP, then the linear path solved exactly by weighted least squares).
2. **PPO** (:data:`PPO`, skrl) fine-tunes that policy on the shaped reward (:data:`SHAPING`),
   for the rest of the ``--minutes`` budget.
3. The policy kept is the better of the two on validation seeds (:data:`VAL_SEED0`, not the
   held-out ones).

It writes into ``--out``: ``learning_curve.png`` (the success rate and final RMSE against the
environment steps and the wall time), ``results.json``, ``policy.pickle`` (the skrl agent),
``policy.npz`` (the kept policy as a
policy file, run with numpy alone and by a scenario's ``[servo] policy``), ``dagger.npz`` and
``ppo.npz`` (the two candidates). Training seeds are ``--seed`` + world index; evaluation uses
seeds ``EVAL_SEED0`` and up, never seen in training or selection.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from tdacm.envs.options import RANDOMIZATION_LIMITS

#: The robustness campaigns' initial spread of paper-in-fov (std on q; roll and pitch level),
#: ``examples/campaigns/paper-in-fov-200.toml``.
SPREAD = (0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05)
#: The env's options for training and evaluation (docs/learning.md).
#: The action range is 1 rad/s and 1 m/s (the env's default, 0.5, clips the servo's descent:
#: the IBVS twist clipped to 0.5 succeeds on 26 of 32 development seeds, to 1 on 29 of 32 as
#: the servo itself).
TASK = {
    "max_steps": 250,
    "success_rmse": 0.01,
    "hold_success": True,
    "init_noise": SPREAD,
    "max_angular": 1.0,
    "max_linear": 1.0,
}
#: Domain randomization of the training worlds (env option ``randomize``, drawn at each reset):
#: rod stiffness and damping, masses and tendon moment arms within +-10 %, pixel noise 0-2 px,
#: dropout 0-10 %, latency 0-2 frames: the env's whole ranges. Evaluation runs the nominal task.
RANDOMIZE = dict(RANDOMIZATION_LIMITS)
#: held-out evaluation seeds (never used in training or selection) and validation seeds
#: (the choice between the DAgger and the PPO policy)
EVAL_SEED0 = 10_000
VAL_SEED0 = 20_000
VAL_EPISODES = 64
#: worlds of the vector env stepped together
N_ENVS = 128
#: the policy's MLP (hidden layers, tanh), beside the linear path
HIDDEN = (64, 64)
#: the observation entries the linear path reads: the feature error (entries 0:6; near the
#: goal the servo's twist is ``-lambda J^+ e``, linear in it; with the state entries too the
#: least-squares fit picks up their correlation with the twist in the training data and the
#: policy stalls short of the goal)
LINEAR_INPUTS = 6
#: DAgger: rounds (round 0 is the teacher's own), environment steps per round, Adam steps of
#: each refit (mini-batches of 2,048, learning rate 1e-3 decaying to 0), the RMSE floor of
#: the sample weights ``1 / max(rmse, floor)^2`` (the error allowed near the goal shrinks
#: with the twist there) and the RMSE below which the linear path is solved exactly
#: (:func:`fit`)
DAGGER = {
    "rounds": 6,
    "steps": 32_768,
    "iterations": 1_500,
    "batch": 2_048,
    "learning_rate": 1e-3,
    "rmse_floor": 0.01,
    "near": 0.03,
}
#: PPO's settings (skrl's PPO_CFG names): 32 steps per world per update (4,096 transitions);
#: a small learning rate adapted to a KL divergence of KL_TARGET per update (fine-tuning)
PPO = {
    "rollouts": 32,
    "learning_epochs": 5,
    "mini_batches": 4,
    "discount_factor": 0.99,
    "gae_lambda": 0.95,
    "learning_rate": 1e-4,
    "kl_threshold": 0.0,
    "grad_norm_clip": 1.0,
    "ratio_clip": 0.2,
    "value_clip": 0.2,
    "entropy_loss_scale": 0.0,
    "value_loss_scale": 1.0,
    "time_limit_bootstrap": True,
}
KL_TARGET = 0.002
#: the initial log standard deviation of the Gaussian policy's actions (in [-1, 1] units):
#: after the warm start (exp(-4) = 0.018, about the twist near the goal) and from scratch
INIT_LOG_STD = -4.0
SCRATCH_LOG_STD = -1.0
#: the training's wall-time budget (minutes): the set-up, JAX's compilation, DAgger and PPO;
#: with the choice between the two candidates (about 2 minutes under load) the policy file is
#: written within 15 minutes on two cores
MINUTES = 12.0
#: The PPO reward (docs/learning.md), computed from each step's ``info`` by
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


def make_env(num_envs: int = N_ENVS, randomize=None, **task):
    """The vector env of :data:`TASK` (``task`` replaces some of it), with ``randomize``'s
    domain randomization (None: off)."""
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    extra = {"randomize": randomize} if randomize else {}
    return gym.make_vec(
        "tdacm/TipServo-v0",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        **{**TASK, **task},
        **extra,
    )


class OutOfTime(Exception):
    """The training's wall-time budget is spent (raised by :class:`Recorder`'s wrapper)."""


class Recorder:
    """The training episodes as the vector env ends them: ``(env steps, wall s, success,
    final rmse, phase)`` (phase 0: DAgger, 1: PPO), read from the ``info`` of each step (a
    gymnasium wrapper that also gives :func:`shaped_reward` and stops the training after
    ``budget_s`` seconds)."""

    def __init__(self, budget_s: float = float("inf")):
        self.rows = []
        self.steps = 0
        self.budget_s = budget_s
        self.t0 = time.perf_counter()
        self.phase = 0

    def record(self, info, term, trunc, n: int) -> float:
        """Count ``n`` env steps and the episodes that ended; returns the wall time."""
        self.steps += n
        wall = time.perf_counter() - self.t0
        for w in np.flatnonzero(term | trunc):
            self.rows.append(
                (self.steps, wall, bool(info["success"][w]), info["rmse"][w], self.phase)
            )
        return wall

    def wrap(self, venv):
        import gymnasium as gym

        rec = self

        class Record(gym.vector.VectorWrapper):
            def step(self, actions):
                obs, _, term, trunc, info = self.env.step(actions)
                u = self.env.unwrapped
                r = shaped_reward(info, u.steps, u.max_steps)
                before = rec.steps
                wall = rec.record(info, term, trunc, len(r))
                if rec.steps // 50_000 != before // 50_000 and rec.rows:
                    last = np.array([row[2] for row in rec.rows[-100:]], float)
                    print(
                        f"PPO: {rec.steps} steps, {wall:.0f} s: success {last.mean():.2f} "
                        f"(last {last.size} episodes)",
                        flush=True,
                    )
                if wall > rec.budget_s:
                    raise OutOfTime
                return obs, r, term, trunc, info

        return Record(venv)


# ----------------------------------------------------------------------------- the policy
def _mean_net(x, mean, std, num_actions: int):
    """The policy's mean action of raw observations ``x``: ``clip(x L + c, -1, 1) + mlp(x)``
    on ``clip((x - mean) / std, +-5)`` (flax, inside a compact module; the MLP's last layer
    starts at zero)."""
    import flax.linen as nn
    import jax.numpy as jnp

    xs = jnp.clip((x - mean) / std, -5.0, 5.0)
    lin = jnp.clip(nn.Dense(num_actions, name="linear")(xs[..., :LINEAR_INPUTS]), -1.0, 1.0)
    h = xs
    for i, k in enumerate(HIDDEN):
        h = nn.tanh(nn.Dense(k, name=f"hidden_{i}")(h))
    zeros = nn.initializers.zeros
    out = nn.Dense(num_actions, name="out", kernel_init=zeros, bias_init=zeros)(h)
    return lin + out


def _models(env, mean, std, log_std: float):
    """The policy (Gaussian around :func:`_mean_net`, a fixed observation scaling ``mean``,
    ``std``) and the value function (MLP 64-64 on the same scaling)."""
    import flax.linen as nn
    import jax.numpy as jnp
    from skrl.models.jax import DeterministicMixin, GaussianMixin, Model

    spaces = dict(
        observation_space=env.observation_space,
        state_space=getattr(env, "state_space", None),
        action_space=env.action_space,
        device=env.device,
    )
    m = jnp.asarray(mean, jnp.float32)
    s = jnp.asarray(std, jnp.float32)

    class Policy(GaussianMixin, Model):
        def __init__(self, **kw):
            Model.__init__(self, **kw)
            GaussianMixin.__init__(self, clip_actions=True, reduction="sum")

        @nn.compact
        def __call__(self, inputs, role):
            mu = _mean_net(inputs["observations"], m, s, self.num_actions)
            ls = self.param("log_std", lambda _: jnp.full(self.num_actions, log_std, jnp.float32))
            return mu, {"log_std": ls}

    class Value(DeterministicMixin, Model):
        def __init__(self, **kw):
            Model.__init__(self, **kw)
            DeterministicMixin.__init__(self)

        @nn.compact
        def __call__(self, inputs, role):
            x = jnp.clip((inputs["observations"] - m) / s, -5.0, 5.0)
            x = nn.tanh(nn.Dense(64)(x))
            x = nn.tanh(nn.Dense(64)(x))
            return nn.Dense(1)(x), {}

    models = {"policy": Policy(**spaces), "value": Value(**spaces)}
    for role, model in models.items():
        model.init_state_dict(role=role)
    return models


def make_agent(env, mean, std, directory: Path | None = None, ppo=None, log_std=INIT_LOG_STD):
    """skrl's PPO with :data:`PPO`'s settings (``ppo`` replaces some) on ``env`` (a wrapped
    skrl env); the observations scaled by the fixed ``mean``, ``std`` inside the models (the
    policy file's scaling), the values by their running mean and variance."""
    from skrl.agents.jax.ppo import PPO as Agent
    from skrl.agents.jax.ppo import PPO_CFG
    from skrl.memories.jax import RandomMemory
    from skrl.resources.preprocessors.jax import RunningStandardScaler
    from skrl.resources.schedulers.jax import KLAdaptiveLR

    settings = {**PPO, **(ppo or {})}
    cfg = PPO_CFG(**settings)
    cfg.learning_rate_scheduler = KLAdaptiveLR
    cfg.learning_rate_scheduler_kwargs = {"kl_threshold": KL_TARGET}
    cfg.value_preprocessor = RunningStandardScaler
    cfg.value_preprocessor_kwargs = {"size": 1, "device": env.device}
    cfg.experiment.write_interval = 0  # no TensorBoard files
    cfg.experiment.checkpoint_interval = 0
    cfg.experiment.directory = str(directory or Path("out") / "ppo")
    memory = RandomMemory(
        memory_size=settings["rollouts"], num_envs=env.num_envs, device=env.device
    )
    return Agent(
        models=_models(env, mean, std, log_std),
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


def numpy_policy(params, mean, std):
    """The deterministic policy of the flax ``params`` (:func:`_mean_net`'s) with numpy:
    ``obs (N, m) -> action (N, 6)`` in ``[-1, 1]`` (as :class:`tdacm.loop.policy.Policy`)."""
    from tdacm.loop.policy import Policy

    return Policy(*_layers(params), np.asarray(mean, float), np.asarray(std, float), {},
                  _linear(params))  # fmt: skip


def _layers(params):
    p = params["params"] if "params" in params else params
    names = [f"hidden_{i}" for i in range(len(HIDDEN))] + ["out"]
    W = tuple(np.asarray(p[k]["kernel"], float) for k in names)
    b = tuple(np.asarray(p[k]["bias"], float) for k in names)
    return W, b


def _linear(params):
    """``(L, c)`` of the policy file: the linear path's kernel padded with zero rows for the
    entries it does not read."""
    p = params["params"] if "params" in params else params
    k = np.asarray(p["linear"]["kernel"], float)
    m = np.asarray(p["hidden_0"]["kernel"]).shape[0]
    L = np.zeros((m, k.shape[1]))
    L[: k.shape[0]] = k
    return L, np.asarray(p["linear"]["bias"], float)


# ----------------------------------------------------------------------------- DAgger
def rollout(venv, act, steps: int, seed: int, rec: Recorder | None = None):
    """``steps`` environment steps of ``venv`` acting with ``act(obs) -> actions`` (None:
    the servo's own IBVS twist, NaN actions), each state the worlds observe labelled by the
    teacher (:func:`tdacm.envs.teacher.teacher_twists`, in action units, clipped to
    ``[-1, 1]``). Returns the observations (k, m), the labels (k, 6) and the RMSE (k,) of the
    states with features."""
    from tdacm.envs.teacher import teacher_twists

    u = venv.unwrapped
    N = u.num_envs
    obs, info = venv.reset(seed=seed)
    rmse = np.asarray(info["rmse"], float)
    nan = np.full((N, 6), np.nan)
    X, Y, R = [], [], []
    for _ in range(max(1, steps // N)):
        label = teacher_twists(venv) / u.scale
        ok = ~u._autoreset & np.isfinite(label).all(axis=1) & np.isfinite(rmse)
        X.append(obs[ok])
        Y.append(np.clip(label[ok], -1.0, 1.0))
        R.append(rmse[ok])
        a = nan if act is None else np.clip(act(obs), -1.0, 1.0)
        obs, _, term, trunc, info = venv.step(a)
        rmse = np.asarray(info["rmse"], float)
        if rec is not None:
            rec.record(info, term, trunc, N)
    return np.concatenate(X), np.concatenate(Y), np.concatenate(R)


def _mlp_np(p, xs):
    """The MLP part of :func:`_mean_net` with numpy on scaled observations ``xs``."""
    W, b = _layers(p)
    h = xs
    for i, (Wi, bi) in enumerate(zip(W, b, strict=True)):
        h = h @ Wi + bi
        if i < len(W) - 1:
            h = np.tanh(h)
    return h


def _solve_linear(xs, target, near):
    """The linear path ``L, c`` fitted exactly (least squares) to ``target`` on the near-goal
    samples ``near`` (all samples if too few)."""
    import jax.numpy as jnp

    if near.sum() < 4 * xs.shape[1]:
        near = np.ones(len(xs), bool)
    A = np.c_[xs[near, :LINEAR_INPUTS], np.ones(near.sum())]
    coef = np.linalg.lstsq(A, target[near], rcond=None)[0]
    return {"kernel": jnp.asarray(coef[:-1], jnp.float32),
            "bias": jnp.asarray(coef[-1], jnp.float32)}  # fmt: skip


def fit(params, X, Y, R, mean, std, iterations: int, seed: int, log=print):
    """Refit the policy's flax ``params`` to the labels ``Y`` of the observations ``X``
    (RMSE ``R``): the linear path first solved by least squares on the near-goal samples
    (``R <= DAGGER["near"]``), where the teacher's twist is affine in the observation; then
    Adam on the squared action error of the whole policy, weighted by
    ``1 / max(rmse, rmse_floor)^2`` (normalized; mini-batches of ``DAGGER["batch"]``, a
    learning rate decaying to 0); then the linear path solved again on the near-goal samples
    for what the MLP leaves there, so that near the goal the policy is the least-squares fit.
    Returns the new params."""
    import flax.linen as nn
    import jax
    import jax.numpy as jnp
    import optax

    class Net(nn.Module):
        @nn.compact
        def __call__(self, x):
            return _mean_net(x, jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32), 6)

    net = Net()
    xs = np.clip((X - mean) / std, -5.0, 5.0)
    near = R <= DAGGER["near"]
    p = {"params": {k: v for k, v in params["params"].items() if k != "log_std"}}
    if "solved" not in params:  # the first fit: the linear path from the near-goal samples
        p["params"]["linear"] = _solve_linear(xs, Y - _mlp_np(p, xs), near)
    w = 1.0 / np.maximum(R, DAGGER["rmse_floor"]) ** 2
    w = w / w.mean()
    Xj, Yj, wj = (jnp.asarray(a, jnp.float32) for a in (X, Y, w))
    sched = optax.cosine_decay_schedule(DAGGER["learning_rate"], max(1, iterations))
    opt = optax.adam(sched)
    state = opt.init(p)

    def loss(pp, x, y, ww):
        return jnp.mean(ww * jnp.sum((net.apply(pp, x) - y) ** 2, axis=1))

    @jax.jit
    def update(pp, s, x, y, ww):
        val, g = jax.value_and_grad(loss)(pp, x, y, ww)
        upd, s = opt.update(g, s, pp)
        return optax.apply_updates(pp, upd), s, val

    rng = np.random.default_rng(seed)
    B = min(DAGGER["batch"], X.shape[0])
    for _ in range(iterations):
        idx = rng.integers(0, X.shape[0], B)
        p, state, _ = update(p, state, Xj[idx], Yj[idx], wj[idx])
    p = {"params": dict(p["params"])}
    p["params"]["linear"] = _solve_linear(xs, Y - _mlp_np(p, xs), near)
    new = dict(params["params"])
    new.update(p["params"])
    pred = numpy_policy({"params": new}, mean, std)(X)
    err = np.sum((pred - Y) ** 2, axis=1)
    log(
        f"DAgger fit: {X.shape[0]} labels, mse {err.mean():.3g} (near the goal "
        f"{err[near].mean() if near.any() else np.nan:.3g}, {near.sum()} labels)"
    )
    return {"params": new, "solved": True}


def dagger(venv, params, mean, std, seed: int, rec: Recorder, deadline: float, log=print):
    """:data:`DAGGER`'s rounds on ``venv`` (module docstring), within ``deadline`` (a
    ``perf_counter`` time). Round 0's labels (the teacher's own run) are given; returns the
    params and the rounds run."""
    X, Y, R = params.pop("_data")
    rounds = 1
    params = fit(params, X, Y, R, mean, std, DAGGER["iterations"], seed, log)
    for k in range(1, DAGGER["rounds"]):
        if time.perf_counter() > deadline:
            log("DAgger: wall-time budget spent")
            break
        act = numpy_policy(params, mean, std)
        x, y, r = rollout(venv, act, DAGGER["steps"], seed + 1000 * k, rec)
        X, Y, R = np.r_[X, x], np.r_[Y, y], np.r_[R, r]
        params = fit(params, X, Y, R, mean, std, DAGGER["iterations"], seed + k, log)
        rounds += 1
        done = [row for row in rec.rows if row[4] == 0][-N_ENVS:]
        ok = np.mean([row[2] for row in done]) if done else np.nan
        log(f"DAgger round {k}: training episodes' success {ok:.2f}, "
            f"{time.perf_counter() - rec.t0:.0f} s")  # fmt: skip
    return params, rounds


# ----------------------------------------------------------------------------- training
def train(
    timesteps: int,
    seed: int = 0,
    log=print,
    directory: Path | None = None,
    ppo=None,
    num_envs: int = N_ENVS,
    minutes: float = float("inf"),
    dagger_rounds: int = DAGGER["rounds"],
    randomize=RANDOMIZE,
):
    """DAgger (``dagger_rounds`` > 0; 0: PPO from scratch) then PPO on ``num_envs``
    domain-randomized worlds (``ppo`` replaces some of :data:`PPO`) for ``timesteps`` PPO
    steps or ``minutes`` of wall time in all, whichever ends first. Returns the DAgger policy
    (None from scratch) and the PPO agent as ``(params, mean, std)`` / agent, and the
    :class:`Recorder`."""
    import jax.numpy as jnp
    from skrl.envs.wrappers.jax import wrap_env
    from skrl.trainers.jax import SequentialTrainer
    from skrl.utils import set_seed

    _cpu()
    set_seed(seed)
    rec = Recorder(60.0 * minutes)
    venv = make_env(num_envs, randomize)
    # the observation scaling (fixed: the policy file's): the teacher's states, or from
    # scratch those of random twists
    if dagger_rounds > 0:
        X, Y, R = rollout(venv, None, DAGGER["steps"], seed, rec)
        data = (X, Y, R)
    else:
        rng = np.random.default_rng(seed)
        X, _, _ = rollout(venv, lambda o: rng.uniform(-1, 1, (o.shape[0], 6)), 4096, seed, rec)
    mean = X.mean(axis=0)
    var = X.var(axis=0) + 1e-4  # constant entries (the detection flag) stay bounded
    std = np.sqrt(var) + 1e-8
    log(f"observation scaling from {X.shape[0]} states, {time.perf_counter() - rec.t0:.0f} s")

    wrapped = rec.wrap(venv)
    env = wrap_env(wrapped, wrapper="gymnasium", verbose=False)
    agent = make_agent(env, mean, std, directory, ppo,
                       INIT_LOG_STD if dagger_rounds > 0 else SCRATCH_LOG_STD)  # fmt: skip
    imitated = None
    if dagger_rounds > 0:
        model = agent.models["policy"]
        params = {"params": dict(model.state_dict.params["params"]), "_data": data}
        old = DAGGER["rounds"]
        DAGGER["rounds"] = dagger_rounds
        try:
            deadline = rec.t0 + 0.6 * rec.budget_s
            params, rounds = dagger(venv, params, mean, std, seed, rec, deadline, log)
        finally:
            DAGGER["rounds"] = old
        p = dict(params["params"])
        p["linear"] = {k: jnp.asarray(v) for k, v in p["linear"].items()}
        model.state_dict = model.state_dict.replace(params={"params": p})
        imitated = (params, mean, std)
        log(f"DAgger: {rounds} rounds, {rec.steps} env steps, "
            f"{time.perf_counter() - rec.t0:.0f} s")  # fmt: skip
    rec.phase = 1
    rec.ppo_start = (rec.steps, time.perf_counter() - rec.t0)
    wrapped.reset(seed=seed + 100_000)
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
    try:
        trainer.train()
    except OutOfTime:
        log(f"wall-time budget of {minutes:g} min spent")
    log(f"trained {rec.steps} env steps in {time.perf_counter() - rec.t0:.0f} s")
    venv.close()
    return imitated, (agent, mean, std), rec


def agent_params(agent):
    """The PPO agent's policy params (flax)."""
    return agent.models["policy"].state_dict.params


def export_policy(params, mean, std, path: Path, options: dict) -> Path:
    """The deterministic policy as a policy file (:func:`tdacm.loop.policy.save_policy`,
    format 2: the linear path, the MLP, the observation scaling, the robot it was trained
    for, the action scale and the training options), loaded with numpy alone by
    :func:`tdacm.loop.policy.load_policy` or by a scenario's ``[servo] policy``."""
    from tdacm.loop.policy import save_policy
    from tdacm.sim.blocks import robot_signature

    env = make_env(1)
    u = env.unwrapped
    meta = {
        "robot": robot_signature(u.scenario.config, u.n, u.scenario.name),
        "action_scale": {"max_angular": float(u.scale[0]), "max_linear": float(u.scale[3])},
        "features": u.scenario.config.ibvs.features,
        "env_options": options,
    }
    env.close()
    W, b = _layers(params)
    var = (np.asarray(std, float) - 1e-8) ** 2
    return save_policy(path, W, b, mean, var, meta, linear=_linear(params))


def load_npz(path):
    """The deterministic policy ``obs (.., m) -> action (.., 6)`` of :func:`export_policy`'s
    file, numpy only (:func:`tdacm.loop.policy.load_policy`); and its metadata."""
    from tdacm.loop.policy import load_policy

    p = load_policy(path)
    return p, p.meta


def policy_of(agent):
    """The agent's deterministic policy ``obs (N, m) -> action (N, 6)`` (its mean action)."""
    agent.enable_training_mode(False)

    def act(obs):
        _, out = agent.act(np.asarray(obs, np.float32), None, timestep=0, timesteps=0)
        return np.asarray(out["mean_actions"], np.float32)

    return act


# ----------------------------------------------------------------------------- evaluation
def evaluate(policy, episodes: int, seed0: int = EVAL_SEED0, overrides=None) -> dict:
    """Success rate, final RMSE and time to an RMSE of 0.01 of ``policy(obs) -> actions``
    (None: the servo's own IBVS twist) over the seeds ``seed0 ... seed0 + episodes - 1``: one
    world per seed, its first episode, on the batched engine (analytic C_L, true state);
    ``overrides``: scenario overrides (e.g. ``{"sensors": {"pixel_noise": 3.0}}``)."""
    env = make_env(episodes, **({"overrides": overrides} if overrides else {}))
    dt = float(env.unwrapped.scenario.data["dt"])
    obs, _ = env.reset(seed=seed0)
    done = np.zeros(episodes, bool)
    success = np.zeros(episodes, bool)
    final = np.full(episodes, np.nan)
    first = np.full(episodes, np.nan)
    ends = {}
    nan = np.full((episodes, 6), np.nan)
    k = 0
    while not done.all():
        a = nan.copy() if policy is None else np.clip(policy(obs), -1, 1)
        a[done] = 0.0 if policy is not None else np.nan  # finished worlds: ignored
        obs, r, term, trunc, info = env.step(a)
        k += 1
        with np.errstate(invalid="ignore"):
            hit = ~done & np.isnan(first) & (info["rmse"] <= TASK["success_rmse"])
        first[hit] = k * dt
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
        "time_to_0.01_median_s": float(np.nanmedian(first)) if np.isfinite(first).any() else None,
        "reached_0.01": int(np.isfinite(first).sum()),
        "endings": ends,
        "success": success.tolist(),
        "final_rmse": [None if not np.isfinite(x) else float(x) for x in final],
        "time_to_0.01": [None if not np.isfinite(x) else float(x) for x in first],
    }


def plot_curve(rows, path: Path, ppo_start=None, evals=None) -> None:
    """Success rate and final RMSE of the training episodes against the env steps and the
    wall time (a moving window of 1/20 of the episodes; DAgger then PPO, the line between);
    ``evals``: ``(steps, wall, validation success)`` points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps, wall, ok, rmse, _ = np.asarray(rows, float).reshape(-1, 5).T  # no rows: empty
    w = max(1, len(steps) // 20)

    def smooth(x):
        return np.convolve(x, np.ones(w) / w, mode="valid") if x.size >= w else x[:0]

    fig, ax = plt.subplots(2, 2, figsize=(9, 6))
    for j, (x, label) in enumerate(((steps, "environment steps"), (wall, "wall time (s)"))):
        ax[0, j].plot(x[w - 1 :], smooth(ok), label="training episodes (randomized)")
        if evals:
            ax[0, j].plot([e[j] for e in evals], [e[2] for e in evals], "o", c="C3",
                          label="validation seeds (nominal)")  # fmt: skip
        ax[0, j].set(xlabel=label, ylabel="success rate", ylim=(-0.02, 1.02))
        fin = np.isfinite(rmse)
        ax[1, j].semilogy(x[fin], rmse[fin], ".", alpha=0.2)
        ax[1, j].axhline(TASK["success_rmse"], ls="--", c="k", lw=0.8)
        ax[1, j].set(xlabel=label, ylabel="final RMSE (normalized)")
        if ppo_start is not None:
            for i in range(2):
                ax[i, j].axvline(ppo_start[j], c="gray", lw=0.8, ls=":")
    ax[0, 0].legend(fontsize=7, loc="lower right")
    ax[0, 0].set_title(f"DAgger then PPO (dotted line), {len(rows)} training episodes",
                       fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(
    timesteps: int = 5_000_000,
    eval_episodes: int = 100,
    out="out/ppo",
    seed: int = 0,
    ppo=None,
    num_envs: int = N_ENVS,
    minutes: float = MINUTES,
    dagger_rounds: int = DAGGER["rounds"],
    val_episodes: int = VAL_EPISODES,
    randomize=RANDOMIZE,
):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    imitated, (agent, mean, std), rec = train(
        timesteps, seed, directory=out, ppo=ppo, num_envs=num_envs, minutes=minutes,
        dagger_rounds=dagger_rounds, randomize=randomize,
    )  # fmt: skip
    train_s = time.perf_counter() - t0
    agent.save(str(out / "policy.pickle"))
    opts = {"scenario": "paper-in-fov", **TASK, "randomize": randomize or {}}
    candidates = {"ppo": (agent_params(agent), mean, std)}
    if imitated is not None:
        candidates["dagger"] = imitated
    val, evals = {}, []
    for name, (params, m, s) in candidates.items():
        export_policy(params, m, s, out / f"{name}.npz", opts)
        pol = load_npz(out / f"{name}.npz")[0]
        val[name] = evaluate(pol, val_episodes, VAL_SEED0)["success_rate"]
        print(f"{name}: validation success {val[name]:.2f} (seeds {VAL_SEED0}+)")
    # the kept policy: PPO's unless the DAgger policy does better on the validation seeds
    kept = "ppo" if val["ppo"] >= val.get("dagger", -1.0) else "dagger"
    select_s = time.perf_counter() - t0 - train_s
    (out / "policy.npz").write_bytes((out / f"{kept}.npz").read_bytes())
    if "dagger" in val:
        evals.append((*rec.ppo_start, val["dagger"]))
    if rec.rows:
        evals.append((rec.steps, train_s, val["ppo"]))
    plot_curve(rec.rows, out / "learning_curve.png", rec.ppo_start if imitated else None, evals)
    results = {
        "task": TASK,
        "randomize": randomize,
        "num_envs": num_envs,
        "env_steps": rec.steps,
        "ppo_start": {"env_steps": rec.ppo_start[0], "wall_s": rec.ppo_start[1]},
        "train_wall_s": train_s,
        "selection_wall_s": select_s,
        "validation_success": val,
        "kept": kept,
        "training_episodes": [list(map(float, r)) for r in rec.rows],
        "policy": evaluate(load_npz(out / "policy.npz")[0], eval_episodes),
        "ibvs": evaluate(None, eval_episodes),
    }
    (out / "results.json").write_text(json.dumps(results, indent=1))
    for name in ("policy", "ibvs"):
        r = results[name]
        print(
            f"{name}: success {r['success_rate']:.2f} on seeds {r['seeds']}, final rmse "
            f"(median) {r['final_rmse_median']}, endings {r['endings']}"
        )
    print(f"kept {kept}; trained {train_s:.0f} s, selection {select_s:.0f} s")
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description="Train a servoing policy (DAgger on the IBVS law, then PPO with skrl on "
        "JAX) on the twist action of tdacm/TipServo-v0 (vector env, batched engine), save it "
        "and measure it on held-out seeds.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--timesteps", type=int, default=5_000_000, help="PPO environment steps")
    ap.add_argument(
        "--minutes", type=float, default=MINUTES, help="wall-time budget of the training"
    )
    ap.add_argument("--num-envs", type=int, default=N_ENVS, help="worlds stepped together")
    ap.add_argument("--eval-episodes", type=int, default=100, help="held-out episodes")
    ap.add_argument("--out", default="out/ppo", help="output folder")
    ap.add_argument("--seed", type=int, default=0, help="seed of training")
    ap.add_argument(
        "--dagger-rounds", type=int, default=DAGGER["rounds"],
        help="DAgger rounds before PPO (0: PPO from scratch)",
    )  # fmt: skip
    ap.add_argument("--no-randomize", action="store_true", help="train on the nominal task")
    a = ap.parse_args()
    main(
        a.timesteps,
        a.eval_episodes,
        a.out,
        a.seed,
        num_envs=a.num_envs,
        minutes=a.minutes,
        dagger_rounds=a.dagger_rounds,
        randomize=None if a.no_randomize else RANDOMIZE,
    )
