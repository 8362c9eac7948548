"""Campaign report: success rate with a Wilson interval, distributions, worst runs, plots, and
the sensitivity to each sampled parameter (``sensitivity/KEY.png``: final error and success
against the sampled value, a panel per component that varies)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .store import read_results


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion (good at small n and near 0 or 1)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def _stats(x):
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None
    return {
        "n": int(x.size),
        "median": float(np.median(x)),
        "p5": float(np.percentile(x, 5)),
        "p95": float(np.percentile(x, 95)),
        "max": float(x.max()),
    }


def _first_line(text) -> str:
    return text.splitlines()[0] if isinstance(text, str) and text else ""


def replay_command(spec, out, run: int, seed: int) -> str:
    """The ``tdacm run`` command that reproduces stored run ``run``: the spec's scenario,
    the run's sampled overrides (``OUT/configs/run-NNNNNN.toml``, an absolute path: the command
    works from any folder), its seed, and the spec's duration when it sets one."""
    import shlex

    cfg = (Path(out) / "configs" / f"run-{run:06d}.toml").resolve()
    cmd = ["tdacm", "run", spec.scenario, "--config", str(cfg), "--seed", str(seed)]
    if spec.duration is not None:
        cmd += ["--duration", repr(float(spec.duration))]
    return shlex.join(cmd)


def hold_outcome(row, spec) -> str:
    """A contact run's outcome in words (``spec.success_hold_force_rms`` set): ``held``, the
    termination that ended it (``ended: safety``, ...), ``no hold``, or the rule the hold
    broke (``force``: its RMS error over the limit; ``image``: the task's image error over
    ``success_rmse``; ``short``: cut short), several joined by ``+``."""

    def num(k):
        v = row.get(k)
        return float(v) if v is not None and np.isfinite(float(v)) else float("nan")

    if bool(row.get("success")):
        return "held"
    if row.get("status") == "error":
        return "error"
    if bool(row.get("terminated")):
        return f"ended: {row.get('termination') or 'early'}"
    if not num("hold_duration") > 0:
        return "no hold"
    broke = []
    if not num("hold_force_rms_rel") <= spec.success_hold_force_rms:
        broke.append("force")
    if not num("hold_image_error_max") <= spec.success_rmse:
        broke.append("image")
    return "+".join(broke) or "short"


def hold_runs(df, spec) -> list[dict]:
    """Per run of a contact campaign: its outcome (:func:`hold_outcome`), the hold's length,
    the true force's RMS error (relative), the force estimate's RMS error (N), the task's image
    error (measured and true C_L, max over the hold) and the largest contact force."""
    keys = ("landings", "hold_duration", "hold_force_rms_rel", "hold_force_estimate_error_rms",
            "hold_image_error_max", "hold_image_error_true_max", "max_contact_force")  # fmt: skip
    out = []
    for _, r in df.iterrows():
        row = r.to_dict()
        item = {
            "run": int(row["run"]),
            "seed": int(row["seed"]),
            "outcome": hold_outcome(row, spec),
        }
        for k in keys:
            v = row.get(k)
            item[k] = None if v is None or not np.isfinite(float(v)) else float(v)
        out.append(item)
    return out


def write_report(spec, out, n_worst: int = 5) -> dict:
    """Write ``report.json``, ``report.md`` and ``report.png`` and return the report dict."""
    out = Path(out)
    df = read_results(out)
    n = len(df)
    ok = int(df["success"].sum()) if n else 0
    errors = df[df["status"] == "error"] if n else df
    lo, hi = wilson_interval(ok, n)
    report = {
        "scenario": spec.scenario,
        "runs_requested": spec.runs,
        "runs_stored": n,
        "complete": n == spec.runs,
        "success_rmse": spec.success_rmse,
        "success_window": spec.success_window,
        **(
            {"success_hold_force_rms": spec.success_hold_force_rms}
            if spec.success_hold_force_rms is not None
            else {}
        ),
        "successes": ok,
        "success_rate": ok / n if n else None,
        "success_rate_ci95": [lo, hi],
        "errors": int(len(errors)),
        "terminated": int(df["terminated"].fillna(False).astype(bool).sum())
        if n and "terminated" in df
        else 0,
        # runs ended early, by their named outcome (tdacm.loop.Termination)
        "terminations": {
            str(k): int(v) for k, v in df["termination"].fillna("").value_counts().items() if k
        }
        if n and "termination" in df
        else {},
        "time_to_0.01": _stats(df["time_to_0.01"]) if n and "time_to_0.01" in df else None,
        "final_rmse": _stats(df["final_rmse"]) if n and "final_rmse" in df else None,
        **{
            k: _stats(df[k]) if n and k in df else None
            for k in (
                "late_rmse_1s",
                "within_0.01_last_2s",
                "strain_estimation_rms",
                "drone_position_estimation_rms",
            )
        },
        # servoing into contact: only when the runs hold a force
        **{
            k: _stats(df[k])
            for k in (
                "hold_force_rms_rel",
                "hold_force_estimate_error_rms",
                "hold_image_error_max",
                "hold_image_error_true_max",
                "max_contact_force",
            )
            if n and k in df and not df[k].isna().all()
        },
        "worst_runs": [],
    }
    if n and spec.success_hold_force_rms is not None:
        report["runs"] = hold_runs(df, spec)
    if n:
        key = (
            df["final_rmse"].astype(float).fillna(np.inf)
            if "final_rmse" in df
            else np.full(n, np.inf)
        )
        order = np.argsort(-np.asarray(key), kind="stable")[:n_worst]
        for i in order:
            r = df.iloc[int(i)]
            report["worst_runs"].append(
                {
                    "run": int(r["run"]),
                    "seed": int(r["seed"]),
                    "status": r["status"],
                    "final_rmse": None
                    if "final_rmse" not in r
                    or r["final_rmse"] is None
                    or not np.isfinite(r["final_rmse"])
                    else float(r["final_rmse"]),
                    "replay": replay_command(spec, out, int(r["run"]), int(r["seed"])),
                    "error": _first_line(r.get("error")),
                }
            )
    report["sensitivity"] = (
        [str(p.relative_to(out)) for p in write_sensitivity(df, spec, out)] if n else []
    )
    (out / "report.json").write_text(json.dumps(report, indent=2, default=float))
    _write_markdown(report, out)
    if n:
        _plot(df, spec, out)
    return report


def sampled_values(df, key: str) -> dict:
    """``{label: values per run}`` of the sampled parameter ``key`` (a dotted scenario key of
    the spec's ``[distributions]``) from the rows' ``overrides``: one entry for a number, one per
    component that varies for a vector (``key[i]``; none for a number that did not vary), the
    category's text for a string or a bool; ``NaN`` (``None`` for text) where a row has no
    value (a worker failure)."""
    parts = key.split(".")
    raw = []
    for text in df["overrides"] if "overrides" in df else [""] * len(df):
        node = json.loads(text) if isinstance(text, str) and text else {}
        for part in parts:
            node = node.get(part) if isinstance(node, dict) else None
        raw.append(node)
    present = [v for v in raw if v is not None]
    if not present:
        return {}
    if isinstance(present[0], bool | str):
        if len({str(v) for v in present}) < 2:  # one category for every run: no sensitivity
            return {}
        return {key: [None if v is None else str(v) for v in raw]}
    if isinstance(present[0], list):
        width = len(present[0])
        rows = np.array([v if isinstance(v, list) and len(v) == width else [np.nan] * width
                         for v in raw], float)  # fmt: skip
        return {f"{key}[{i}]": rows[:, i] for i in range(width) if _varies(rows[:, i])}
    x = np.array([np.nan if v is None else v for v in raw], float)
    return {key: x} if _varies(x) else {}


def _varies(x) -> bool:
    """Whether the finite values of ``x`` take more than one value."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return x.size > 1 and x.max() > x.min()


def write_sensitivity(df, spec, out: Path, bins: int = 6) -> list[Path]:
    """``OUT/sensitivity/KEY.png`` for every sampled parameter of the spec: per component
    that varies, the final normalized RMSE of each run against its sampled value (green:
    success, red: not) and the success rate in ``bins`` quantile bins of the value (95 %
    Wilson interval). Returns the files written (a parameter that did not vary: none)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = out / "sensitivity"
    success = df["success"].to_numpy(bool)
    final = (
        df["final_rmse"].astype(float).to_numpy()
        if "final_rmse" in df
        else np.full(len(df), np.nan)
    )
    paths = []
    for key in sorted(spec.distributions):
        columns = sampled_values(df, key)
        if not columns:
            continue
        k = len(columns)
        fig, axes = plt.subplots(2, k, figsize=(3.4 * k + 1.0, 5.8), squeeze=False)
        for j, (label, x) in enumerate(columns.items()):
            top, bottom = axes[0, j], axes[1, j]
            if isinstance(x, list):  # categories: their index on the axis
                names = sorted({v for v in x if v is not None})
                x = np.array([np.nan if v is None else names.index(v) for v in x], float)
                for ax in (top, bottom):
                    ax.set_xticks(range(len(names)), names)
                centres = [(np.flatnonzero(x == i), float(i)) for i in range(len(names))]
            else:
                x = np.asarray(x, float)
                good = np.isfinite(x)
                edges = np.unique(np.quantile(x[good], np.linspace(0, 1, bins + 1)))
                idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
                centres = [
                    (np.flatnonzero(good & (idx == b)), 0.5 * (edges[b] + edges[b + 1]))
                    for b in range(max(len(edges) - 1, 1))
                ]
            ok = np.isfinite(x) & np.isfinite(final) & (final > 0)
            top.scatter(x[ok], final[ok], c=np.where(success[ok], "C2", "C3"), s=10)
            if ok.any():
                top.set_yscale("log")
            top.axhline(spec.success_rmse, color="k", ls="--", lw=0.8)
            top.set_title(label, fontsize=9)
            rate, lo, hi, at = [], [], [], []
            for members, centre in centres:
                if members.size:
                    hits = int(success[members].sum())
                    a, b = wilson_interval(hits, members.size)
                    rate.append(hits / members.size)
                    # at a rate of 0 or 1 the interval's end equals it up to rounding
                    lo.append(max(0.0, rate[-1] - a))
                    hi.append(max(0.0, b - rate[-1]))
                    at.append(centre)
            bottom.errorbar(at, rate, yerr=[lo, hi], fmt="o-", color="C0", capsize=3)
            bottom.set_ylim(-0.05, 1.05)
            bottom.set_xlabel("sampled value")
            for ax in (top, bottom):
                ax.grid(alpha=0.3)
        axes[0, 0].set_ylabel("final normalized RMSE")
        axes[1, 0].set_ylabel("success rate (95 % CI)")
        fig.suptitle(f"{spec.scenario}, {len(df)} runs:\nsensitivity to {key}", fontsize=10)
        fig.tight_layout()
        folder.mkdir(exist_ok=True)
        path = folder / f"{key}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def _write_markdown(report, out: Path):
    lines = [f"# Campaign report: {report['scenario']}", ""]
    lines.append(f"- runs stored: {report['runs_stored']} / {report['runs_requested']}")
    if report["success_rate"] is not None:
        lo, hi = report["success_rate_ci95"]
        w = report.get("success_window")
        what = (
            "final normalized RMSE"
            if w is None
            else f"RMS of the normalized RMSE over the last {w:g} s"
        )
        if spec_hold := report.get("success_hold_force_rms"):
            what = (
                f"force held for touch.hold_time within {100 * spec_hold:g} % RMS, "
                "the task's image error (detected C_L points to the reference in C_L) during the hold"
            )
        lines.append(
            f"- success ({what} <= {report['success_rmse']}, not terminated): "
            f"{report['successes']}/{report['runs_stored']} = {100 * report['success_rate']:.1f} % "
            f"(95 % Wilson CI {100 * lo:.1f}-{100 * hi:.1f} %)"
        )
    by = ", ".join(f"{k} {v}" for k, v in report.get("terminations", {}).items())
    lines.append(
        f"- errors (bugs): {report['errors']}, ended early: {report['terminated']}"
        + (f" ({by})" if by else "")
    )
    for key in (
        "time_to_0.01",
        "final_rmse",
        "late_rmse_1s",
        "within_0.01_last_2s",
        "strain_estimation_rms",
        "drone_position_estimation_rms",
        "hold_force_rms_rel",
        "hold_force_estimate_error_rms",
        "hold_image_error_max",
        "hold_image_error_true_max",
        "max_contact_force",
    ):
        s = report.get(key)
        if s:
            lines.append(
                f"- {key}: median {s['median']:.4g}, 5-95 % [{s['p5']:.4g}, {s['p95']:.4g}], max {s['max']:.4g} (n = {s['n']})"
            )
    lines += [
        "",
        "## Worst runs",
        "",
        "| run | seed | status | final RMSE | replay |",
        "|---|---|---|---|---|",
    ]
    for w in report["worst_runs"]:
        lines.append(
            f"| {w['run']} | {w['seed']} | {w['status']} | "
            f"{'-' if w['final_rmse'] is None else format(w['final_rmse'], '.4g')} | "
            f"`{w['replay']}` |"
        )
    if report.get("runs"):
        lines += [
            "",
            "## Runs",
            "",
            "| run | seed | outcome | landings | hold (s) | force RMS error "
            "| force estimate RMS error (N) | image error (C_L, measured) "
            "| image error (C_L, true) | largest force (N) |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]

        def fmt(v, f):
            return "-" if v is None else format(v, f)

        for r in report["runs"]:
            rms = r["hold_force_rms_rel"]
            lines.append(
                f"| {r['run']} | {r['seed']} | {r['outcome']} | {fmt(r['landings'], '.0f')} "
                f"| {fmt(r['hold_duration'], '.2f')} "
                f"| {'-' if rms is None else f'{100 * rms:.1f} %'} "
                f"| {fmt(r['hold_force_estimate_error_rms'], '.4f')} "
                f"| {fmt(r['hold_image_error_max'], '.4f')} "
                f"| {fmt(r['hold_image_error_true_max'], '.4f')} "
                f"| {fmt(r['max_contact_force'], '.3f')} |"
            )
    if report.get("sensitivity"):
        lines += ["", "## Sensitivity to the sampled parameters", ""]
        lines += [f"- [{Path(p).stem}]({p})" for p in report["sensitivity"]]
    (out / "report.md").write_text("\n".join(lines) + "\n")


def _plot(df, spec, out: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    final = df["final_rmse"].astype(float).to_numpy() if "final_rmse" in df else np.array([])
    final = final[np.isfinite(final) & (final > 0)]
    if final.size:
        bins = np.logspace(np.log10(final.min()), np.log10(final.max()) + 1e-9, 25)
        axes[0].hist(final, bins=bins, color="C0")
        axes[0].set_xscale("log")
        _log_ticks(axes[0], final.min(), final.max(), spec.success_rmse)
    axes[0].axvline(spec.success_rmse, color="k", ls="--", lw=0.8)
    axes[0].set_xlabel("final normalized RMSE")
    axes[0].set_ylabel("runs")
    t = df["time_to_0.01"].astype(float).to_numpy() if "time_to_0.01" in df else np.array([])
    t = t[np.isfinite(t)]
    if t.size:
        axes[1].hist(t, bins=20, color="C1")
    else:
        axes[1].text(0.5, 0.5, "no run reached RMSE 0.01", ha="center", va="center",
                     transform=axes[1].transAxes, color="0.4")  # fmt: skip
        axes[1].set_xticks([])
        axes[1].set_yticks([])
    axes[1].set_xlabel("time to RMSE 0.01 (s)")
    for ax, counts in ((axes[0], final.size), (axes[1], t.size)):
        if counts:  # counts of runs: whole numbers
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    init = df["initial_rmse"].astype(float).to_numpy() if "initial_rmse" in df else np.array([])
    fin = df["final_rmse"].astype(float).to_numpy() if "final_rmse" in df else np.array([])
    colors = np.where(df["success"].to_numpy(bool), "C2", "C3")
    ok = np.isfinite(init) & np.isfinite(fin) & (fin > 0)
    if ok.any():
        axes[2].scatter(init[ok], fin[ok], c=colors[ok], s=12)
        axes[2].set_yscale("log")
    else:  # every run failed: no error to scale the axes
        axes[2].set_ylim(0.0, 2.0 * spec.success_rmse)
    axes[2].set_xlabel("initial normalized RMSE")
    axes[2].set_ylabel("final normalized RMSE")
    axes[2].axhline(spec.success_rmse, color="k", ls="--", lw=0.8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"{spec.scenario}: {int(df['success'].sum())}/{len(df)} runs succeeded")
    fig.tight_layout()
    fig.savefig(out / "report.png", dpi=120)
    plt.close(fig)


def _log_ticks(ax, lo: float, hi: float, *also) -> None:
    """Readable ticks on a log axis spanning ``[lo, hi]`` (and the values ``also`` marked on
    it): matplotlib labels the minor ticks of a range under a decade, and they overlap; here
    the minor ticks stay unlabelled and, under two decades, three major ticks are labelled
    in plain numbers."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())
    lo, hi = min(lo, *also), max(hi, *also)
    if hi / lo < 100:  # 1, 2, 5 times the powers of ten
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
