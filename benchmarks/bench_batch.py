"""The batched engine's speed: world-periods/s over batch sizes and threads, one world's
real-time factor, the first call cold and warm.

    python benchmarks/bench_batch.py [--sizes 1 4 16 64 256 1024] [--repeats 3] [--out out/bench]
        [--duration 2] [--predicted] [--no-cold] [--no-vector]
    python benchmarks/bench_batch.py --filter-only     # the target filter's cost, N = 256
    python benchmarks/bench_batch.py --vector-only     # gym.make_vec(..., num_envs=256)
    python benchmarks/bench_batch.py --touch-only --sizes 16 [--estimated]   # whole touch-target runs
    python benchmarks/bench_batch.py --allocations-only   # numba's allocations a world-period
    python benchmarks/bench_batch.py --split-only [--sizes 64]   # a period's two halves in a run
    python benchmarks/bench_batch.py --engine-compile   # the engine's own compile (its cache entries
                                                        # removed), in one process, then in two
    python benchmarks/bench_batch.py --rate-only --scenario dual-in-fov [--estimated]
        [--sizes 256] [--threads 2]   # world-periods/s of one scenario (the largest size and
                                      # thread count given), and CPU a world-period

``--predicted`` adds the table with the robust servo's target filter in the period
(``--features predicted``: that table alone); the table is printed as markdown at the end.

Writes the ``batch`` section of ``OUT/bench.json`` (see :mod:`tdacm.bench.batch`; with
``--filter-only`` its ``filter`` entry only: env-steps/s with and without the robust servo's
target filter in the period).
"""

import argparse
import json
from pathlib import Path

from tdacm.bench.batch import (
    allocations,
    batch_bench,
    engine_first_call,
    filter_cost,
    period_split,
    periods_per_second,
    touch_rate,
    vector_env_rate,
)

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 4, 16, 64, 256, 1024])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default="out/bench")
    p.add_argument("--filter-only", action="store_true")
    p.add_argument("--vector-only", action="store_true")
    p.add_argument("--touch-only", action="store_true")
    p.add_argument("--allocations-only", action="store_true")
    p.add_argument("--split-only", action="store_true")
    p.add_argument("--engine-compile", action="store_true")
    p.add_argument("--rate-only", action="store_true")
    p.add_argument("--scenario", default="paper-in-fov")
    p.add_argument("--estimated", action="store_true")
    p.add_argument("--duration", type=float, default=2.0)
    p.add_argument("--predicted", action="store_true")
    p.add_argument("--features", nargs="+", choices=["measured", "predicted"], default=None)
    p.add_argument("--no-cold", action="store_true")
    p.add_argument("--no-vector", action="store_true")
    a = p.parse_args()
    path = Path(a.out) / "bench.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.is_file() else {}
    if a.filter_only:
        res = filter_cost(threads=max(a.threads), repeats=a.repeats)
        data.setdefault("batch", {})["filter"] = res
    elif a.allocations_only:
        res = allocations(4, 1, a.duration)
        data.setdefault("batch", {})["allocations"] = res
    elif a.split_only:
        res = period_split(min(a.sizes), scenario=a.scenario)
        data.setdefault("batch", {})["split_" + a.scenario] = res
    elif a.engine_compile:
        res = {"one_process_s": engine_first_call(parallel=False),
               "two_processes_s": engine_first_call(parallel=True)}  # fmt: skip
        data.setdefault("batch", {})["engine_compile"] = res
    elif a.rate_only:
        rate, cpu_ms = periods_per_second(max(a.sizes), max(a.threads), a.duration, a.repeats,
                                          cpu=True, scenario=a.scenario,
                                          estimated=a.estimated)  # fmt: skip
        res = {"scenario": a.scenario, "estimated": a.estimated, "n_worlds": max(a.sizes),
               "threads": max(a.threads), "rate": rate, "cpu_us": 1e3 * cpu_ms}  # fmt: skip
        data.setdefault("batch", {})["rate_" + a.scenario + ("_estimated" * a.estimated)] = res
    elif a.touch_only:
        res = touch_rate(min(a.sizes), max(a.threads), a.repeats, estimated=a.estimated)
        data.setdefault("batch", {})["touch" + ("_estimated" if a.estimated else "")] = res
    elif a.vector_only:
        res = vector_env_rate(threads=max(a.threads), repeats=a.repeats)
        data.setdefault("batch", {})["vector_env"] = res
    else:
        feats = ("measured", "predicted") if a.predicted else ("measured",)
        if a.features:
            feats = tuple(a.features)
        res = batch_bench(tuple(a.sizes), tuple(a.threads), a.repeats, duration=a.duration,
                          servo_modes=feats, vector=not a.no_vector, cold=not a.no_cold)  # fmt: skip
        data["batch"] = res
    path.write_text(json.dumps(data, indent=2))
    print(json.dumps(res, indent=2))
