"""Train a servoing policy with PPO (stable-baselines3) on the twist action of
``tdacm/TipServo-v0``, and compare its success rate with the zero-twist and the IBVS policies
on held-out seeds.

Needs the ``rl`` extra (``pip install 'tdacm[env,rl]'``; on a machine without a GPU install
the CPU build of torch first). Run::

    python examples/train_ppo.py --timesteps 40000 --out out/ppo

It writes ``learning_curve.png`` (the training episodes' return and final RMSE against the
environment steps) and ``results.json`` (success rates and final RMSE of the three policies on
the held-out seeds) into ``--out``. The task (:data:`TASK`): servo the paper-in-fov scenario
from its initial pose (noise 0.02 on q) until the normalized RMSE of the four points falls
below ``success_rmse`` within ``max_steps`` control periods. Training seeds are drawn from
seed 0's generator; evaluation uses seeds 10_000 and up, never seen in training.
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


def make_env():
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    return gym.make("tdacm/TipServo-v0", **TASK)


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


def train(timesteps: int, seed: int = 0, log=print):
    """PPO on the twist action; returns the model and the training episodes
    ``(env steps at the end, return, final rmse, success)``."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    torch.set_num_threads(1)
    episodes = []

    class Record(BaseCallback):
        def _on_step(self) -> bool:
            for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
                if done and "episode" in info:
                    episodes.append(
                        (self.num_timesteps, info["episode"]["r"], info["rmse"], info["success"])
                    )
            return True

    venv = make_vec_env(make_env, n_envs=2, seed=seed)
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=512,
        batch_size=128,
        n_epochs=10,
        learning_rate=3e-4,
        gamma=0.98,
        seed=seed,
        device="cpu",
        verbose=0,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=Record())
    log(f"trained {timesteps} steps in {time.perf_counter() - t0:.0f} s")
    venv.close()
    return model, episodes


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


def main(timesteps: int = 40_000, eval_episodes: int = 20, out="out/ppo", seed: int = 0):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    model, episodes = train(timesteps, seed)
    train_s = time.perf_counter() - t0

    def ppo(env, obs):
        return model.predict(obs, deterministic=True)[0]

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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timesteps", type=int, default=40_000)
    ap.add_argument("--eval-episodes", type=int, default=20)
    ap.add_argument("--out", default="out/ppo")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    main(a.timesteps, a.eval_episodes, a.out, a.seed)
