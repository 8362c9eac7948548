"""A robustness campaign on the batched engine against the block loop: the wall time of
``examples/campaigns/paper-in-fov-1000-batched.toml`` (1,000 runs) on ``--workers`` Dask
workers, and of the same spec's first ``--block-runs`` runs on the block loop (scaled to the
campaign's runs), with both success rates and the machine's load.

    python benchmarks/bench_campaign.py [--runs 1000] [--block-runs 50] [--workers 2] [--out out/bench]

Writes the ``campaign`` section of ``OUT/bench.json``. The engine's kernels are compiled (or
read from numba's cache) before the clock starts: one warm-up chunk of 2 worlds, and one
block-loop run.
"""

import argparse
import dataclasses
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from tdacm.campaign import read_results, run_campaign
from tdacm.campaign.spec import load_spec

SPEC = Path(__file__).resolve().parents[1] / "examples/campaigns/paper-in-fov-1000-batched.toml"


def _campaign(spec, workers, out):
    shutil.rmtree(out, ignore_errors=True)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    run_campaign(spec, out, workers=workers, progress=False)
    wall = time.perf_counter() - t0
    df = read_results(out)
    return {
        "runs": int(len(df)),
        "wall_s": wall,
        "success_rate": float(df["success"].mean()),
        "errors": int((df["status"] == "error").sum()),
        "load_average_1min": [load0, os.getloadavg()[0]],
    }


def campaign_bench(runs: int, block_runs: int, workers: int) -> dict:
    spec = load_spec(SPEC)
    tmp = Path(tempfile.mkdtemp(prefix="tdacm-bench-campaign-"))
    try:
        # warm-up: the kernels compiled or read from the cache in this process and the workers
        _campaign(dataclasses.replace(spec, runs=2), 1, tmp / "warm")
        batched = _campaign(dataclasses.replace(spec, runs=runs), workers, tmp / "batched")
        block = _campaign(
            dataclasses.replace(spec, runs=block_runs, batched=False), workers, tmp / "block"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    block["wall_s_scaled"] = block["wall_s"] * runs / block_runs
    return {
        "spec": str(SPEC.name),
        "workers": workers,
        "cpu_count": os.cpu_count(),
        "batched": batched,
        "block_loop": block,
        "speedup": block["wall_s_scaled"] / batched["wall_s"],
    }


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--block-runs", type=int, default=50)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", default="out/bench")
    a = p.parse_args()
    res = campaign_bench(a.runs, a.block_runs, a.workers)
    path = Path(a.out) / "bench.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.is_file() else {}
    data["campaign"] = res
    path.write_text(json.dumps(data, indent=2))
    print(json.dumps(res, indent=2))
