"""State estimation: filter cost per period, accuracy, consistency, and the closed
loop on estimates against the true state. The numbers of ``docs/estimation.md``.

    python benchmarks/bench_estimation.py [--seeds 6] [--out out/bench]
    python benchmarks/bench_estimation.py --parts   # microseconds of the prediction's parts

Writes ``OUT/estimation.json``. Part 1 drives the filter with the plant alone (the paper
system under the project's controller on the true state, hover + strain steps, default sensors,
10 % model error, initial strain error 0.3 rad/m; :mod:`tdacm.bench.estimation`); part 2 runs
the shipped scenarios (analytic C_L, noise-free cameras) with ``estimation.source`` = "true"
and "estimated".
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from tdacm.bench.estimation import filter_parts, nees, run
from tdacm.control import EstimatedModel
from tdacm.estimation import ExtendedKalmanFilter, SensorSuite
from tdacm.sim import build_loop
from tdacm.sim.runner import estimation_summary
from tdacm.sim.scenario import load_scenario

FAST = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}


def filter_cost(repeats=5, steps=250):
    """Median wall time of ``ExtendedKalmanFilter.step`` (default sensors, 20 ms pose latency),
    measured on pre-recorded measurements; the best median of ``repeats`` (the machine is shared)."""
    r = run(seed=0, duration=steps * 0.02)
    s = r.estimator.system
    suite = SensorSuite(s, seed=0)
    u = np.concatenate([np.full(4, s.total_mass * 9.81 / 4), np.full(4, 0.5)])
    meas = []
    for k, (q, qd) in enumerate(zip(r.q, r.qd, strict=True)):
        meas.append(suite.sample(0.02 * k, q, qd, np.zeros(8) if k else None))
    medians = []
    for _ in range(repeats):
        est = ExtendedKalmanFilter(EstimatedModel(s, 0.1, 0))
        est.reset(r.q[0])
        est.step(0.0, None, meas[0])
        w = []
        for k in range(1, len(meas)):
            t0 = time.perf_counter()
            est.step(0.02 * k, u, meas[k])
            w.append(time.perf_counter() - t0)
        medians.append(float(np.median(w)))
    return {"median_ms": 1e3 * min(medians), "medians_ms": [1e3 * m for m in medians]}


def standalone(seeds):
    rows, ne = [], []
    for seed in range(seeds):
        r = run(seed=seed, duration=2.0)
        late = r.t >= 1.0
        e, ed = r.q_hat - r.q, r.qd_hat - r.qd
        rows.append(
            {
                "strain_rms": float(np.sqrt(np.mean(e[late, 6:] ** 2))),
                "drone_position_rms": float(np.sqrt(np.mean(np.sum(e[late, 3:6] ** 2, 1)))),
                "attitude_rms": float(np.sqrt(np.mean(e[late, :3] ** 2))),
                "velocity_rms": float(np.sqrt(np.mean(ed[late, 3:6] ** 2))),
                "strain_rate_rms": float(np.sqrt(np.mean(ed[late, 6:] ** 2))),
                "strain_error_after_first_update": float(np.max(np.abs(e[0, 6:]))),
            }
        )
        ne.append(nees(r)[5:])
    ne = np.concatenate(ne)
    lo, hi = chi2.ppf([0.025, 0.975], 16)
    return {
        "runs": rows,
        "nees": {
            "mean": float(ne.mean()),
            "dof": 16,
            "inside_95": float(np.mean((ne > lo) & (ne < hi))),
            "above": float(np.mean(ne > hi)),
            "below": float(np.mean(ne < lo)),
        },
    }


def closed_loop(name, source, duration=None, seed=0, estimation=None, sensors=None):
    est = {"source": source, **(estimation or {})}
    sc = load_scenario(name).with_overrides(
        {**FAST, "estimation": est, "sensors": dict(sensors or {})}
    )
    loop = build_loop(sc, seed).loop
    dur = sc["duration"] if duration is None else duration
    n_steps = int(round(dur / loop.dt))
    loop.reset()
    covs, done, reason = [], False, None
    t0 = time.perf_counter()
    for k in range(n_steps + 1):
        st = loop.step(last=k == n_steps)
        covs.append(st.estimate.P)
        if st.done:
            done, reason = st.reason is not None, st.reason
            break
    wall = time.perf_counter() - t0
    a = loop.log.arrays()
    covs = covs[: len(a["t"])]
    rmse = a["rmse"]
    fin = np.isfinite(rmse)
    reach = np.flatnonzero(fin & (rmse <= 0.01))
    out = {
        "terminated": bool(done),
        "reason": reason,
        "final_rmse": float(rmse[fin][-1]) if fin.any() else None,
        "mean_rmse_last_2s": float(np.nanmean(rmse[a["t"] >= a["t"][-1] - 2.0])),
        "time_to_0.01": float(a["t"][reach[0]]) if reach.size else None,
        "final_drone_position_error_m": float(
            np.linalg.norm(a["q"][-1][3:6] - np.asarray(sc["desired"]["q"])[3:6])
        ),
        "wall_per_sim_second": wall / max(float(a["t"][-1]), 1e-9),
        **estimation_summary(a, loop.plant.system, source, loop),
    }
    if source == "estimated":
        err = np.concatenate([a["q_hat"] - a["q"], a["qd_hat"] - a["qd"]], axis=1)
        ne = np.array([e @ np.linalg.solve(p, e) for e, p in zip(err, covs, strict=True)])[5:]
        lo, hi = chi2.ppf([0.025, 0.975], err.shape[1])
        var = np.array([np.diag(p) for p in covs])
        out["normalized_error_by_state"] = [float(v) for v in np.mean(err**2 / var, axis=0)]
        out["nees_mean"] = float(ne.mean())
        out["nees_inside_95"] = float(np.mean((ne > lo) & (ne < hi)))
        out["strain_rate_rms"] = float(np.sqrt(np.mean(err[a["t"] >= 1.0, 14:] ** 2)))
    loop.close()
    return out


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--out", default="out/bench")
    p.add_argument("--parts", action="store_true", help="only the prediction's parts (us)")
    args = p.parse_args()
    if args.parts:
        print(json.dumps(filter_parts(), indent=2))
        raise SystemExit(0)
    res = {"load_average": os.getloadavg(), "filter_cost": filter_cost()}
    res["standalone"] = standalone(args.seeds)
    res["closed_loop"] = {
        f"{name}/{src}": closed_loop(name, src)
        for name in ("paper-in-fov", "flight-test-c", "paper-out-of-fov")
        for src in ("true", "estimated")
    }
    res["load_average_end"] = os.getloadavg()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "estimation.json").write_text(json.dumps(res, indent=2))
    print(json.dumps(res, indent=2))
