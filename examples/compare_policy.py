"""A learned policy beside the IBVS law on the same held-out seeds, on the batched engine
(analytic C_L, true state): success, final RMSE and time to an RMSE of 0.01, nominal and
under 1 and 3 px of pixel noise and 0, 1 and 2 frames of latency. Writes a Markdown table and
a figure. Run after ``examples/train_ppo.py``::

    python examples/compare_policy.py out/ppo/policy.npz --out out/compare
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np

#: the conditions (scenario overrides of the sensors) and their labels
CONDITIONS = {
    "nominal": None,
    "1 px noise": {"sensors": {"pixel_noise": 1.0}},
    "3 px noise": {"sensors": {"pixel_noise": 3.0}},
    "latency 1 frame": {"sensors": {"latency_steps": 1}},
    "latency 2 frames": {"sensors": {"latency_steps": 2}},
}


def _train_module():
    spec = importlib.util.spec_from_file_location(
        "train_ppo", Path(__file__).with_name("train_ppo.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def compare(policy_path, episodes: int = 100, seed0: int | None = None) -> dict:
    """``{condition: {"policy": evaluate(...), "ibvs": evaluate(...)}}`` on the seeds
    ``seed0 ...`` (default: the held-out ones, ``train_ppo.EVAL_SEED0``)."""
    tp = _train_module()
    seed0 = tp.EVAL_SEED0 if seed0 is None else seed0
    pol = tp.load_npz(policy_path)[0]
    res = {}
    for name, ov in CONDITIONS.items():
        res[name] = {
            "policy": tp.evaluate(pol, episodes, seed0, ov),
            "ibvs": tp.evaluate(None, episodes, seed0, ov),
        }
        p, i = res[name]["policy"], res[name]["ibvs"]
        print(f"{name}: policy {p['success_rate']:.2f}, ibvs {i['success_rate']:.2f}", flush=True)
    return res


def table(res) -> str:
    """The Markdown table of :func:`compare`'s result."""

    def fmt(x, f):
        return "-" if x is None else format(x, f)

    lines = [
        "| condition | policy: success | IBVS: success | policy: final RMSE (median) | "
        "IBVS: final RMSE (median) | policy: time to 0.01 (median, s) | "
        "IBVS: time to 0.01 (median, s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in res.items():
        p, i = r["policy"], r["ibvs"]
        lines.append(
            f"| {name} | {round(100 * p['success_rate'])} / {p['episodes']} | "
            f"{round(100 * i['success_rate'])} / {i['episodes']} | "
            f"{fmt(p['final_rmse_median'], '.4f')} | {fmt(i['final_rmse_median'], '.4f')} | "
            f"{fmt(p['time_to_0.01_median_s'], '.2f')} | {fmt(i['time_to_0.01_median_s'], '.2f')} |"
        )
    return "\n".join(lines)


def figure(res, path: Path) -> None:
    """Success rates per condition, and the final RMSE and time to 0.01 per seed (nominal)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(res)
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
    x = np.arange(len(names))
    for k, (who, c) in enumerate((("policy", "C0"), ("ibvs", "C1"))):
        ax[0].bar(x + (k - 0.5) * 0.38, [res[n][who]["success_rate"] for n in names], 0.38,
                  color=c, label="learned policy" if who == "policy" else "IBVS")  # fmt: skip
    ax[0].set_xticks(x, names, rotation=25, ha="right", fontsize=8)
    ax[0].set(ylabel="success rate (100 held-out seeds)", ylim=(0, 1.05))
    ax[0].legend(fontsize=8, loc="lower left")
    nom = res[names[0]]
    for j, key in ((1, "final_rmse"), (2, "time_to_0.01")):
        p = np.array([np.nan if v is None else v for v in nom["policy"][key]])
        i = np.array([np.nan if v is None else v for v in nom["ibvs"][key]])
        ax[j].scatter(i, p, s=10)
        ok = np.isfinite(p) & np.isfinite(i)
        if ok.any():
            lo, hi = min(p[ok].min(), i[ok].min()), max(p[ok].max(), i[ok].max())
            ax[j].plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax[j].set(
            xlabel=f"IBVS: {key.replace('_', ' ')}", ylabel=f"policy: {key.replace('_', ' ')}"
        )
        if key == "final_rmse":
            ax[j].set(xscale="log", yscale="log")
            ax[j].axhline(0.01, c="gray", lw=0.6)
            ax[j].axvline(0.01, c="gray", lw=0.6)
    ax[1].set_title("nominal, per seed", fontsize=9)
    ax[2].set_title("nominal, per seed (s)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy", help="a policy file (policy.npz of examples/train_ppo.py)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed0", type=int, default=None, help="first seed (default: held-out)")
    ap.add_argument("--out", default="out/compare")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    r = compare(a.policy, a.episodes, a.seed0)
    (out / "compare.json").write_text(json.dumps(r, indent=1))
    (out / "compare.md").write_text(table(r) + "\n")
    figure(r, out / "compare.png")
    print(table(r))
