"""Speed of the batched engine (``tdacm bench --batch``, ``benchmarks/bench_batch.py``).

The engine's configuration of ``paper-in-fov`` (analytic cameras, the servo on the measured
points, 1 px of pixel noise, the scenario's 10 % model error): world-periods per second
(an env step is one period; 50 periods are one simulated second) for a table of batch
sizes and thread counts, one world's real-time factor, and the batch's first call on a cold
and on a warm cache (in fresh processes). Medians of ``repeats`` runs after a warm-up. The
robust servo's target filter apart (:func:`filter_cost`): the same batch with the servo on
the features predicted from the filter (the scenario as shipped) against the measured ones,
measured in one run.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

#: the engine's configuration of the scenario (the vector env's)
ENGINE = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
    "ibvs": {"features": "measured"},
    "sensors": {"pixel_noise": 1.0},
}


def _batch(n_worlds: int, threads: int, duration: float, features: str | None = None):
    from ..sim.batch import build_batch
    from ..sim.scenario import load_scenario

    ov = ENGINE if features is None else {**ENGINE, "ibvs": {"features": features}}
    sc = load_scenario("paper-in-fov").with_overrides(ov, "batch benchmark")
    return build_batch(sc, np.arange(n_worlds), duration=duration, threads=threads)


def periods_per_second(n_worlds: int, threads: int, duration: float = 2.0, repeats: int = 3,
                       features: str | None = None):  # fmt: skip
    """Median world-periods per second of whole runs of ``n_worlds`` worlds (the runs that
    end early count the periods they ran); ``features``: the servo's (``ibvs.features``;
    default :data:`ENGINE`'s)."""
    b = _batch(n_worlds, threads, duration, features)
    b.run()  # warm-up (compiles on a cold cache)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = b.run()
        wall = time.perf_counter() - t0
        rates.append(float(res.samples.sum()) / wall)
    return statistics.median(rates)


def filter_cost(n_worlds: int = 256, threads: int = 2, duration: float = 1.0, repeats: int = 3,
                progress=print) -> dict:  # fmt: skip
    """World-periods (env steps) per second of ``n_worlds`` worlds with the servo on the
    measured points and on the points predicted from the target filter (the robust servo),
    medians of ``repeats`` runs of ``duration`` s, one after the other, the machine's load
    before and after."""
    out = {"n_worlds": n_worlds, "threads": threads, "load": os.getloadavg()}
    for features in ("measured", "predicted"):
        out[features] = periods_per_second(n_worlds, threads, duration, repeats, features)
        progress(f"batch N={n_worlds} threads={threads} {features:9s}: {out[features]:9.0f} "
                 "world-periods/s")  # fmt: skip
    out["ratio"] = out["predicted"] / out["measured"]
    # the filter's share of a period: 1/rate_pred - 1/rate_meas per world-period (s)
    out["filter_us_per_period"] = 1e6 * threads * (1 / out["predicted"] - 1 / out["measured"])
    out["load_after"] = os.getloadavg()
    return out


def step_rate(n_worlds: int, threads: int, steps: int = 100, repeats: int = 3):
    """Median world-periods per second through :meth:`Batch.step` (one call per period, the
    vector env's path: the threads meet at every period)."""
    b = _batch(n_worlds, threads, 100.0)
    b.step()
    rates = []
    for _ in range(repeats):
        b.reset()
        t0 = time.perf_counter()
        for _ in range(steps):
            b.step()
        rates.append(n_worlds * steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def first_call(cold: bool) -> float:
    """Wall time (s) of a fresh process building a batch of 4 worlds and running 0.1 s, on
    an empty numba cache (``cold``, a temporary ``NUMBA_CACHE_DIR``) or the current one."""
    env = dict(os.environ)
    tmp = None
    if cold:
        tmp = tempfile.mkdtemp(prefix="tdacm-batch-cold-")
        env["NUMBA_CACHE_DIR"] = tmp
    code = (
        "import time; t0 = time.perf_counter()\n"
        "from tdacm.bench.batch import _batch\n"
        "_batch(4, 2, 0.1).run()\n"
        "print(time.perf_counter() - t0)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return float(out.stdout.strip().splitlines()[-1])


def batch_bench(sizes=(1, 4, 16, 64, 256, 1024), threads=(1, 2), repeats: int = 3, progress=print):
    """The ``batch`` section of ``bench.json`` (module docstring)."""
    out = {"load": os.getloadavg(), "runs": {}, "steps": {}}
    for t in threads:
        for n in sizes:
            r = periods_per_second(n, t, repeats=repeats)
            out["runs"][f"{n}x{t}"] = r
            progress(f"batch run   N={n:5d} threads={t}: {r:9.0f} world-periods/s")
    for t in threads:
        for n in (64, 256):
            if n in sizes:
                r = step_rate(n, t, repeats=repeats)
                out["steps"][f"{n}x{t}"] = r
                progress(f"batch step  N={n:5d} threads={t}: {r:9.0f} world-periods/s")
    one = out["runs"].get(f"1x{threads[0]}")
    if one is not None:
        out["one_world_real_time"] = one / 50.0  # 50 periods of 20 ms per simulated second
    out["first_call_warm_s"] = first_call(False)
    out["first_call_cold_s"] = first_call(True)
    out["filter"] = filter_cost(progress=progress)
    out["load_after"] = os.getloadavg()
    progress(
        f"first call: cold {out['first_call_cold_s']:.1f} s, warm {out['first_call_warm_s']:.1f} s"
    )
    return out
