"""Where compile time goes, and what the shipped kernels cost at run time.

    python benchmarks/bench_compile.py [JOB ...] [--out out/bench]    # the compile tables
    python benchmarks/bench_compile.py --from out/bench/compile.json --write-estimates
    python benchmarks/bench_compile.py --portable [--rounds 2]       # portable / host-tuned
    python benchmarks/bench_compile.py --portable --wheel DIR         # ... a wheel's kernels
    python benchmarks/bench_compile.py --against /other/src [--rounds 2]  # run-time speed of
                                                  # this tree against another source tree

The tables (``tdacm bench --compile JOB`` prints the same): each job of
:data:`tdacm.bench.compile.JOBS` (default all) in a fresh process on an empty numba cache, each
kernel's compile seconds (the compiling thread's CPU, exclusive of the callees it compiled,
and wall), the total and the count; the records go to ``OUT/compile.json``.
``--write-estimates`` writes the notice's estimates (``src/tdacm/data/compile_times.json``,
:mod:`tdacm._compiling`) from those records.

``--portable``: the run-time cost of the wheel's portable target (``NUMBA_CPU_NAME=generic``,
no added CPU features) against host-tuned code: the paper system's forward dynamics in a
compiled loop and the engine's world-periods/s (256 worlds, 2 threads), in fresh processes
alternating the two targets (:func:`tdacm.bench.compile.speed_ab`; each target's kernels in
its own cache under ``OUT/targets/``, compiled by a first untimed process). With ``--wheel
DIR`` (an unpacked wheel: ``python -m zipfile -e tdacm-*.whl DIR``) the portable side is the
wheel's package with its shipped kernels, the host side this checkout's.

``--against DIR``: the same measures of this checkout against the package in ``DIR`` (a
``src`` folder of another version, e.g. a ``git worktree``), alternating.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tdacm.bench.compile import (
    JOBS,
    portable_env,
    profile,
    speed_ab,
    summary,
    table,
    write_estimates,
)

ROOT = Path(__file__).resolve().parents[1]
ESTIMATES = ROOT / "src" / "tdacm" / "data" / "compile_times.json"

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("jobs", nargs="*", help=f"of {', '.join(JOBS)} (default all)")
    p.add_argument("--out", default="out/bench")
    p.add_argument("--from", dest="from_json", default=None, help="tables of an earlier run")
    p.add_argument("--write-estimates", action="store_true")
    p.add_argument("--portable", action="store_true")
    p.add_argument("--wheel", default=None, metavar="DIR", help="an unpacked wheel")
    p.add_argument("--against", default=None, metavar="SRC")
    p.add_argument("--rounds", type=int, default=2)
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.portable or a.against:
        if a.portable:
            variants = {
                "host": {
                    "PYTHONPATH": str(ROOT / "src"),
                    "TDACM_KERNEL_CACHE": "local",
                    # against a wheel: this checkout's own cache (what its tests compiled)
                    **({} if a.wheel else {"NUMBA_CACHE_DIR": str(out / "targets" / "host")}),
                },  # fmt: skip
                "portable": (
                    {
                        "PYTHONPATH": str(ROOT / "src"),
                        **portable_env(out / "targets" / "portable"),
                    }  # fmt: skip
                    if a.wheel is None
                    else {  # the unpacked wheel's package with its shipped kernels
                        "PYTHONPATH": str(Path(a.wheel).resolve()),
                        "NUMBA_CACHE_DIR": str(out / "targets" / "wheel-others"),
                        "TDACM_KERNEL_CACHE": "shipped",
                    }
                ),
            }
        else:
            variants = {
                "this": {"PYTHONPATH": str(ROOT / "src")},
                "against": {"PYTHONPATH": str(Path(a.against).resolve())},
            }
        res = speed_ab(variants, rounds=a.rounds)
        name = "portable.json" if a.portable else "against.json"
        (out / name).write_text(json.dumps(res, indent=1))
        print(json.dumps({k: v for k, v in res.items() if k != "runs"}, indent=1))
    else:
        if a.from_json:
            results = json.loads(Path(a.from_json).read_text())
        else:
            results = {}
            for job in a.jobs or list(JOBS):
                results[job] = profile(job)
                (out / "compile.json").write_text(json.dumps(results, indent=1))
        for res in results.values():
            print(table(res) + "\n")
        for job, res in results.items():
            s = summary(res)
            print(f"{job}: {s['kernels']} kernels, {s['compile_cpu_s']:.1f} s of compile CPU")
        if a.write_estimates:
            print(f"estimates written to {write_estimates(results, ESTIMATES)}")
