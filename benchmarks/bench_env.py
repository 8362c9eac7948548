"""Gymnasium env speed: one env's steps/s, reset ms, two async envs' env-steps/s.

    python benchmarks/bench_env.py [--steps 1000] [--repeats 5] [--out out/bench]

Writes the ``env`` section of ``OUT/bench.json`` (see :mod:`tdacm.bench.env`).
"""

import argparse
import json
from pathlib import Path

from tdacm.bench.env import env_bench

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default="out/bench")
    a = p.parse_args()
    res = env_bench(a.steps, a.repeats)
    path = Path(a.out) / "bench.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.is_file() else {}
    data["env"] = res
    path.write_text(json.dumps(data, indent=2))
    print(json.dumps(res, indent=2))
