"""Identification of the paper robot's five main parameters (E, damping, tip mass, tendon
radius, drone mass) from the shipped excitation experiments (tendon-steps, the same with a
known 20 g clip-on tip mass, hover), starting 30 % off the hidden values; then the held-out
5 s prediction.

Run: ``python benchmarks/bench_identify.py [out_dir] [--repeats N] [--seeds 101,202]``.
Prints per seed the errors against the hidden values, the fit's wall time, and the median
time; writes ``bench_identify.json``. See ``docs/identify.md``."""

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from tdacm.identify import DEFAULT_TRUTH, MAIN_PARAMETERS, synthesize, truth_errors
from tdacm.identify.fit import identify_staged
from tdacm.identify.validate import held_out_rms

#: The shipped experiments the five parameters are identified from.
EXPERIMENTS = ("tendon-steps", "tendon-steps-loaded", "hover")
#: Fit every 2nd sample (50 Hz, RK4 at 20 ms): see ``identify(decimate=...)``.
DECIMATE = 2


def one(seed: int, scale: float) -> dict:
    recs = [synthesize(e, seed=seed) for e in EXPERIMENTS]
    start = {k: scale * DEFAULT_TRUTH[k] for k in MAIN_PARAMETERS}
    t0, c0 = time.perf_counter(), time.process_time()
    res = identify_staged(recs, list(MAIN_PARAMETERS), start=start, decimate=DECIMATE)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    held = held_out_rms(res.values, seed=seed)
    return {
        "seed": seed,
        "start_scale": scale,
        "seconds": wall,
        "cpu_seconds": cpu,
        "load_average": os.getloadavg(),  # the machine is shared: (1, 5, 15 min) at the end
        "estimates": res.values,
        "relative_std": res.rel_std,
        "relative_error": truth_errors(res, DEFAULT_TRUTH),
        "residual_variance": res.residual_variance,
        "nfev": res.nfev,
        "held_out_tip_rms_m": held,
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default="out/bench")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seeds", default="101,202,303")
    ap.add_argument("--scale", type=float, default=1.3, help="start = scale * hidden value")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = [int(s) for s in args.seeds.split(",")]
    runs = []
    for i in range(args.repeats):
        r = one(seeds[i % len(seeds)], args.scale)
        runs.append(r)
        errs = "  ".join(f"{k} {100 * v:+.2f}%" for k, v in r["relative_error"].items())
        print(f"seed {r['seed']}: {r['seconds']:.1f} s (CPU {r['cpu_seconds']:.1f} s)  {errs}  "
              f"held-out tip RMS {1e3 * r['held_out_tip_rms_m']:.2f} mm")  # fmt: skip
    med = statistics.median(r["seconds"] for r in runs)
    cpu = statistics.median(r["cpu_seconds"] for r in runs)
    print(f"median identification time: {med:.1f} s wall, {cpu:.1f} s CPU over {len(runs)} runs")
    (out / "bench_identify.json").write_text(
        json.dumps(
            {"median_seconds": med, "median_cpu_seconds": cpu, "runs": runs},
            indent=2,
            default=float,
        )  # fmt: skip
    )
