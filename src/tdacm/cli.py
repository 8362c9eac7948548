"""Command-line interface: ``tdacm info``, ``tdacm demo``, ``tdacm bench``."""

from __future__ import annotations

import argparse
import json
import sys


def _cmd_info(args) -> int:
    from . import paper_system
    from .system.paper import PAPER_DEFAULTS_NOT_IN_PAPER

    system = paper_system()
    print(system.summary())
    print("  defaults not given by the paper:")
    for name, (value, why) in PAPER_DEFAULTS_NOT_IN_PAPER.items():
        print(f"    {name} = {value}  ({why})")
    return 0


def _cmd_demo(args) -> int:
    from pathlib import Path

    from .demo import run_demo

    summary = run_demo(args.out, duration=args.duration)
    out = Path(args.out).resolve()
    print(json.dumps(summary, indent=2))
    print(f"\nDemo output written to {out}/ (hover_tendon_step.png, .npz, .csv, summary.json)")
    return 0


def _cmd_bench(args) -> int:
    from .bench import run_model_bench

    run_model_bench(out=args.out, repeats=args.repeats)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tdacm",
        description="Tendon-driven aerial continuum manipulators: strain-parameterized coupled "
        "dynamics, dual-camera visual servoing, adaptive control.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("info", help="print the paper system's model summary")
    s.set_defaults(func=_cmd_info)
    s = sub.add_parser("demo", help="simulate the paper TD-ACM hovering with a tendon step")
    s.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    s.add_argument("--duration", type=float, default=4.0, help="simulated seconds (default 4)")
    s.set_defaults(func=_cmd_demo)
    s = sub.add_parser("bench", help="time the model (terms, forward dynamics, passive simulation)")
    s.add_argument("--out", default="out/bench", help="output folder for bench.json")
    s.add_argument("--repeats", type=int, default=7, help="timing repeats (median reported)")
    s.set_defaults(func=_cmd_bench)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
