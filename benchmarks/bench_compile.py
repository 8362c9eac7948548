"""Where compile time goes: the numba kernels a job compiles on an empty cache, each with its
compile seconds, the total and the count.

    python benchmarks/bench_compile.py engine [--top 25] [--json out/compile-engine.json]
    python benchmarks/bench_compile.py run | engine-ekf | vector-env

The job runs in a fresh process on an empty numba cache (a temporary ``NUMBA_CACHE_DIR``, one
process: ``TDACM_PARALLEL_COMPILE=0``) and records numba's ``numba:compile`` events (one per
function and argument types, nested when a caller compiles its callees): each kernel's
inclusive and exclusive seconds of the compiling thread's CPU time (exclusive: without the
callees compiled inside it), so the figures do not count other processes' load.

Jobs: ``run`` (``tdacm run paper-in-fov --duration 1``'s loop), ``engine`` (the batched
engine's first ``build_batch(...).run()``, 4 worlds for 0.1 s with analytic cameras, then a
step, a reset and the vector env's act-then-sense pass), ``engine-ekf`` (the same on the
EKF's estimates), ``vector-env`` (``gym.make_vec``: reset, the imitation teacher, 5 steps).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


def _job(name: str, work: str) -> None:
    import numpy as np

    from tdacm.sim.scenario import load_scenario

    if name.startswith("engine"):
        from tdacm.batch import engine as E
        from tdacm.sim.batch import build_batch

        ov = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
              "ibvs": {"features": "measured"}}  # fmt: skip
        if name == "engine-ekf":
            ov["estimation"] = {"source": "estimated"}
        sc = load_scenario("paper-in-fov").with_overrides(ov, "compile")
        b = build_batch(sc, [0, 1, 2, 3], duration=0.1, threads=2)
        b.run()
        b.step()
        b.reset()
        ones = np.ones(4, np.bool_)
        E.parallel(E.act_sense, (b.model, b.data, np.full((4, 6), np.nan), ones, ones), 4, 2)
    elif name == "vector-env":
        import gymnasium as gym

        import tdacm.envs  # noqa: F401  (registers the env)
        from tdacm.envs.teacher import teacher_twists

        env = gym.make_vec("tdacm/TipServo-v0", num_envs=8, vectorization_mode="vector_entry_point")
        env.reset(seed=0)
        teacher_twists(env)
        env.action_space.seed(0)
        for _ in range(5):
            env.step(env.action_space.sample())
        env.close()
    elif name == "run":
        from tdacm.sim import Simulation

        sim = Simulation(load_scenario("paper-in-fov"), duration=1.0)
        sim.build()
        sim.run(os.path.join(work, "run"))
    else:
        raise SystemExit(f"unknown job {name!r}")


def record(name: str, work: str) -> dict:
    """Run job ``name`` in this process, recording numba's compile events."""
    from numba.core import event

    stack, records = [], []

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append([time.thread_time(), 0.0])

        def on_end(self, ev):
            c0, inner = stack.pop()
            cpu = time.thread_time() - c0
            if stack:
                stack[-1][1] += cpu
            fn = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
            records.append({
                "function": f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', '?')}",
                "types": str(tuple((ev.data or {}).get("args") or ())),
                "inclusive_s": cpu,
                "exclusive_s": cpu - inner,
            })  # fmt: skip

    t0, c0 = time.perf_counter(), time.process_time()
    with event.install_listener("numba:compile", Listener()):
        _job(name, work)
    return {"job": name, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "records": records}  # fmt: skip


def table(res: dict, top: int) -> str:
    by: dict = {}
    for r in res["records"]:
        e = by.setdefault(r["function"].replace("tdacm.", ""), [0, 0.0])
        e[0] += 1
        e[1] += r["exclusive_s"]
    total = sum(e[1] for e in by.values())
    lines = [
        f"job {res['job']}: {len(res['records'])} kernels ({len(by)} functions), "
        f"{total:.0f} s of compile CPU, {res['wall_s']:.0f} s wall",
        "",
        "| function | kernels | compile CPU s (exclusive) |",
        "|---|---|---|",
    ]
    for f, (n, s) in sorted(by.items(), key=lambda kv: -kv[1][1])[:top]:
        lines.append(f"| `{f}` | {n} | {s:.1f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("job", choices=["run", "engine", "engine-ekf", "vector-env"])
    p.add_argument("--top", type=int, default=25)
    p.add_argument("--json", default=None)
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)  # its result file
    a = p.parse_args()
    if a.child:  # in the fresh process, on the empty cache
        with tempfile.TemporaryDirectory() as work:
            res = record(a.job, work)
        with open(a.child, "w") as f:
            json.dump(res, f)
        sys.exit(0)
    print(f"compiling job {a.job!r} on an empty numba cache (minutes) ...", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="tdacm-empty-cache-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, TDACM_PARALLEL_COMPILE="0")
        result = os.path.join(cache, "result.json")
        out = subprocess.run([sys.executable, __file__, a.job, "--child", result], env=env,
                             capture_output=True, text=True, check=False)  # fmt: skip
        if out.returncode != 0:
            print(out.stderr[-3000:], file=sys.stderr)
            sys.exit(1)
        with open(result) as f:
            res = json.load(f)
    res["load"] = os.getloadavg()
    if a.json:
        os.makedirs(os.path.dirname(a.json) or ".", exist_ok=True)
        with open(a.json, "w") as f:
            json.dump(res, f)
    print(table(res, a.top))
