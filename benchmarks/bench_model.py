"""Benchmark of the coupled model (speed targets).  Run: ``python benchmarks/bench_model.py``
or ``tdacm bench``.  Reports medians; see ``docs/benchmarks.md`` for this machine's figures."""

from tdacm.bench import configure_logging, run_model_bench

if __name__ == "__main__":
    configure_logging()  # the tables on stdout, progress on stderr
    run_model_bench()
