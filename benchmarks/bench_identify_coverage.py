"""Coverage of the reported standard deviations: over many seeds, how often the 2-sigma
interval of each estimate contains the hidden value.

The rod's four parameters from ``tendon-steps`` and ``tendon-steps-loaded`` (documented
noise, start 30 % off, decimate 2) on the scenario's basis, or with ``--basis`` on a hidden
robot of that basis fitted on it. Reports, per parameter, the share of seeds with
``|error| <= 2 std`` for the reported standard deviation (the larger of the stated noise
model's and the sandwich's), for each of those two and for the white-residual one; writes
``bench_identify_coverage.json``.

Run: ``python benchmarks/bench_identify_coverage.py [out] --seeds 1000-1019``."""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from tdacm.identify import DEFAULT_TRUTH, synthesize, truth_errors
from tdacm.identify.fit import identify

ROD = ("E", "damping", "tip_mass", "radius")


def seeds_of(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default="out/bench")
    ap.add_argument("--seeds", default="1000-1019")
    ap.add_argument("--basis", default=None, help="hidden and fitted basis (default: scenario's)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for seed in seeds_of(args.seeds):
        recs = [synthesize(e, seed=seed, basis=args.basis)
                for e in ("tendon-steps", "tendon-steps-loaded")]  # fmt: skip
        if args.basis:
            recs = [r.with_basis(args.basis) for r in recs]
        t0 = time.perf_counter()
        res = identify(recs, list(ROD), start={k: 1.3 * DEFAULT_TRUTH[k] for k in ROD},
                       decimate=2)  # fmt: skip
        err = truth_errors(res, DEFAULT_TRUTH)
        iid = {k: res.std_iid[k] / res.values[k] for k in ROD}
        sw = {k: res.std_sandwich[k] / res.values[k] for k in ROD}
        nm = {k: res.std_noise[k] / res.values[k] for k in ROD}
        runs.append({"seed": seed, "errors": err, "relative_std": res.rel_std,
                     "relative_std_noise_model": nm, "relative_std_sandwich": sw,
                     "relative_std_white": iid, "residual_variance": res.residual_variance,
                     "lags": res.lags, "seconds": time.perf_counter() - t0,
                     "load_average": os.getloadavg()})  # fmt: skip
        print(f"seed {seed}: " + "  ".join(
            f"{k} {100 * err[k]:+.3f}% (reported {100 * res.rel_std[k]:.3f}%, noise model "
            f"{100 * nm[k]:.3f}%, sandwich {100 * sw[k]:.3f}%, white {100 * iid[k]:.3f}%)"
            for k in ROD) + f"  s2 {res.residual_variance:.2f}  {runs[-1]['seconds']:.0f} s",
            flush=True)  # fmt: skip
        kinds = (
            ("reported", "relative_std"),
            ("noise_model", "relative_std_noise_model"),
            ("sandwich", "relative_std_sandwich"),
            ("white", "relative_std_white"),
        )
        cover = {
            kind: {k: float(np.mean([abs(r["errors"][k]) <= 2 * r[key][k] for r in runs]))
                   for k in ROD}
            for kind, key in kinds
        }  # fmt: skip
        (out / "bench_identify_coverage.json").write_text(
            json.dumps({"coverage_2sigma": cover, "runs": runs}, indent=2, default=float)
        )
    print(f"2-sigma coverage over {len(runs)} seeds: {json.dumps(cover)}")
