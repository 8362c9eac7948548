"""GVS vs the constant-curvature Lagrangian baseline: per-iteration cost (model alone and a
50 Hz closed loop, same Python RK4 and step) and GVS cost vs strain DoFs / Gauss points.

Run: ``python benchmarks/bench_baseline.py [out_dir]``; the whole comparison (with accuracy)
is ``tdacm.bench.run_full_bench``.  See ``docs/benchmarks.md``."""

import json
import sys
from pathlib import Path

from tdacm.baselines import study
from tdacm.bench import configure_logging

if __name__ == "__main__":
    configure_logging()  # the tables on stdout
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    out.mkdir(parents=True, exist_ok=True)
    timing = study.timing_study()
    rows = study.scaling_study()
    study.print_report(
        timing, rows, {"duration_s": 0, "rk4_dt_s": 0, "cases": {}}, study.pyelastica_study()
    )
    study.plot_scaling(
        rows, out / "time_vs_dofs.png", timing["model"]["cc"]["forward_dynamics"]["median_s"]
    )
    (out / "bench_baseline.json").write_text(
        json.dumps({"baseline": timing, "scaling": rows}, indent=2)
    )
    print(f"written {out.resolve()}/bench_baseline.json, time_vs_dofs.png", file=sys.stderr)
