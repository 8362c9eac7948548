"""The strain basis chosen from the data: hidden robots on richer bases than the scenario's
paper basis (``bending:0``), identified with basis selection.

For each hidden basis and seed: ``tendon-steps`` and ``tendon-steps-loaded`` (the rod's four
parameters, start 30 % off) and the ``held-out`` experiment (validation and the choice),
synthesized on the hidden basis with the documented noise; ``select_basis`` over the candidate
bases (decimate 2). Prints the candidates' table, the chosen basis's errors against the hidden
values, which bases were flagged (misfit), and the time; writes ``bench_identify_bases.json``.

Run: ``python benchmarks/bench_identify_bases.py [out] --truth bending:2,bending:3
--seeds 707 --bases bending:0,bending:1,bending:2``. See ``docs/identify.md``."""

import argparse
import json
import os
import time
from pathlib import Path

from tdacm.identify import DEFAULT_TRUTH, synthesize, truth_errors
from tdacm.identify.select import select_basis, selection_table

ROD = ("E", "damping", "tip_mass", "radius")
LIMITS = {"E": 0.02, "damping": 0.10, "tip_mass": 0.05, "radius": 0.03}


def one(truth_basis: str, seed: int, bases, scale: float = 1.3) -> dict:
    recs = [synthesize(e, seed=seed, basis=truth_basis) for e in ("tendon-steps",
            "tendon-steps-loaded")]  # fmt: skip
    held = synthesize("held-out", seed=seed, basis=truth_basis)
    start = {k: scale * DEFAULT_TRUTH[k] for k in ROD}
    t0, c0 = time.perf_counter(), time.process_time()
    res = select_basis(recs, list(ROD), bases, held_out=[held], start=start, decimate=2)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    err = truth_errors(res, DEFAULT_TRUTH)
    return {
        "truth_basis": truth_basis,
        "seed": seed,
        "chosen": res.rod_basis,
        "errors": err,
        "relative_std": res.rel_std,
        "within_limits": {k: abs(err[k]) < LIMITS[k] for k in ROD},
        "flagged": [r["basis"] for r in res.selection if r["misfit"]],
        "selection": res.selection,
        "seconds": wall,
        "cpu_seconds": cpu,
        "load_average": os.getloadavg(),  # the machine is shared: (1, 5, 15 min) at the end
        "table": selection_table(res.selection),
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default="out/bench")
    ap.add_argument("--truth", default="bending:2,bending:3")
    ap.add_argument("--seeds", default="707")
    ap.add_argument("--bases", default="bending:0,bending:1,bending:2")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for tb in args.truth.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            r = one(tb, seed, args.bases.split(","))
            runs.append(r)
            print(f"hidden {tb}, seed {seed}: chosen {r['chosen']}, flagged {r['flagged']}, "
                  f"{r['seconds']:.0f} s wall ({r['cpu_seconds']:.0f} s CPU)")  # fmt: skip
            print(r["table"])
            print("  " + "  ".join(f"{k} {100 * v:+.2f}% (std {100 * r['relative_std'][k]:.2f}%)"
                                   for k, v in r["errors"].items()), flush=True)  # fmt: skip
            (out / "bench_identify_bases.json").write_text(json.dumps(runs, indent=2,
                                                                      default=float))  # fmt: skip
