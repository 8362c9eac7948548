"""Tip accuracy of the CC baseline and GVS orders 0..3 against a converged GVS reference
(clamped rod swinging under gravity; tendon-bent rod with a tip dead load).

Run: ``python benchmarks/bench_accuracy.py [out_dir]``.  See ``docs/benchmarks.md``."""

import json
import sys
from pathlib import Path

from tdacm.baselines import study

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    out.mkdir(parents=True, exist_ok=True)
    acc = study.accuracy_study()
    for case, res in acc["cases"].items():
        print(f"{case}: {res['description']}")
        print(f"  reference self-check {res['reference_self_error_m'] * 1e3:.3f} mm")
        for name, row in res["models"].items():
            print(
                f"  {name:6s} n_s={row['n_s']:2d} {row['fd_us']:7.1f} us/call  "
                f"max {row['max_error_m'] * 1e3:8.2f} mm  rms {row['rms_error_m'] * 1e3:8.2f} mm"
            )
    study.plot_accuracy(acc, out / "error_vs_time.png")
    (out / "bench_accuracy.json").write_text(json.dumps(acc, indent=2))
    print(f"written {out.resolve()}/bench_accuracy.json, error_vs_time.png", file=sys.stderr)
