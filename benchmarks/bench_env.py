"""Gymnasium env speed: one env's steps/s, reset ms, two async envs' env-steps/s; the vector
env on the batched engine: env-steps/s for N = 1, 16, 64, 256 worlds on 1 and 2 threads.

    python benchmarks/bench_env.py [--steps 1000] [--repeats 5] [--out out/bench]
                                   [--only single|vector]

Writes the ``env`` and ``vector_env`` sections of ``OUT/bench.json`` (see
:mod:`tdacm.bench.env`: ``env_bench``, ``vector_bench``; the vector env's figures are medians
of 3 runs).
"""

import argparse
import json
from pathlib import Path

from tdacm.bench.env import env_bench, vector_bench

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default="out/bench")
    p.add_argument("--only", choices=["single", "vector"], default=None)
    a = p.parse_args()
    path = Path(a.out) / "bench.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.is_file() else {}
    if a.only != "vector":
        data["env"] = env_bench(a.steps, a.repeats)
        print(json.dumps(data["env"], indent=2))
    if a.only != "single":
        data["vector_env"] = vector_bench()
        print(json.dumps(data["vector_env"], indent=2))
    path.write_text(json.dumps(data, indent=2))
