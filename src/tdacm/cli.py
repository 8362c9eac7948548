"""Command-line interface: ``tdacm info``, ``tdacm demo``, ``tdacm bench``, ``tdacm run``,
``tdacm scenarios``, ``tdacm campaign``, ``tdacm replay``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _cmd_info(args) -> int:
    from . import paper_system
    from .system.paper import PAPER_DEFAULTS_NOT_IN_PAPER

    system = paper_system()
    print(system.summary())
    print("  defaults not given by the paper:")
    for name, (value, why) in PAPER_DEFAULTS_NOT_IN_PAPER.items():
        print(f"    {name} = {value}  ({why})")
    print(
        "\nModel options (docs/model.md):\n"
        "  strain bases: StrainBasis(orders per mode [torsion, bending_y, bending_z, elongation,\n"
        "    shear_y, shear_z], kind='legendre'|'monomial' (monomial refused above order 6));\n"
        "    Rod(n_gauss=None, magnus_order=None) picks Magnus order 4 and max(8, 2(p+1)) Gauss\n"
        "    points; n_gauss must be >= p + 2 for a mode of order p\n"
        "  multi-section rods: SectionedRod([Rod(...), Rod(...)]), own length/material/basis each\n"
        "  tendons ending part-way: Tendons(offsets=..., ends=[s_i or None]) (arc length, m)\n"
        "  several rods on one drone: TDACM([rod_1, rod_2], [tendons_1, tendons_2], base,\n"
        "    [g_a1, g_a2]); q = [drone, rod 1, rod 2, ...]; dual_paper_system() = the dual TD-CR\n"
        "  integrators: simulate(method='auto'|'rk4'|'rosenbrock'|'radau'|'adaptive'); 'auto' = RK4\n"
        "    unless a torsion/elongation/shear basis needs RK4 steps < 1 ms, then 'radau'"
    )
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
    from .bench import run_full_bench, run_model_bench

    if args.full:
        run_full_bench(out=args.out, repeats=args.repeats)
    else:
        run_model_bench(out=args.out, repeats=args.repeats)
    return 0


def _cmd_run(args) -> int:
    from pathlib import Path

    from .sim import ScenarioError, run_scenario

    out = Path(args.out) if args.out else Path("out") / Path(args.scenario).stem
    try:
        _, summary = run_scenario(
            args.scenario,
            out=out,
            config=args.config,
            duration=args.duration,
            seed=args.seed,
            video=args.video,
            progress=True,
        )
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    print(f"\nRun written to {out.resolve()}/")
    return 1 if summary["terminated"] else 0


def _cmd_scenarios(args) -> int:
    from .sim import list_scenarios, load_scenario

    for name in list_scenarios():
        sc = load_scenario(name)
        print(f"{name:18s} {sc['duration']:5.1f} s  {sc['description']}")
    return 0


def _cmd_campaign(args) -> int:
    from .campaign import CampaignSpecError, run_campaign

    try:
        report = run_campaign(args.spec, args.out, workers=args.workers, scheduler=args.scheduler)
    except CampaignSpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    print((out / "report.md").read_text())
    print(f"Campaign written to {out.resolve()}/ (results/, report.md, report.png)")
    return 0 if report["complete"] else 1


def _cmd_replay(args) -> int:
    from .viz import replay_run

    path = replay_run(args.run_dir, args.out, fps=args.fps, max_frames=args.max_frames)
    print(f"3-D replay written to {path.resolve()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tdacm",
        description="Tendon-driven aerial continuum manipulators: strain-parameterized coupled "
        "dynamics, dual-camera visual servoing, adaptive control.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("info", help="print the paper system's model summary and the model options")
    s.set_defaults(func=_cmd_info)
    s = sub.add_parser("demo", help="simulate the paper TD-ACM hovering with a tendon step")
    s.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    s.add_argument("--duration", type=float, default=4.0, help="simulated seconds (default 4)")
    s.set_defaults(func=_cmd_demo)
    s = sub.add_parser(
        "bench",
        help="time the model (terms, forward dynamics, passive simulation, stiff integrators)",
    )
    s.add_argument("--out", default="out/bench", help="output folder for bench.json")
    s.add_argument("--repeats", type=int, default=7, help="timing repeats (median reported)")
    s.add_argument(
        "--full",
        action="store_true",
        help="add the CC Lagrangian baseline comparison, DoF scaling and accuracy study (minutes)",
    )
    s.set_defaults(func=_cmd_bench)
    s = sub.add_parser("run", help="run a closed-loop scenario (see `tdacm scenarios`)")
    s.add_argument("scenario", help="scenario name or path to a scenario TOML file")
    s.add_argument("--config", help="TOML file overriding scenario values (same layout)")
    s.add_argument("--out", help="output folder (default: out/SCENARIO)")
    s.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's)")
    s.add_argument("--seed", type=int, help="seed of the model perturbation and noise")
    s.add_argument("--video", action="store_true", help="write video.mp4 (C_L | C_G)")
    s.set_defaults(func=_cmd_run)
    s = sub.add_parser("scenarios", help="list the shipped scenarios")
    s.set_defaults(func=_cmd_scenarios)
    s = sub.add_parser("campaign", help="run a robustness campaign on Dask (resumable)")
    s.add_argument("spec", help="campaign spec TOML (see docs/campaigns.md)")
    s.add_argument("--workers", type=int, help="local Dask worker processes (default: CPU count)")
    s.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:port)")
    s.add_argument("--out", default="out/campaign", help="output folder; rerun to resume")
    s.set_defaults(func=_cmd_campaign)
    s = sub.add_parser("replay", help="3-D animation (GIF or MP4) of a `tdacm run` folder")
    s.add_argument("run_dir", help="a folder written by `tdacm run`")
    s.add_argument("--out", help="output .gif or .mp4 (default: RUN_DIR/replay.gif)")
    s.add_argument("--fps", type=int, default=20)
    s.add_argument("--max-frames", type=int, default=60)
    s.set_defaults(func=_cmd_replay)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
