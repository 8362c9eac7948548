"""Speed of the batched engine (``tdacm bench --batch``, ``benchmarks/bench_batch.py``).

The engine's configuration of ``paper-in-fov`` (analytic cameras, the servo on the measured
points, 1 px of pixel noise, the scenario's 10 % model error): world-periods per second
(an env step is one period; 50 periods are one simulated second) for a table of batch
sizes and thread counts, with the servo on the measured points and on the points predicted
from the robust servo's target filter (:func:`table`), one world's real-time factor, the
batch's first call on a cold and on a warm cache (in fresh processes) and the Gymnasium
vector env's env-steps per second (:func:`vector_env_rate`). Medians of ``repeats`` runs after
a warm-up. The robust servo's target filter apart (:func:`filter_cost`): the same batch with
the servo on the features predicted from the filter (the scenario as shipped) against the
measured ones, measured in one run.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: the engine's configuration of the scenario (the vector env's)
ENGINE = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
    "ibvs": {"features": "measured"},
    "sensors": {"pixel_noise": 1.0},
}


def _batch(n_worlds: int, threads: int, duration: float, features: str | None = None,
           scenario: str = "paper-in-fov", estimated: bool = False):  # fmt: skip
    from ..sim.batch import build_batch
    from ..sim.scenario import load_scenario

    ov = ENGINE if features is None else {**ENGINE, "ibvs": {"features": features}}
    if estimated:
        ov = {**ov, "estimation": {"source": "estimated"}}
    sc = load_scenario(scenario).with_overrides(ov, "batch benchmark")
    return build_batch(sc, np.arange(n_worlds), duration=duration, threads=threads)


def periods_per_second(n_worlds: int, threads: int, duration: float = 2.0, repeats: int = 3,
                       features: str | None = None, cpu: bool = False,
                       scenario: str = "paper-in-fov", estimated: bool = False):  # fmt: skip
    """Median world-periods per second of whole runs of ``n_worlds`` worlds of ``scenario`` in
    the engine's configuration (:data:`ENGINE`; ``estimated``: on the EKF's estimates) (the
    runs that end early count the periods they ran); ``features``: the servo's
    (``ibvs.features``; default :data:`ENGINE`'s). ``cpu``: also the median CPU time of this
    process per world-period (ms; the threads' included), a figure the machine's load
    changes less."""
    kw = dict(features=features, scenario=scenario, estimated=estimated)
    _batch(min(n_worlds, 2), 1, 0.1, **kw).run()  # warm-up (compiles on a cold cache)
    rate, cpu_ms = _timed_runs(_batch(n_worlds, threads, duration, **kw), repeats)
    return (rate, cpu_ms) if cpu else rate


def _timed_runs(b, repeats: int) -> tuple[float, float]:
    """Medians over ``repeats`` whole runs of the batch ``b``: world-periods per second (the
    runs that end early count the periods they ran) and this process's CPU time per
    world-period (ms; the threads' included)."""
    rates, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = b.run()
        wall, c = time.perf_counter() - t0, time.process_time() - c0
        rates.append(float(res.samples.sum()) / wall)
        cpus.append(1e3 * c / float(res.samples.sum()))
    return statistics.median(rates), statistics.median(cpus)


def touch_rate(n_worlds: int = 16, threads: int = 2, repeats: int = 1, estimated: bool = False,
               progress=print) -> dict:  # fmt: skip
    """World-periods per second and CPU per world-period of whole runs of ``touch-target``
    (40 s: the approach, the touch, the hold, the release) on the engine, analytic cameras,
    1 px of pixel noise, the scenario's model error, on the true state or the EKF's estimates
    (``estimated``); medians of ``repeats`` runs after a warm-up, the machine's load before
    and after."""
    from ..sim.batch import build_batch
    from ..sim.scenario import load_scenario

    ov = {"cameras": ENGINE["cameras"], "sensors": ENGINE["sensors"]}
    if estimated:
        ov["estimation"] = {"source": "estimated"}
    sc = load_scenario("touch-target").with_overrides(ov, "touch benchmark")
    out = {"n_worlds": n_worlds, "threads": threads, "estimated": estimated,
           "load": os.getloadavg()}  # fmt: skip
    build_batch(sc, [0, 1], duration=0.1, threads=1).run()  # warm-up (compiles on a cold cache)
    rate, cpu_ms = _timed_runs(build_batch(sc, np.arange(n_worlds), threads=threads), repeats)
    out.update(rate=rate, cpu_ms=cpu_ms, load_after=os.getloadavg())
    progress(f"touch-target N={n_worlds} threads={threads}: {out['rate']:.0f} world-periods/s, "
             f"{out['cpu_ms']:.2f} ms CPU a world-period")  # fmt: skip
    return out


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


def period_split(n_worlds: int = 64, periods: int = 60, skip: int = 10,
                 scenario: str = "paper-in-fov") -> dict:  # fmt: skip
    """Where a world-period goes in a run: the engine's two halves timed apart on ``n_worlds``
    worlds of ``scenario`` (the engine's configuration, one thread), ``periods`` periods of
    :func:`~tdacm.batch.engine.act_worlds` then :func:`~tdacm.batch.engine.sense_worlds`,
    each half timed over all the worlds; medians after the first ``skip`` periods, in us a
    world (the halves of whole runs, with every world's code and data as a run leaves them,
    unlike a step called again and again on one world's state)."""
    from ..batch import engine as E

    b = _batch(min(n_worlds, 2), 1, 0.1, scenario=scenario)
    b.run()  # warm-up (compiles on a cold cache)
    b = _batch(n_worlds, 1, 1000.0, scenario=scenario)
    b.reset()
    m, d = b.model, b.data
    twist = np.full((n_worlds, 6 * d.servo_out.rmse.shape[1]), np.nan)
    E.sense_worlds(m, d, 0, n_worlds)
    halves = {"act": [], "sense": []}
    for _ in range(periods):
        acting = max(int(d.active.sum()), 1)  # the worlds the act half steps
        t0 = time.perf_counter()
        E.act_worlds(m, d, twist, 0, n_worlds)
        t1 = time.perf_counter()
        sensing = max(int(d.active.sum()), 1)  # those still running, which the sense half views
        E.sense_worlds(m, d, 0, n_worlds)
        t2 = time.perf_counter()
        halves["act"].append(1e6 * (t1 - t0) / acting)
        halves["sense"].append(1e6 * (t2 - t1) / sensing)
    out = {"scenario": scenario, "n_worlds": n_worlds, "periods": periods,
           "load": os.getloadavg()}  # fmt: skip
    for half, us in halves.items():
        out[half + "_us"] = statistics.median(us[skip:])
    out["period_us"] = out["act_us"] + out["sense_us"]
    return out


def first_call(cold: bool, parallel: bool = True) -> float:
    """Wall time (s) of a fresh process building a batch of 4 worlds and running 0.1 s, on
    an empty numba cache (``cold``, a temporary ``NUMBA_CACHE_DIR``) or the current one;
    ``parallel`` False: in one process (``TDACM_PARALLEL_COMPILE=0``; by default the engine
    compiles in two on a cold cache, :mod:`tdacm.sim.compile_engine`)."""
    env = dict(os.environ, TDACM_PARALLEL_COMPILE="1" if parallel else "0")
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


def engine_cache_entries() -> list:
    """The files of numba's cache entries of the engine's own module
    (:mod:`tdacm.batch.engine`) in the cache this process uses (``NUMBA_CACHE_DIR``, or the
    ``__pycache__`` folder beside the module)."""
    from ..batch import engine as E

    src = Path(E.__file__).resolve()
    stem = src.stem + "."
    root = os.environ.get("NUMBA_CACHE_DIR")
    if root:
        folders = [d for d in Path(root).rglob("*") if d.is_dir() and d.parts[-2:] ==
                   src.parent.parts[-2:]]  # fmt: skip
    else:
        folders = [src.parent / "__pycache__"]
    return [f for d in folders for f in sorted(d.glob(stem + "*"))
            if f.suffix in (".nbi", ".nbc") or ".tmp." in f.name]  # fmt: skip


def engine_first_call(parallel: bool = True) -> float:
    """Wall time (s) of the engine's first call (:func:`first_call` on the current cache)
    after removing the engine's own cache entries (:func:`engine_cache_entries`): the blocks'
    steps load, the engine's four functions compile, as after ``tdacm run`` or ``make test``'s
    first phase. ``parallel``: in two processes (the default), else in one."""
    for f in engine_cache_entries():
        f.unlink()
    return first_call(False, parallel=parallel)


#: the child of :func:`allocations`: whole runs of :func:`_batch`, numba's allocation count
#: (its runtime's statistics) before and after
_ALLOCATIONS_CODE = """
import json, sys
from numba.core.runtime import rtsys
from tdacm.bench.batch import _batch
n, threads, duration = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
b = _batch(n, threads, duration)
b.run()  # warm-up: kernels loaded (or compiled), work arrays in place
a0 = rtsys.get_allocation_stats().alloc
res = b.run()
a1 = rtsys.get_allocation_stats().alloc
print(json.dumps({"allocations": a1 - a0, "world_periods": int(res.samples.sum())}))
"""


def allocations(n_worlds: int = 4, threads: int = 1, duration: float = 1.0) -> dict:
    """Numba's allocations (its runtime's ``NRT_Allocate`` calls: every array a compiled step
    creates) per world-period of whole runs of the engine's ``paper-in-fov``
    (:data:`ENGINE`), counted in a fresh process with the runtime's statistics on
    (``NUMBA_NRT_STATS=1``, read before numba is imported). What an allocation-free step
    removes: each allocation is a ``malloc`` and a ``free`` with their reference counts, and
    threads share the allocator. Returns ``{"allocations", "world_periods",
    "per_world_period"}``."""
    env = dict(os.environ, NUMBA_NRT_STATS="1")
    cmd = [sys.executable, "-c", _ALLOCATIONS_CODE, str(n_worlds), str(threads), str(duration)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["per_world_period"] = res["allocations"] / max(res["world_periods"], 1)
    return res


def vector_env_rate(num_envs: int = 256, steps: int = 200, threads: int | None = None,
                    seed: int = 0, repeats: int = 3) -> dict:  # fmt: skip
    """Env-steps per second of ``gym.make_vec("tdacm/TipServo-v0", num_envs,
    vectorization_mode="vector_entry_point")`` under uniformly random actions (the action
    space seeded with ``seed``; the autoresets of ended worlds included): the median of
    ``repeats`` blocks of ``steps`` steps after a warm-up step, with the CPU time per env step
    of this process and the share of the steps that autoreset a world."""
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the env)

    env = gym.make_vec("tdacm/TipServo-v0", num_envs=num_envs,
                       vectorization_mode="vector_entry_point", threads=threads)  # fmt: skip
    try:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        env.step(env.action_space.sample())
        rates, cpu, resets = [], [], 0
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(steps):
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                resets += int(np.count_nonzero(term | trunc))
            wall, c = time.perf_counter() - t0, time.process_time() - c0
            rates.append(num_envs * steps / wall)
            cpu.append(c / (num_envs * steps))
    finally:
        env.close()
    return {
        "num_envs": num_envs,
        "env_steps_per_s": statistics.median(rates),
        "cpu_ms_per_env_step": 1e3 * statistics.median(cpu),
        "episode_ends_per_env_step": resets / (repeats * steps * num_envs),
        "load": os.getloadavg(),
    }


def table(runs: dict, sizes, threads) -> str:
    """A markdown table of world-periods per second (``runs``: ``{"NxT": rate}``, or per
    servo ``{"measured": {...}, "predicted": {...}}``), a row per batch size, a column per
    thread count (and servo)."""
    parts = runs if isinstance(next(iter(runs.values())), dict) else {"": runs}
    head = [f"{k} {t} thr".strip() for k in parts for t in threads]
    lines = ["| N | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
    for n in sizes:
        cells = []
        for part in parts.values():
            for t in threads:
                r = part.get(f"{n}x{t}")
                cells.append("" if r is None else f"{r:,.0f}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def batch_bench(sizes=(1, 4, 16, 64, 256, 1024), threads=(1, 2), repeats: int = 3,
                progress=print, duration: float = 2.0, servo_modes=("measured",),
                vector: bool = True, cold: bool = True):  # fmt: skip
    """The ``batch`` section of ``bench.json`` (module docstring): the table over ``sizes``
    and ``threads`` for each servo of ``servo_modes`` (``"measured"``, ``"predicted"``), runs of
    ``duration`` s."""
    out = {"load": os.getloadavg(), "runs": {}, "steps": {}, "duration": duration, "cpu_ms": {}}
    for feat in servo_modes:
        runs = out["runs"] if feat == "measured" else out.setdefault(f"runs_{feat}", {})
        for t in threads:
            for n in sizes:
                r, c = periods_per_second(n, t, duration, repeats, feat, cpu=True)
                runs[f"{n}x{t}"] = r
                out["cpu_ms"][f"{feat} {n}x{t}"] = c
                progress(f"batch run   N={n:5d} threads={t} {feat:9s}: {r:9.0f} world-periods/s"
                         f", {c:.3f} ms CPU each  (load {os.getloadavg()[0]:.1f})")  # fmt: skip
    for t in threads:
        for n in (64, 256):
            if n in sizes:
                r = step_rate(n, t, repeats=repeats)
                out["steps"][f"{n}x{t}"] = r
                progress(f"batch step  N={n:5d} threads={t}: {r:9.0f} world-periods/s")
    first = out["runs"] if "measured" in servo_modes else out[f"runs_{servo_modes[0]}"]
    one = first.get(f"1x{threads[0]}")
    if one is not None:
        out["one_world_real_time"] = one / 50.0  # 50 periods of 20 ms per simulated second
    out["first_call_warm_s"] = first_call(False)
    progress(f"first call: warm {out['first_call_warm_s']:.1f} s")
    if cold:
        out["first_call_cold_s"] = first_call(True)
        progress(f"first call: cold {out['first_call_cold_s']:.1f} s")
    if vector:
        out["vector_env"] = vector_env_rate(threads=max(threads))
        progress(f"vector env N=256: {out['vector_env']['env_steps_per_s']:.0f} env-steps/s")
    out["load_after"] = os.getloadavg()
    tabs = {f: out["runs"] if f == "measured" else out[f"runs_{f}"] for f in servo_modes}
    progress(table(tabs, sizes, threads))
    return out
