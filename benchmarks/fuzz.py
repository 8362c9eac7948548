"""Fuzz the closed loop (tdacm.campaign.fuzz): thousands of short episodes with random robots,
sensors, initial states and actions; prints the counts by termination and any exception.

    python benchmarks/fuzz.py --episodes 2000 --seed 0 --out out/fuzz

Writes ``OUT/fuzz.json`` (every episode: case, policy, outcome, reason, steps, overrides) and
``OUT/fuzz.txt`` (the report) after every case, so an interrupted run keeps what it did.
Exit status 1 if any episode raised an exception.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from tdacm.campaign.fuzz import fuzz, main_report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out/fuzz")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    w0 = time.perf_counter()

    def save(outcomes):
        wall = time.perf_counter() - w0
        (out / "fuzz.json").write_text(
            json.dumps([dataclasses.asdict(o) for o in outcomes], indent=1, default=str)
        )
        (out / "fuzz.txt").write_text(main_report(outcomes, wall) + "\n")

    outcomes = fuzz(args.episodes, args.seed, progress=save)
    save(outcomes)
    print((out / "fuzz.txt").read_text())
    return 1 if any(o.outcome == "exception" for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
