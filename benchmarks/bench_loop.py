"""Closed-loop speed: rendered and analytic C_L, and the cold first run.

    python benchmarks/bench_loop.py [--repeats 5] [--no-cold] [--cold-ab ROUNDS] [--env] [--out out/bench]

Writes the ``loop`` section of ``OUT/bench.json`` (see :mod:`tdacm.bench.loop`) and, with
``--env``, the ``env`` section measured in the same run (:mod:`tdacm.bench.env`).
"""

import argparse
import json
from pathlib import Path

from tdacm.bench.loop import run_loop_bench

if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--no-cold", action="store_true")
    p.add_argument("--cold-ab", type=int, default=0, help="rounds of one vs two compile processes")
    p.add_argument("--env", action="store_true", help="also the Gymnasium env's figures")
    p.add_argument("--out", default="out/bench")
    a = p.parse_args()
    res = {"loop": run_loop_bench(a.out, a.repeats, not a.no_cold, cold_ab=a.cold_ab)}
    if a.env:
        from tdacm.bench.env import env_bench

        res["env"] = env_bench(repeats=a.repeats)
        path = Path(a.out) / "bench.json"
        data = json.loads(path.read_text())
        data["env"] = res["env"]
        path.write_text(json.dumps(data, indent=2))
    print(json.dumps(res, indent=2))
