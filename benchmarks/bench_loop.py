"""Closed-loop speed: rendered and analytic C_L, and the cold first run.

    python benchmarks/bench_loop.py [--repeats 5] [--no-cold] [--cold-ab ROUNDS] [--out out/bench]

Writes the ``loop`` section of ``OUT/bench.json`` (see :mod:`tdacm.bench.loop`).
"""

import argparse
import json

from tdacm.bench.loop import run_loop_bench

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--no-cold", action="store_true")
    p.add_argument("--cold-ab", type=int, default=0, help="rounds of one vs two compile processes")
    p.add_argument("--out", default="out/bench")
    a = p.parse_args()
    print(json.dumps(run_loop_bench(a.out, a.repeats, not a.no_cold, cold_ab=a.cold_ab), indent=2))
