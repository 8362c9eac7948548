"""Closed-loop timings (``tdacm bench`` section ``loop``; ``benchmarks/bench_loop.py``).

* ``shipped``: ``tdacm run paper-in-fov`` as shipped (the main job: C_L rendered and
  detected every period, C_G offered every period but rendered only if the servo reads it),
  its real-time factor against the target :data:`MAIN_JOB_TARGET`;
* ``rendered``: ``paper-in-fov`` for 5 s, C_L rendered (planar renderer) and detected every
  period, C_G only when the servo needs it (``cameras.global_every = 0``);
* ``analytic``: the same with ``cameras.local_renderer = "analytic"`` (campaigns);
* ``compiled`` (inside each loop case): the period's time spent in compiled code, the numba
  kernels and the OpenCV calls, from one profiled run (:func:`compiled_share`); ``dt``
  divided by it bounds the real-time factor a loop with no Python overhead at all could reach;
* ``cold_start``: a first ``tdacm run paper-in-fov --duration 1`` in a fresh numba cache
  (``NUMBA_CACHE_DIR`` set to an empty folder), wall time of the whole command;
* ``cold_start_ab`` (optional): the same with the kernels compiled in one process and in two
  (:mod:`tdacm.loop.precompile`), alternating, and the ratio of the medians.

Each loop figure is the median of ``repeats`` runs after one warm-up run (one process, one
core), reported as wall seconds per simulated second and as the real-time factor.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: Real-time factor the main job (``tdacm run paper-in-fov``) should reach once compiled.
MAIN_JOB_TARGET = 3.0

LOOP_CASES = {
    "rendered": {"cameras": {"global_every": 0}},
    "analytic": {"cameras": {"global_every": 0, "local_renderer": "analytic"}},
}


def time_loop(overrides: dict, duration: float = 5.0, repeats: int = 5) -> dict:
    from ..sim import load_scenario
    from ..sim.assemble import build_loop

    sc = load_scenario("paper-in-fov").with_overrides(overrides)
    walls = []
    for i in range(repeats + 1):
        loop = build_loop(sc, 0).loop
        t0 = time.perf_counter()
        res = loop.run(duration)
        wall = time.perf_counter() - t0
        loop.close()
        if res.terminated:
            raise RuntimeError(f"benchmark run terminated: {res.reason}")
        if i:  # the first run warms caches up
            walls.append(wall)
    med = float(np.median(walls))
    return {
        "duration_s": duration,
        "repeats": repeats,
        "wall_s_median": med,
        "wall_s_all": walls,
        "wall_per_sim_second": med / duration,
        "real_time_factor": duration / med,
    }


def compiled_share(overrides: dict, duration: float = 5.0, top: int = 8) -> dict:
    """Time per control period inside compiled code: every numba dispatcher and OpenCV call
    of one ``paper-in-fov`` run, as ``cProfile`` measures their own time (``tottime``, their
    call overhead included). The profiler slows the Python around them, not the compiled
    calls, so the period's total comes from an unprofiled run (:func:`time_loop`, one run
    after its warm-up).

    Returns the period's wall time, the compiled time, the cap ``dt / compiled`` on the
    real-time factor of a loop without any Python overhead, and the ``top`` entries."""
    import cProfile
    import pstats

    import cv2
    from numba.core.registry import CPUDispatcher

    from ..sim import load_scenario
    from ..sim.assemble import build_loop

    wall = time_loop(overrides, duration, repeats=1)["wall_s_median"]
    sc = load_scenario("paper-in-fov").with_overrides(overrides)
    loop = build_loop(sc, 0).loop
    prof = cProfile.Profile()
    prof.enable()
    res = loop.run(duration)
    prof.disable()
    loop.close()
    # the profiler names a jitted function by its Python code: map those back to the kernels
    kernels = {}
    for mod in [m for k, m in sys.modules.items() if k.startswith("tdacm.")]:
        for obj in vars(mod).values():
            if isinstance(obj, CPUDispatcher):
                code = obj.py_func.__code__
                key = (code.co_filename, code.co_firstlineno, code.co_name)
                kernels[key] = f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"
    n = len(res.arrays["t"])
    entries = {}
    for where, (_cc, calls, tottime, _ct, _callers) in pstats.Stats(prof).stats.items():
        path, _line, name = where
        if path == "~":  # C functions: OpenCV's, named "<name>" or "<method ... of 'cv2...>"
            bare = name[1:-1] if name[:1] in "<{" and name[-1:] in ">}" else name
            if not (hasattr(cv2, bare) or " of 'cv2." in name):
                continue
            key = bare
        elif where in kernels:
            key = kernels[where]
        else:
            continue
        entries[key] = (calls / n, tottime / n * 1e3)
    compiled = sum(ms for _, ms in entries.values())
    period = wall / n * 1e3
    ranked = sorted(entries.items(), key=lambda kv: -kv[1][1])[:top]
    return {
        "period_ms": period,
        "compiled_ms": compiled,
        "compiled_fraction": compiled / period,
        "cap_real_time_factor": sc.config.dt * 1e3 / compiled,
        "top": {k: {"calls_per_period": c, "ms_per_period": ms} for k, (c, ms) in ranked},
    }


def _cold_run(parallel: bool | None, warm: bool = False):
    """``(cold wall s, its CompletedProcess, warm wall s or None)`` of ``tdacm run paper-in-fov
    --duration 1`` in a fresh, empty numba cache, then (``warm``) once more on that cache.
    ``parallel`` forces the two-process compile on or off; ``None``: the default."""
    cmd = [sys.executable, "-m", "tdacm.cli", "run", "paper-in-fov", "--duration", "1"]
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        if parallel is not None:
            env["TDACM_PARALLEL_COMPILE"] = "1" if parallel else "0"
        walls, proc = [], None
        for _ in range(2 if warm else 1):
            t0 = time.perf_counter()
            p = subprocess.run(cmd + ["--out", out], env=env, capture_output=True, text=True)
            walls.append(time.perf_counter() - t0)
            proc = proc or p
    return walls[0], proc, (walls[1] if warm else None)


def time_cold_start() -> dict:
    """Wall time of ``tdacm run paper-in-fov --duration 1`` with an empty numba cache."""
    wall, proc, warm = _cold_run(None, warm=True)
    return {
        "command": "tdacm run paper-in-fov --duration 1 (empty NUMBA_CACHE_DIR)",
        "cold_wall_s": wall,
        "warm_wall_s": warm,
        "exit_code": proc.returncode,
        "stderr_first_lines": proc.stderr.splitlines()[:3],
    }


def cold_start_ab(rounds: int = 2, progress=print) -> dict:
    """The cold first run with the kernels compiled in one process and in two
    (:mod:`tdacm.loop.precompile`), alternating, ``rounds`` of each: the ratio of the
    medians is the speed-up, measured in the same minutes."""
    one, two = [], []
    for r in range(rounds):
        for parallel, acc in ((False, one), (True, two)):
            wall, proc, _ = _cold_run(parallel)
            if proc.returncode != 0:
                raise RuntimeError(f"cold run failed: {proc.stderr[-500:]}")
            acc.append(wall)
            progress(
                f"  round {r + 1}: {'two processes' if parallel else 'one process'} {wall:.1f} s"
            )
    return {
        "one_process_s": one,
        "two_processes_s": two,
        "ratio_of_medians": float(np.median(one) / np.median(two)),
    }


def loop_bench(repeats: int = 5, cold: bool = True, progress=print, cold_ab: int = 0) -> dict:
    """All closed-loop figures (the ``loop`` section of ``bench.json``); ``cold_ab`` rounds
    of :func:`cold_start_ab` (0: none)."""
    res = {}
    progress(f"closed loop, paper-in-fov as shipped ({repeats} + 1 runs of 5 s)...")
    res["shipped"] = time_loop({}, repeats=repeats)
    res["shipped"]["target_real_time_factor"] = MAIN_JOB_TARGET
    res["shipped"]["ratio_to_target"] = res["shipped"]["real_time_factor"] / MAIN_JOB_TARGET
    progress(f"  {res['shipped']['real_time_factor']:.1f}x real time")
    for name, ov in LOOP_CASES.items():
        progress(f"closed loop, {name} C_L ({repeats} + 1 runs of 5 s)...")
        res[name] = time_loop(ov, repeats=repeats)
        progress(f"  {res[name]['real_time_factor']:.1f}x real time")
        c = res[name]["compiled"] = compiled_share(ov)
        progress(
            f"  compiled code {c['compiled_ms']:.2f} of {c['period_ms']:.2f} ms a period: "
            f"without any Python at most {c['cap_real_time_factor']:.1f}x"
        )
    if cold:
        progress("cold first run (empty numba cache)...")
        res["cold_start"] = time_cold_start()
        progress(f"  {res['cold_start']['cold_wall_s']:.1f} s")
    if cold_ab:
        progress(f"cold first run, one process against two ({cold_ab} rounds)...")
        res["cold_start_ab"] = cold_start_ab(cold_ab, progress)
        progress(f"  {res['cold_start_ab']['ratio_of_medians']:.2f}x")
    res["cpu_count"] = os.cpu_count()
    return res


def run_loop_bench(
    out="out/bench", repeats: int = 5, cold: bool = True, progress=print, cold_ab: int = 0
) -> dict:
    """:func:`loop_bench`, merged into ``OUT/bench.json`` under ``"loop"``."""
    res = loop_bench(repeats, cold, progress, cold_ab)
    path = Path(out) / "bench.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.is_file() else {}
    data["loop"] = res
    path.write_text(json.dumps(data, indent=2))
    return res
