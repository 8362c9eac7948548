"""Benchmark of the coupled model (speed targets).  Run: ``python benchmarks/bench_model.py``
or ``tdacm bench``.  Reports medians; see ``docs/benchmarks.md`` for this machine's figures.

``python benchmarks/bench_model.py --against REV [REV ...]`` times instead the forward dynamics
of this checkout against that of each git revision ``REV`` in one process: the module
``tdacm/system/forward.py`` of ``REV`` (the recursion, its workspace and solve), over the
module ``tdacm/system/kernels.py`` of ``REV`` (the helpers it calls), is loaded beside the
current ones, and compiled loops of ``workspace`` + ``forward_dynamics_ws`` (what
``forward_dynamics`` does per call) run alternately, round by round, on the paper system and
the 18-DoF rod; the model arrays are this checkout's (a revision reads the fields it knows).
Prints, per
revision, the medians, the 10th percentiles, the median of the paired ratios (revision over
current) and the largest difference of ``qdd`` from the current one on random states, and the
load average.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _module_at(rev: str, path: str, name: str, where: Path, edits=()):
    """The file ``path`` of ``rev`` as the top-level module ``name`` (relative imports made
    absolute, then the replacements ``edits``)."""
    text = subprocess.run(
        ["git", "show", f"{rev}:{path}"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout
    text = re.sub(r"from \.\.(\w)", r"from tdacm.\1", text)
    for a, b in edits:
        text = text.replace(a, b)
    where.mkdir(parents=True, exist_ok=True)
    file = where / f"{name}.py"
    if not file.exists() or file.read_text() != text:
        file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _load_forward_at(rev: str, where: Path):
    """The forward module of ``rev`` over the kernels module of ``rev`` (its helpers: the
    tendon sums, the body wrenches), both as top-level modules; the revision's kernels take
    this checkout's forward module for their own forward dynamics (unused here)."""
    tag = re.sub(r"\W", "_", rev)
    kernels = _module_at(
        rev, "src/tdacm/system/kernels.py", f"kernels_at_{tag}", where,
        [("from . import forward as _F", "from tdacm.system import forward as _F")],
    )  # fmt: skip
    return _module_at(
        rev, "src/tdacm/system/forward.py", f"forward_at_{tag}", where,
        [("from . import kernels as K", f"import {kernels.__name__} as K")],
    )  # fmt: skip


def _loop(F):
    from numba import njit

    @njit
    def loop(q, qd, u, m, loads, count):
        e = np.empty(0)
        acc = 0.0
        for _ in range(count):
            ws = F.workspace(q.shape[0], m)
            qdd = np.empty(q.shape[0])
            F.forward_dynamics_ws(q, qd, u, m, loads, e, e, ws, qdd)
            acc += qdd[0]
        return acc

    return loop


def _qdd(F, q, qd, u, m, loads):
    e = np.empty(0)
    qdd = np.empty(q.shape[0])
    F.forward_dynamics_ws(q, qd, u, m, loads, e, e, F.workspace(q.shape[0], m), qdd)
    return qdd


def compare(revs, rounds: int = 41, calls: int = 200, out: str = "out/bench-model-ab"):
    import tdacm.system.forward as new
    from tdacm.bench.model import bench_state
    from tdacm.rod import StrainBasis
    from tdacm.system import paper_system

    revs = [revs] if isinstance(revs, str) else list(revs)
    mods = {"current": new}
    for rev in revs:
        mods[rev] = _load_forward_at(rev, Path(out) / "modules")
    loops = {k: _loop(f) for k, f in mods.items()}
    load0 = open("/proc/loadavg").read().split()[:3]
    rows = []
    rich = paper_system(basis=StrainBasis((3, 3, 3, None, None, None)), n_gauss=8, magnus_order=4)
    for name, s in (("paper", paper_system()), ("18-DoF", rich)):
        m, loads = s.model_arrays, s.loads.packed()
        q, qd, u = bench_state(s)
        diff = dict.fromkeys(revs, 0.0)
        for seed in range(5):  # random states: each revision's qdd against the current one
            r = np.random.default_rng(100 + seed)
            qs = q + r.normal(size=s.n) * 0.2
            qds = r.normal(size=s.n)
            a = _qdd(new, qs, qds, u, m, loads)
            for rev in revs:
                b = _qdd(mods[rev], qs, qds, u, m, loads)
                d = float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))
                diff[rev] = max(diff[rev], d)
        times = {k: [] for k in loops}
        for f in loops.values():
            f(q, qd, u, m, loads, 1)
        for _ in range(rounds):
            for k, f in loops.items():
                t0 = time.perf_counter()
                f(q, qd, u, m, loads, calls)
                times[k].append((time.perf_counter() - t0) / calls * 1e6)
        cur = np.array(times["current"])
        row = {
            "system": name,
            "n": s.n,
            "current_median_us": float(np.median(cur)),
            "current_p10_us": float(np.percentile(cur, 10)),
            "against": {},
        }
        print(
            f"{name:7s} n={s.n:2d}  current {row['current_median_us']:7.2f} us "
            f"(p10 {row['current_p10_us']:6.2f})"
        )
        for rev in revs:
            ref = np.array(times[rev])
            r = {
                "median_us": float(np.median(ref)),
                "p10_us": float(np.percentile(ref, 10)),
                "ratio_median_of_paired": float(np.median(ref / cur)),
                "max_relative_difference_qdd": diff[rev],
            }
            row["against"][rev] = r
            print(
                f"{'':13s}{rev:>8s} {r['median_us']:7.2f} us (p10 {r['p10_us']:6.2f})  "
                f"ratio {r['ratio_median_of_paired']:.2f}x  qdd difference {diff[rev]:.1e}"
            )
        rows.append(row)
    load1 = open("/proc/loadavg").read().split()[:3]
    print(f"load average (1, 5, 15 min): {load0} at the start, {load1} at the end")
    res = {"against": revs, "rounds": rounds, "calls": calls, "rows": rows, "load": [load0, load1]}
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / "ab.json").write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--against", metavar="REV", nargs="+", help="time against the forward module of each REV"
    )
    p.add_argument("--rounds", type=int, default=41)
    p.add_argument("--out", default="out/bench-model-ab")
    a = p.parse_args()
    if a.against:
        compare(a.against, rounds=a.rounds, out=a.out)
    else:
        from tdacm.bench import configure_logging, run_model_bench

        configure_logging()  # the tables on stdout, progress on stderr
        run_model_bench()
