"""Benchmark of the coupled model (issue: speed targets).  Run: ``python benchmarks/bench_model.py``
or ``tdacm bench``.  Reports medians; see ``docs/benchmarks.md`` for this machine's figures."""

from tdacm.bench import run_model_bench

if __name__ == "__main__":
    run_model_bench()
