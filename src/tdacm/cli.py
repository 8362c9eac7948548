"""Command-line interface: ``tdacm info``, ``demo``, ``bench``, ``run``, ``plot``, ``scenarios``,
``campaign``, ``replay``, ``export`` (MCAP), ``import`` (MCAP through a topic map), ``replay-recording``
(a recording through perception and estimation), ``identify`` (parameters from recordings).

Conventions: stdout carries only the program's own output (``tdacm run`` prints the summary JSON
alone, so ``tdacm run ... | python -m json.tool`` works); notices, progress lines and "written
to" lines go to stderr. Invalid input exits with status 2 and one ``error:`` line naming the
flag or the scenario key; Ctrl-C exits with status 130 and one line (``tdacm run`` writes the
steps simulated so far; a campaign keeps its stored runs and resumes when rerun). ``tdacm run``
exits 0 when the run reached its duration and 1 when an outcome ended it early (the summary's
``termination``: safety monitor, failed recovery, plant, tumbled drone, point behind the virtual
camera, estimator, non-finite command; every output written), see :func:`main`.

Logging: the library logs through ``logging.getLogger(__name__)`` under the ``tdacm`` logger;
the command line sends it to stderr in a plain format, at INFO by default, DEBUG with ``-v`` and
warnings only with ``-q`` (which also hides the progress bars and notices).
"""

from __future__ import annotations

import argparse
import inspect
import json
import logging
import math
import sys
from pathlib import Path

from ._log import StderrHandler, configure_logging


def _err(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def _note(msg: str) -> None:
    """A notice on stderr (through logging: hidden by ``-q``)."""
    if not any(isinstance(h, StderrHandler) for h in logging.getLogger("tdacm").handlers):
        configure_logging()  # a command called without main(), e.g. from the tests
    logging.getLogger("tdacm.cli").info(msg)


# ------------------------------------------------------------------ argument types
def _number_type(kind, ok, what: str):
    """An argparse type: ``kind(text)`` that ``ok`` accepts, else the message ``must be <what>``."""

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
        return v

    return parse


_positive_int = _number_type(int, lambda v: v >= 1, "a positive integer")
_nonneg_int = _number_type(int, lambda v: v >= 0, "a non-negative integer")
_positive_float = _number_type(
    float, lambda v: math.isfinite(v) and v > 0, "a finite positive number"
)


def _address(text: str):
    """An argparse type: ``[HOST:]PORT`` of ``--live`` (:func:`tdacm.live.parse_address`)."""
    from .live.server import LiveError, parse_address

    try:
        return parse_address(text)
    except LiveError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _start_live(address):
    """``(server, None)``: the live server of ``--live`` listening (:class:`tdacm.live.LiveServer`),
    or ``(None, the one-line error)``; ``(None, None)`` without ``--live``."""
    if address is None:
        return None, None
    from .live import LiveError, LiveServer, is_loopback

    host, port = address
    try:
        server = LiveServer(host, port)
    except LiveError as exc:
        return None, f"--live {exc}"
    _note(f"tdacm: live at {server.url} (Foxglove: Open connection, Foxglove WebSocket; "
          f"layout: {_layout_path()})")  # fmt: skip
    if not is_loopback(host):
        _note(f"tdacm: --live listens on {host}: other machines that reach it can watch")
    return server, None


def _layout_path() -> Path:
    """The shipped Foxglove layout (docs/live.md)."""
    from .live import LAYOUT

    return LAYOUT


# ------------------------------------------------------------------ helpers
def _out_error(flag: str, path, folder: bool = True) -> str | None:
    """Why ``path`` cannot be written (a file where a folder is needed, on the path or at its
    end; a folder where nothing can be created), or ``None``: the one-line message of an
    ``--out`` flag. Nothing is left behind: the check creates a file in the nearest existing
    folder and removes it."""
    p = Path(path)
    if folder and p.exists() and not p.is_dir():
        return f"{flag} {p} is a file, not a folder"
    if not folder and p.is_dir():
        return f"{flag} {p} is a folder, not a file"
    near = p if folder and p.is_dir() else None
    for parent in p.parents:
        if near is not None:
            break
        if parent.exists():
            if not parent.is_dir():
                return f"{flag} {p}: {parent} is a file, not a folder"
            near = parent
    if near is None:
        near = Path.cwd()
    return _writable_error(flag, p, near, None if folder else p)


def _writable_error(flag: str, p: Path, folder: Path, file: Path | None) -> str | None:
    """Why nothing can be written in ``folder`` (the nearest existing folder of ``p``), or in
    the existing ``file``: a probe file created and removed (the permission bits alone do not
    tell, e.g. for root on a read-only or virtual file system); ``None`` when writable."""
    import os
    import tempfile

    try:
        if file is not None and file.is_file():
            with open(file, "ab"):
                pass
            return None
        fd, probe = tempfile.mkstemp(prefix=".tdacm-probe-", dir=folder)
    except OSError as exc:
        where = file if file is not None and file.is_file() else folder
        return f"{flag} {p} cannot be written: {where} refuses it ({exc.strerror})"
    os.close(fd)
    os.unlink(probe)
    return None


def numba_cache_is_cold() -> bool:
    """:func:`tdacm.loop.precompile.numba_cache_is_cold` (imported on use: the CLI starts
    without the loop's modules)."""
    from .loop.precompile import numba_cache_is_cold as cold

    return cold()


def _compile_notice(parallel: bool = False, scenario=None) -> None:
    """With ``parallel``, when the kernels will compile: part of them compile in a second
    process meanwhile (:mod:`tdacm.loop.precompile`; with the run's ``scenario``, its
    plant's and controller's steps too), which the compile notice says. The notice itself
    comes with the first compile (:mod:`tdacm._compiling`)."""
    if parallel and numba_cache_is_cold():
        from ._compiling import add_note
        from .loop.precompile import start

        if start(scenario):
            add_note("in two processes")


def _progress(desc: str, unit: str = "frame"):
    """A ``progress(done, total)`` callback drawing one tqdm line on stderr (not with ``-q``)."""
    from ._log import Progress

    state = {}

    def cb(done, total):
        bar = state.get("bar")
        if bar is None:
            bar = state["bar"] = Progress(total, desc, unit)
        bar.to(done)
        if done >= total:
            bar.close(complete=True)

    return cb


# ------------------------------------------------------------------ commands
def _opening(
    out=None,
    flag: str = "--out",
    folder: bool = True,
    suffixes: tuple = (),
    file=None,
    topic_map=None,
    compile_notice: bool = False,
):
    """The checks a command opens with, in this order: the output ``out`` of ``flag`` (its
    suffix among ``suffixes`` if given, then :func:`_out_error`; ``folder``: a folder, else a
    file), the input ``file`` exists, the ``--topic-map`` file reads; then the compile notice.
    Returns ``(topic map or None, None)``, or ``(None, the one-line error)``."""
    if out is not None:
        if suffixes and Path(out).suffix.lower() not in suffixes:
            kind = " or ".join(suffixes)
            what = f"name a {kind} file" if len(suffixes) == 1 else f"end in {kind}"
            return None, f"{flag} must {what}, got {out}"
        if (problem := _out_error(flag, out, folder)) is not None:
            return None, problem
    if file is not None and not Path(file).is_file():
        return None, f"FILE {file} does not exist or is not a file"
    tmap, problem = _read_topic_map(topic_map)
    if problem is not None:
        return None, problem
    if compile_notice:
        _compile_notice()
    return tmap, None


def _cmd_info(args) -> int:
    """print the paper system's model summary and the model options"""
    from . import paper_system
    from .estimation import SensorSuiteConfig, hover_estimate_limits
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
        "  several arms in a scenario: [[robot.arms]] (attachment.position, rod, tendons, camera,\n"
        "    tip, marker per arm); the closed loop servoes each arm's C_L to its own marker with\n"
        "    one stacked joint-rate mapping (docs/control.md, 'Two arms'; scenario dual-in-fov);\n"
        "    with [touch] both probes squeeze one object, each arm's force estimated from its\n"
        "    tendons (docs/contact.md, 'The squeeze'; scenario dual-squeeze)\n"
        "  integrators: simulate(method='auto'|'rk4'|'rosenbrock'|'radau'|'adaptive'); 'auto' = RK4\n"
        "    unless a torsion/elongation/shear basis needs RK4 steps < 1 ms, then 'radau'"
    )
    sensors = SensorSuiteConfig()
    lim = hover_estimate_limits(sensors)
    pose, imu = sensors.pose, sensors.imu
    print(
        "\nDefault sensors (docs/estimation.md): drone pose "
        f"{pose.rate_hz:g} Hz, {pose.position_noise * 1e3:g} mm, "
        f"{pose.attitude_noise * 1e3:g} mrad; "
        f"IMU {imu.rate_hz:g} Hz, gyro {imu.gyro_noise * 1e3:g} mrad/s, "
        f"accelerometer {imu.accel_noise:g} m/s^2 (per sample)\n"
        "  what they allow in hover, per horizontal axis (hover_estimate_limits): position "
        f"{lim.position * 1e3:.2f} mm, velocity {lim.velocity * 1e3:.2f} mm/s, "
        f"tilt {lim.attitude * 1e3:.2f} mrad"
    )
    return 0


def _cmd_demo(args) -> int:
    """simulate the paper TD-ACM hovering with a tendon step"""
    from .demo import run_demo

    # one process for the compilation: the demo's kernels would not split evenly (measured)
    if (problem := _opening(args.out, compile_notice=True)[1]) is not None:
        return _err(problem)
    summary = run_demo(args.out, duration=args.duration)
    out = Path(args.out).resolve()
    print(json.dumps(summary, indent=2))
    _note(f"Demo output written to {out}/ (hover_tendon_step.png, .npz, .csv, summary.json)")
    return 0


def _cmd_bench(args) -> int:
    """time the model (terms, forward dynamics, passive simulation, stiff integrators)

    With --compile JOB: where the compile time of a job's first use goes (each kernel numba
    compiles on an empty cache, in a fresh process, with its seconds; the total and the
    count); JOB is run (tdacm run paper-in-fov --duration 1), engine, vector-env, identify or
    all. Writes compile.json into --out; --write-estimates also stores the jobs' kernels and
    seconds as the estimates of the compile notice (tdacm/data/compile_times.json).
    """
    if args.compile is not None:
        return _bench_compile(args)
    from .bench import run_full_bench, run_model_bench

    if (problem := _opening(args.out, compile_notice=True)[1]) is not None:
        return _err(problem)
    if args.full:
        run_full_bench(out=args.out, repeats=args.repeats)
    else:
        run_model_bench(out=args.out, repeats=args.repeats)
    return 0


def _bench_compile(args) -> int:
    """``tdacm bench --compile JOB``: :func:`tdacm.bench.compile.profile` of each job, its
    table on stdout, the records in ``OUT/compile.json``."""
    from .bench.compile import JOBS, profile, summary, table, write_estimates

    if (problem := _out_error("--out", args.out)) is not None:
        return _err(problem)
    jobs = list(JOBS) if args.compile == "all" else [args.compile]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for job in jobs:
        _note(f"tdacm: compiling `{JOBS[job][0]}` on an empty cache in a fresh process ...")
        results[job] = res = profile(job)
        print(table(res) + "\n", flush=True)
        (out / "compile.json").write_text(json.dumps(results, indent=1))
    if len(jobs) > 1:
        for job in jobs:
            s = summary(results[job])
            print(f"{job}: {s['kernels']} kernels, {s['compile_cpu_s']:.1f} s of compile CPU")
    _note(f"Compile records written to {(out / 'compile.json').resolve()}")
    if args.write_estimates:
        _note(f"Compile estimates written to {write_estimates(results)}")
    return 0


def _cmd_run(args) -> int:
    """run a closed-loop scenario (see `tdacm scenarios`)

    Run a scenario; prints the summary JSON on stdout and writes the run folder (summary.json,
    scenario.toml, timeseries.npz/.csv/.json, figures as PNG and PDF, scene.png, video.mp4 with
    --video). Rerunning into a folder first removes the previous run's files. --live publishes
    the run as it goes to a Foxglove client (docs/live.md); --realtime paces it to the wall
    clock.
    """
    from .sim import ScenarioError
    from .sim.scenario import check_run, load_scenario

    out = Path(args.out) if args.out else Path("out") / Path(args.scenario).stem
    if (problem := _out_error("--out", out)) is not None:
        return _err(problem)
    if args.rerun is not None and Path(args.rerun).suffix != ".rrd":
        return _err(f"--rerun must name a .rrd file, got {args.rerun}")
    if args.rerun is not None and (problem := _out_error("--rerun", args.rerun, False)):
        return _err(problem)
    if args.rerun is not None:
        from ._extras import require

        require("rerun", "rerun")  # before the run, not after it
    try:
        sc = load_scenario(args.scenario, args.config)
        check_run(sc, args.duration, args.seed, flags=True)
    except ScenarioError as exc:
        return _err(str(exc))
    server, problem = _start_live(args.live)  # a port in use: said before anything runs
    if problem is not None:
        return _err(problem)
    # before the checks that build the robot: building it is the first compilation
    _compile_notice(parallel=True, scenario=sc)
    from .loop.precompile import stop

    try:
        return _run_checked(args, sc, out, server)
    finally:
        stop()  # a second compiling process left running: the run failed before warm_up
        if server is not None:
            server.close()


def _run_checked(args, sc, out: Path, server=None) -> int:
    """The rest of ``tdacm run`` once the scenario passed its schema checks: the run's data
    (:class:`tdacm.sim.Simulation`; published to the live ``server`` as it goes, paced with
    ``--realtime``), then its figures and video (:mod:`tdacm.viz`)."""
    from .sim import ScenarioError, Simulation
    from .sim.outputs import clear_run_outputs
    from .viz import plot_run_dir, write_video
    from .viz.video import CaptionedFrames

    sim = Simulation(
        sc,
        duration=args.duration,
        seed=args.seed,
        video=args.video,
        progress=True,
        frame_composer=CaptionedFrames() if args.video else None,
    )
    try:
        sim.build()  # the checks against the built robot, before anything is removed
    except ScenarioError as exc:
        return _err(str(exc))
    removed = clear_run_outputs(out, keep=())
    if removed:
        _note(f"tdacm: removed {len(removed)} files of a previous run in {out}/")
    on_step = live = None
    if server is not None or args.realtime:
        from .live import LiveRun, RealTime, RobotMessages, chain

        pace = RealTime(sc.config.dt) if args.realtime else None
        if server is not None:  # publishing in the time the pace leaves, then the pace
            server.attach(RobotMessages.of_world(sim.assembly.world))
            live = LiveRun(server, sim.loop, sim.duration, sc.name, pace=pace)
        on_step = chain(live, pace)
    try:
        _, summary = sim.run(out, on_step=on_step)
    except ScenarioError as exc:
        return _err(str(exc))
    except KeyboardInterrupt:
        stored = (out / "timeseries.npz").is_file()
        if stored:
            _write_pictures(out, sim, plot_run_dir, write_video)
        _note(
            "interrupted (Ctrl-C): "
            + (
                f"the steps simulated so far are in {out.resolve()}/"
                if stored
                else "nothing written"
            )
        )
        return 130
    if live is not None:
        live.finish(sim.result)
    try:
        _write_pictures(out, sim, plot_run_dir, write_video)
    except KeyboardInterrupt:  # the run's data is written: the summary says it was cut short
        summary["interrupted"] = True
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        _note(f"interrupted (Ctrl-C) while writing the figures: the run's data is in "
              f"{out.resolve()}/ (`tdacm plot {out}` draws them)")  # fmt: skip
        return 130
    print(json.dumps(summary, indent=2))
    _note(f"Run written to {out.resolve()}/")
    if summary["terminated"]:
        # the run's result: one line naming the termination and its reason, also with -q
        # (a user's controller that broke: its error, then its own line of code)
        failure = summary.get("controller_failure")
        reason = failure["error"] if failure is not None else summary.get("termination_reason")
        print(f"{summary.get('termination') or 'ended early'}: {reason}", file=sys.stderr)
        if failure is not None and failure["code"]:
            print(f"    {failure['code']}", file=sys.stderr)
    if args.rerun is not None:
        from .viz import record_run

        path = record_run(out, args.rerun, progress=_progress("rerun", "step"))
        _note(f"Rerun recording written to {Path(path).resolve()} (open with `rerun {path}`)")
    return 1 if summary["terminated"] else 0


def _write_pictures(out: Path, sim, plot_run_dir, write_video) -> None:
    """The figures of a written run folder and, when frames were kept, its video."""
    plot_run_dir(out)
    frames = sim.result.frames if sim.result is not None else []
    if frames:
        write_video(out / "video.mp4", frames, 1.0 / sim.scenario.config.dt)


def _cmd_plot(args) -> int:
    """regenerate the figures of a `tdacm run` folder"""
    from .sim.outputs import RunDirError
    from .viz.figures import KINDS, plot_run_dir

    kinds = tuple(k.strip() for k in args.kinds.split(",")) if args.kinds else KINDS
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        return _err(f"--kinds: unknown figure {unknown[0]!r} (known: {', '.join(KINDS)})")
    formats = tuple(f.strip() for f in args.formats.split(","))
    if any(f not in ("png", "pdf", "svg") for f in formats):
        return _err(f"--formats must list png, pdf or svg, got {args.formats!r}")
    out, flag = (args.out, "--out") if args.out else (args.run_dir, "RUN_DIR")
    if Path(args.run_dir).is_dir() or args.out:
        if (problem := _opening(out, flag)[1]) is not None:
            return _err(problem + ("" if args.out else " (give --out)"))
    try:
        paths = plot_run_dir(args.run_dir, args.out, formats=formats, kinds=kinds)
    except RunDirError as exc:
        return _err(str(exc))
    if args.kinds:  # asked for by name: a figure the run has no data for is said so
        drawn = {Path(f).stem for f in paths}
        missing = [k for k in kinds if k not in drawn]
        if missing and not paths:
            return _err(f"--kinds {','.join(missing)}: the run in {args.run_dir} has no data for "
                        f"{'it' if len(missing) == 1 else 'them'} ({_KIND_NEEDS})")  # fmt: skip
        if missing:
            _note(f"not drawn (no data in this run): {', '.join(missing)}")
    _note(f"{len(paths)} figure file{'s' if len(paths) != 1 else ''} written to {Path(paths[0]).parent.resolve()}/"
          if paths else "no figures written (empty run)")  # fmt: skip
    return 0


#: what the figures drawn only for some runs need (``tdacm plot --kinds``)
_KIND_NEEDS = ("arms: several arms, [[robot.arms]]; contact: a [touch] run; estimation: "
               "estimation.source = 'estimated'; snapshots: the run's scenario.toml")  # fmt: skip


def _cmd_scenarios(args) -> int:
    """list the shipped scenarios"""
    from .sim import list_scenarios, load_scenario

    for name in list_scenarios():
        sc = load_scenario(name)
        print(f"{name:18s} {sc.config.duration:5.1f} s  {sc.config.description}")
    return 0


def _cmd_schema(args) -> int:
    """print the JSON Schema of a scenario file (for editor completion)

    Print the JSON Schema of a scenario file (of a campaign spec with --campaign); with
    --markdown, write the scenario reference (docs/scenario-reference.md) generated from the
    same records.
    """
    import json

    from .sim.config import json_schema, reference_markdown

    if args.campaign:
        from .campaign.spec import json_schema as campaign_schema

        print(json.dumps(campaign_schema(), indent=2))
        return 0
    if args.markdown is None:
        print(json.dumps(json_schema(), indent=2))
        return 0
    if args.markdown != "-":
        md = _opening(args.markdown, "--markdown", False)[1]
        if md is not None:
            return _err(md)
    text = reference_markdown()
    if args.markdown == "-":
        sys.stdout.write(text)
    else:
        Path(args.markdown).write_text(text, encoding="utf-8")
        _note(f"Scenario reference written to {args.markdown}")
    return 0


def _cmd_campaign(args) -> int:
    """run a robustness campaign on Dask (resumable)"""
    from .campaign import CampaignSpecError, run_campaign

    out = Path(args.out)
    if (problem := _opening(out, compile_notice=True)[1]) is not None:
        return _err(problem)
    try:
        report = run_campaign(args.spec, args.out, workers=args.workers, scheduler=args.scheduler)
    except CampaignSpecError as exc:
        return _err(str(exc))
    except KeyboardInterrupt:
        from .campaign import completed_runs

        n = len(completed_runs(out / "results")) if (out / "results").is_dir() else 0
        _note(f"interrupted (Ctrl-C): {n} runs stored in {out.resolve()}/results; "
              "rerun the same command to resume")  # fmt: skip
        return 130
    print((out / "report.md").read_text())
    _note(f"Campaign written to {out.resolve()}/ (results/, report.md, report.png)")
    if report["runs_stored"] and report["errors"] == report["runs_stored"]:
        _note(f"error: every run ({report['errors']}) raised an error; see the 'error' column "
              f"of {out}/results (tdacm.campaign.read_results)")  # fmt: skip
        return 1
    return 0 if report["complete"] else 1


def _cmd_replay(args) -> int:
    """3-D animation (GIF or MP4) or Rerun recording of a `tdacm run` folder

    Animate a run folder in 3-D (real time by default), or with --rerun convert it to a Rerun
    recording (.rrd), or with --live stream it to a Foxglove client (docs/live.md).
    """
    from .sim.outputs import RunDirError

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        return _err(f"RUN_DIR {run_dir} does not exist or is not a folder")
    if args.live is not None:
        return _replay_live(args, run_dir)
    if args.rerun is not None:
        from .viz import record_run

        rrd = None if args.rerun == "" else args.rerun
        flag = "--rerun" if rrd is not None else "RUN_DIR"
        target = rrd if rrd is not None else run_dir / "run.rrd"
        if (problem := _opening(target, flag, False, (".rrd",))[1]) is not None:
            return _err(problem + ("" if rrd is not None else " (give --rerun FILE.rrd)"))
        try:
            path = record_run(run_dir, rrd, progress=_progress("rerun", "step"))
        except RunDirError as exc:
            return _err(str(exc))
        _note(f"Rerun recording written to {Path(path).resolve()} (open with `rerun {path}`)")
        return 0
    from .viz import replay_run

    target = args.out if args.out is not None else run_dir / "replay.gif"
    problem = _opening(target, "--out" if args.out else "RUN_DIR", False, (".gif", ".mp4"))[1]
    if problem is not None:
        return _err(problem + ("" if args.out else " (give --out FILE.gif)"))
    try:
        path = replay_run(
            run_dir,
            args.out,
            fps=args.fps,
            max_frames=args.max_frames,
            speed=args.speed,
            view=args.view,
            progress=_progress("replay"),
        )
    except RunDirError as exc:
        return _err(str(exc))
    _note(f"3-D replay written to {path.resolve()}")
    return 0


def _replay_live(args, run_dir: Path) -> int:
    """``tdacm replay RUN --live [HOST:]PORT``: stream the run folder to a Foxglove client at
    ``--speed`` times real time, once a client subscribes."""
    from .recording import ExportError
    from .recording.stream import stream_run

    if args.rerun is not None or args.out is not None:
        flag = "--rerun" if args.rerun is not None else "--out"
        return _err(f"{flag}: --live streams the run, it writes no file; give one or the other")
    if not (run_dir / "timeseries.npz").is_file():
        return _err(f"RUN_DIR {run_dir} has no timeseries.npz")
    server, problem = _start_live(args.live)
    if problem is not None:
        return _err(problem)
    try:
        n = stream_run(run_dir, server, speed=args.speed,
                       on_wait=lambda: _note("tdacm: waiting for a client (Ctrl-C to stop)"))  # fmt: skip
    except ExportError as exc:
        return _err(str(exc))
    finally:
        server.close()
    _note(f"tdacm: {n} steps of {run_dir} streamed")
    return 0


def _cmd_export(args) -> int:
    """export a `tdacm run` folder as MCAP with ROS 2 message types

    Write a run folder as an MCAP recording (tf, joint states, poses, camera info, servo
    features; see docs/recordings.md), readable by Foxglove and `ros2 bag play` without a ROS
    installation.
    """
    from .recording import ExportError, export_run

    if (problem := _opening(args.mcap, "--mcap", False, (".mcap",))[1]) is not None:
        return _err(problem)
    run_dir = Path(args.run_dir)
    if not (run_dir / "timeseries.npz").is_file():
        what = "has no timeseries.npz" if run_dir.is_dir() else "does not exist or is not a folder"
        return _err(f"RUN_DIR {run_dir} {what}")
    _compile_notice()
    try:
        path = export_run(
            run_dir, args.mcap, n_sections=args.sections, render_every=args.images or None
        )
    except ExportError as exc:
        return _err(str(exc))
    _note(f"MCAP recording written to {Path(path).resolve()} (open in Foxglove, or "
          f"`ros2 bag play {path}`)")  # fmt: skip
    return 0


def _topic_map_error(exc) -> str:
    """The message of a :class:`~tdacm.recording.RecordingError` naming the flag: the topic
    map's messages start with "topic map"."""
    msg = str(exc)
    return "--topic-map" + msg[len("topic map") :] if msg.startswith("topic map") else msg


def _read_topic_map(path):
    """``(topic map or None, None)`` from ``--topic-map`` (unset: no map), or ``(None, the
    one-line error)``."""
    if path is None:
        return None, None
    from .recording import RecordingError, load_topic_map

    try:
        return load_topic_map(path), None
    except RecordingError as exc:
        return None, _topic_map_error(exc)


def _cmd_import(args) -> int:
    """import an MCAP recording into time-stamped signals (.npz)

    Read an MCAP recording (ROS 2 messages) through a topic map (TOML [topics]: a lab's topic ->
    tdacm signal) and write one NAME.npz per signal.
    """
    from .recording import RecordingError, read_mcap, save_signals

    out = Path(args.out)
    tmap, problem = _opening(out, file=args.file, topic_map=args.topic_map)
    if problem is not None:
        return _err(problem)
    try:
        signals = read_mcap(args.file, tmap, t0="first" if args.relative else None)
    except RecordingError as exc:
        return _err(_topic_map_error(exc))
    paths = save_signals(signals, out)
    for name, sig in signals.items():
        print(f"{name:20s} {len(sig):7d} samples  {sig.topic}  {sig.msg_type}")
    _note(f"{len(paths)} signals written to {out.resolve()}/ (NAME.npz: t, values, names)")
    return 0


def _cmd_replay_recording(args) -> int:
    """re-run an MCAP recording through perception, the estimator and the servo features

    Replay a recording (through a topic map) period by period through the scenario's perception
    block, its EKF (when the recording has pose, IMU or encoder signals) and the servo's feature
    computation; writes DIR/replay.npz (t, q_hat, qd_hat, features, feature_error, points, rmse,
    detected). See docs/recordings.md.
    """
    import numpy as np

    from .recording import RecordingError, read_mcap, replay
    from .sim import ScenarioError, load_scenario

    out = Path(args.out)
    if (problem := _opening(out, file=args.file)[1]) is not None:
        return _err(problem)
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        return _err(f"--scenario: {exc}")
    tmap, problem = _opening(topic_map=args.topic_map, compile_notice=True)
    if problem is not None:
        return _err(problem)
    try:
        signals = read_mcap(args.file, tmap, t0="first" if args.relative else None)
        estimate = {"auto": None, "estimated": True, "recorded": False}[args.state]
        result = replay(signals, scenario, estimate=estimate)
    except RecordingError as exc:
        return _err(_topic_map_error(exc))
    except ScenarioError as exc:
        return _err(f"--scenario: {exc}")
    path = result.save(out)
    rmse = result.rmse[np.isfinite(result.rmse)]
    last = f"{rmse[-1]:.4g}" if len(rmse) else "nan"
    print(
        f"{len(result.t)} periods, {int(result.detected.sum())} with a C_L detection, "
        f"{'EKF estimate' if result.estimated else 'recorded state'}, final rmse {last}"
    )
    _note(f"replay written to {path.resolve()}")
    return 0


def _parse_start(text: str) -> dict:
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"write NAME=VALUE, got {item!r}")
        try:
            v = float(val)
        except ValueError:
            raise ValueError(f"{key.strip()} must be a number, got {val!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"{key.strip()} must be finite, got {val!r}")
        out[key.strip()] = v
    return out


def _cmd_identify(args) -> int:
    """estimate physical parameters from recordings (motion capture, tensions)

    Fit the model's simulated motion to recorded trajectories (multiple shooting, least squares;
    see docs/identify.md) and write identification.json, robot.toml (a [robot] block for a
    scenario) and identification.png.
    """
    from .identify import PARAMETERS, RecordingInputError, load_recording, parse_params
    from .identify.fit import identify_staged
    from .identify.misfit import EXIT_MISFIT, diagnose, held_out_ratio
    from .identify.misfit import summary as misfit_summary
    from .identify.report import correlation_text, robot_toml, write_outputs
    from .identify.select import select_basis, selection_table

    try:
        names = parse_params(args.params)
    except ValueError as exc:
        return _err(f"--params: {exc}")
    try:
        start = _parse_start(args.start) if args.start else {}
    except ValueError as exc:
        return _err(f"--start: {exc}")
    for k, v in start.items():
        if k not in names:
            return _err(f"--start: {k!r} is not among --params ({', '.join(names)})")
        par = PARAMETERS[k]
        if (par.log and v <= 0) or (par.nonnegative and v < 0):
            need = "positive" if par.log else "non-negative"
            return _err(f"--start: {k} must be {need} ({par.doc}, {par.unit}), got {v:g}")
    bases = None
    if args.bases is not None:
        from .sim.robot import parse_basis

        bases = [b.strip() for b in args.bases.split(",") if b.strip()]
        if not bases:
            return _err("--bases: give at least one basis, e.g. bending:0,bending:1,bending:2")
        for b in bases:
            try:
                parse_basis(b)
            except ValueError as exc:
                return _err(f"--bases: {exc}")
    out = Path(args.out)
    if (problem := _opening(out)[1]) is not None:
        return _err(problem)
    if args.topic_map is not None and not Path(args.topic_map).is_file():
        return _err(f"--topic-map {args.topic_map} does not exist or is not a file")
    tmap, problem = _opening(topic_map=args.topic_map, compile_notice=True)
    if problem is not None:
        return _err(problem)
    recs = []
    for path in args.recording:
        try:
            recs.append(load_recording(path, args.scenario, tmap))
        except RecordingInputError as exc:
            return _err(str(exc))
        except ValueError as exc:  # a scenario or topic-map error
            return _err(f"RECORDING {path}: {exc}")
    flying = any(r.model.floating for r in recs)
    for n in names:
        if PARAMETERS[n].floating_only and not flying:
            return _err(f"--params: {n} needs a recording with a flying base")
        if PARAMETERS[n].camera_only and args.use != "camera":
            return _err(f"--params: {n} is seen by the tip camera only (add --use camera)")
    if args.use == "camera" and any(r.pixels is None for r in recs):
        return _err("--use camera: a recording has no camera pixels")
    held = []
    for path in args.held_out or []:
        try:
            h = load_recording(path, args.scenario, tmap)
        except RecordingInputError as exc:
            return _err(f"--held-out: {exc}")
        except ValueError as exc:
            return _err(f"--held-out {path}: {exc}")
        if h.model.floating:
            return _err(f"--held-out {path}: a held-out recording must be of the clamped rod")
        held.append(h)
    kw = {"segment": args.segment, "use": args.use}
    try:
        if bases is not None:
            res = select_basis(recs, names, bases, held, start, decimate=args.decimate, **kw)
        else:
            res = identify_staged(recs, names, start, decimate=args.decimate, **kw)
            ho = {
                h.name: held_out_ratio(res.values, h.decimated(args.decimate), args.segment)
                for h in held
            }
            res.misfit = diagnose(res, ho, fitted=res.names)
    except ValueError as exc:
        return _err(str(exc))
    if res.selection:
        print(selection_table(res.selection))
        print()
    print(res.table())
    print()
    print(correlation_text(res))
    print()
    print(robot_toml(res), end="")
    paths = write_outputs(res, out)
    _note(f"identification ({res.seconds:.1f} s, residual variance {res.residual_variance:.2f}) "
          f"written to {out.resolve()}/ ({', '.join(p.name for p in paths)})")  # fmt: skip
    inadequate = [r["basis"] for r in res.selection if r["misfit"]]
    if inadequate:
        print(f"warning: inadequate bases (misfit beyond the noise): {', '.join(inadequate)}; "
              f"chosen: {res.rod_basis}", file=sys.stderr)  # fmt: skip
    if res.misfit.get("detected"):
        print(misfit_summary(res.misfit), file=sys.stderr)
        if args.strict:
            return EXIT_MISFIT
    return 0


def _levels(p: argparse.ArgumentParser, default) -> None:
    """``-v``/``--verbose`` and ``-q``/``--quiet`` on ``p``: the top-level parser's (defaults
    0 and False) and each command's (``argparse.SUPPRESS``: unset unless given, so that
    ``tdacm -q run ...`` and ``tdacm run ... -q`` are the same)."""
    level = p.add_mutually_exclusive_group()
    level.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0 if default is None else default,
        help="also log debug messages (stderr)",
    )
    level.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=False if default is None else default,
        help="log warnings and errors only; no progress bars",
    )


def _command(sub, name: str, func):
    """The parser of command ``name``, run by ``func``: its help (in ``tdacm --help``) is the
    first paragraph of ``func``'s docstring, its description (``tdacm NAME --help``) the
    rest, if any. ``-q``/``-v`` are accepted after the command too."""
    first, _, rest = inspect.cleandoc(func.__doc__ or "").partition("\n\n")
    s = sub.add_parser(
        name, help=" ".join(first.split()), description=" ".join(rest.split()) or None
    )
    _levels(s, argparse.SUPPRESS)
    s.set_defaults(func=func)
    return s


def _add_topic_map(s) -> None:
    """``--topic-map`` of the commands that read an MCAP recording."""
    s.add_argument(
        "--topic-map", metavar="MAP.toml", help="topic map (default: the topics of tdacm export)"
    )


def _add_live(s, what: str) -> None:
    """``--live [HOST:]PORT`` of ``run`` and ``replay`` (docs/live.md)."""
    from .live.server import DEFAULT_HOST, DEFAULT_PORT

    s.add_argument(
        "--live",
        type=_address,
        metavar="[HOST:]PORT",
        help=f"{what}: a Foxglove WebSocket server on PORT (e.g. {DEFAULT_PORT}; 0: any free "
        f"port), on {DEFAULT_HOST} unless HOST is given",
    )


def _add_relative(s) -> None:
    """``--relative`` of the commands that read an MCAP recording."""
    s.add_argument(
        "--relative", action="store_true", help="times from the recording's first message"
    )


def _compile_jobs() -> list[str]:
    """The jobs of ``tdacm bench --compile`` (:data:`tdacm._compiling.JOBS`)."""
    from ._compiling import JOBS

    return list(JOBS)


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .recording.export import DEFAULT_SECTIONS

    p = argparse.ArgumentParser(
        prog="tdacm",
        description="Tendon-driven aerial continuum manipulators: strain-parameterized coupled "
        "dynamics, dual-camera visual servoing, adaptive control.",
    )
    p.add_argument("--version", action="version", version=f"tdacm {__version__}")
    _levels(p, None)
    sub = p.add_subparsers(dest="command", required=True)
    _command(sub, "info", _cmd_info)
    s = _command(sub, "demo", _cmd_demo)
    s.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    s.add_argument("--duration", type=_positive_float, default=4.0, help="simulated seconds")
    s = _command(sub, "bench", _cmd_bench)
    s.add_argument(
        "--out", default="out/bench", help="output folder for bench.json (default: out/bench)"
    )
    s.add_argument("--repeats", type=_positive_int, default=7, help="timing repeats (median)")
    s.add_argument(
        "--full",
        action="store_true",
        help="add the CC Lagrangian baseline comparison, DoF scaling and accuracy study (minutes)",
    )
    s.add_argument(
        "--compile",
        nargs="?",
        const="run",
        choices=[*_compile_jobs(), "all"],
        metavar="JOB",
        help="instead: each kernel a job compiles on an empty cache, with its seconds "
        f"(JOB: {', '.join(_compile_jobs())} or all; default run)",
    )
    s.add_argument(
        "--write-estimates",
        action="store_true",
        help="with --compile: store the jobs' compile times as the compile notice's estimates",
    )
    s = _command(sub, "run", _cmd_run)
    s.add_argument("scenario", help="scenario name or path to a scenario TOML file")
    s.add_argument("--config", help="TOML file overriding scenario values (same layout)")
    s.add_argument("--out", help="output folder (default: out/SCENARIO)")
    s.add_argument(
        "--duration", type=_positive_float, help="simulated seconds (default: the scenario's)"
    )
    s.add_argument("--seed", type=_nonneg_int, help="seed of the model perturbation and noise")
    s.add_argument("--video", action="store_true", help="write video.mp4 (C_L | C_G, captioned)")
    s.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording at the end")
    _add_live(s, "publish the run as it goes to Foxglove")
    s.add_argument(
        "--realtime",
        action="store_true",
        help="pace the simulation to the wall clock (at most real time)",
    )
    s = _command(sub, "plot", _cmd_plot)
    s.add_argument("run_dir", help="a folder written by `tdacm run`")
    s.add_argument("--out", help="folder for the figures (default: RUN_DIR)")
    s.add_argument("--formats", default="png,pdf", help="comma-separated (default png,pdf)")
    s.add_argument("--kinds", help="comma-separated figure kinds (default: all)")
    _command(sub, "scenarios", _cmd_scenarios)
    s = _command(sub, "schema", _cmd_schema)
    s.add_argument(
        "--markdown",
        nargs="?",
        const="-",
        metavar="FILE.md",
        help="write the scenario reference in Markdown instead (default: stdout)",
    )
    s.add_argument(
        "--campaign", action="store_true", help="the JSON Schema of a campaign spec instead"
    )
    s = _command(sub, "campaign", _cmd_campaign)
    s.add_argument("spec", help="campaign spec TOML (see docs/campaigns.md)")
    s.add_argument(
        "--workers", type=_positive_int, help="local Dask worker processes (default: CPU count)"
    )
    s.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:port)")
    s.add_argument("--out", default="out/campaign", help="output folder; rerun to resume")
    s = _command(sub, "replay", _cmd_replay)
    s.add_argument("run_dir", help="a folder written by `tdacm run`")
    s.add_argument("--out", help="output .gif or .mp4 (default: RUN_DIR/replay.gif)")
    s.add_argument("--fps", type=_positive_int, help="frame rate (default: chosen for --speed)")
    s.add_argument("--max-frames", type=_positive_int, default=200, help="frame cap (200)")
    s.add_argument(
        "--speed", type=_positive_float, default=1.0, help="playback speed (1 = real time)"
    )
    s.add_argument("--view", choices=("follow", "scene"), default="follow", help="camera view")
    s.add_argument(
        "--rerun",
        nargs="?",
        const="",
        metavar="FILE.rrd",
        help="write a Rerun recording instead (default RUN_DIR/run.rrd)",
    )
    _add_live(s, "stream the run to Foxglove instead (at --speed, once a client connects)")
    s = _command(sub, "export", _cmd_export)
    s.add_argument("run_dir", help="a folder written by `tdacm run`")
    s.add_argument("--mcap", required=True, metavar="FILE", help="output .mcap file")
    s.add_argument(
        "--sections",
        type=_positive_int,
        default=DEFAULT_SECTIONS,
        help=f"rod frames on /tf at s = k L / N (default {DEFAULT_SECTIONS})",
    )
    s.add_argument(
        "--images",
        type=_nonneg_int,
        default=0,
        metavar="N",
        help="re-render C_L and C_G every N steps as sensor_msgs/Image (default 0: none)",
    )
    s = _command(sub, "import", _cmd_import)
    s.add_argument("file", help="an .mcap recording")
    _add_topic_map(s)
    s.add_argument("--out", required=True, metavar="DIR", help="folder for the signals")
    _add_relative(s)
    s = _command(sub, "replay-recording", _cmd_replay_recording)
    s.add_argument("file", help="an .mcap recording")
    _add_topic_map(s)
    s.add_argument("--scenario", required=True, help="the robot's scenario (name or TOML file)")
    s.add_argument("--out", required=True, metavar="DIR", help="folder for replay.npz")
    s.add_argument(
        "--state",
        choices=("auto", "estimated", "recorded"),
        default="auto",
        help="configuration of the servo: the EKF's estimate or the recorded state (auto: the "
        "EKF when the recording has proprioception)",
    )
    _add_relative(s)
    s = _command(sub, "identify", _cmd_identify)
    s.add_argument("recording", nargs="+", help="run folders (timeseries.npz) or .mcap recordings")
    s.add_argument(
        "--params",
        required=True,
        help="comma-separated: E, damping, tip_mass, radius, friction, viscous, drone_mass, "
        "inertia (or inertia_x, ...), thrust, camera_offset",
    )
    s.add_argument("--out", default="out/identify", help="output folder (default out/identify)")
    s.add_argument(
        "--scenario", help="scenario of the robot (default: scenario.toml beside the recording)"
    )
    s.add_argument("--topic-map", metavar="MAP.toml", help="topic map of an .mcap recording")
    s.add_argument("--start", metavar="NAME=V,...", help="starting values (default: nominal)")
    s.add_argument(
        "--segment", type=_positive_float, help="multiple-shooting window (s; default 2, flying 1)"
    )
    s.add_argument(
        "--use",
        choices=("auto", "mocap", "camera", "all"),
        default="auto",
        help="measurements fitted: poses (mocap), tip-camera pixels (camera), or both",
    )
    s.add_argument(
        "--decimate",
        type=_positive_int,
        default=1,
        metavar="K",
        help="fit every K-th sample with RK4 steps of K sample periods (default 1)",
    )
    s.add_argument(
        "--bases",
        metavar="B,B,...",
        help="strain bases to compare (e.g. bending:0,bending:1,bending:2): each is fitted, "
        "compared by BIC and on --held-out recordings; the chosen one is reported and "
        "written to robot.toml (default: the scenario's basis only)",
    )
    s.add_argument(
        "--held-out",
        action="append",
        metavar="RECORDING",
        help="a clamped-rod recording not fitted, predicted to validate the model and choose "
        "the basis (repeatable; e.g. the held-out experiment)",
    )
    s.add_argument(
        "--strict",
        action="store_true",
        help="exit with code 3 when the fit's residuals are far from the measurement noise "
        "(misfit; see docs/identify.md)",
    )
    return p


#: set by the SIGINT handler of :func:`main`: after a Ctrl-C, what fails is its consequence
_interrupted = False


def _on_sigint(signum, frame):
    """Python's own Ctrl-C handler (raise ``KeyboardInterrupt``), remembering the interrupt."""
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def _unraisable_hook(default):
    """``sys.unraisablehook`` that, once an interrupt was seen, drops what a Ctrl-C during a
    numba compilation leaves behind: the ``KeyboardInterrupt`` raised inside llvmlite's ctypes
    callbacks (``Exception ignored on calling ctypes callback function``, the interrupt itself,
    swallowed there) and the finalizer errors of half-built numba/llvmlite objects
    (``Exception ignored in: ...__del__``); anything else goes to ``default``."""

    def hook(unraisable):
        obj = unraisable.object
        mods = (getattr(obj, "__module__", None) or "", getattr(type(obj), "__module__", ""))
        ours = any(str(m).split(".")[0] in ("numba", "llvmlite") for m in mods)
        exc = unraisable.exc_type
        if _interrupted and (ours or (exc is not None and issubclass(exc, KeyboardInterrupt))):
            return
        default(unraisable)

    return hook


def main(argv=None) -> int:
    """Exit codes: 0 success (``tdacm run``: the run reached its duration), 1 ``tdacm run``
    ended early by an outcome (the safety monitor, a failed recovery, the plant, a tumbled
    drone, a point behind the virtual camera, the estimator, a non-finite command: the
    summary's ``termination``; its data is written) or a missing optional extra, 2 invalid
    input (one ``error:`` line), 130 Ctrl-C."""
    import signal

    parser = build_parser()
    args = parser.parse_args(argv)
    if args.verbose and args.quiet:  # one before the command, the other after it
        parser.error("argument -q/--quiet: not allowed with argument -v/--verbose")
    configure_logging(args.verbose, args.quiet)
    from ._extras import MissingExtraError

    global _interrupted
    _interrupted = False
    previous = None
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        try:
            previous = signal.signal(signal.SIGINT, _on_sigint)
        except ValueError:  # not the main thread: Python's handler stays
            previous = None
    default_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable_hook(default_hook)
    try:
        return args.func(args)
    except MissingExtraError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        _note("interrupted (Ctrl-C)")
        return 130
    except BrokenPipeError:  # stdout closed early (``tdacm info | head``): not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        # the system refused a file after the checks passed (a disk full, a file removed or
        # made read-only meanwhile): one line naming the file
        if exc.filename is None or _interrupted:
            raise
        print(f"error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # e.g. numba's RuntimeError after a Ctrl-C during a compilation
        from .loop.closed_loop import caused_by_interrupt

        if _interrupted or caused_by_interrupt(exc):
            _note("interrupted (Ctrl-C)")
            return 130
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        if not _interrupted:  # after a Ctrl-C the half-built objects die at exit: stay quiet
            sys.unraisablehook = default_hook


if __name__ == "__main__":
    sys.exit(main())
