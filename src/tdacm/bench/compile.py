"""Where compile time goes: the numba kernels a job compiles on an empty cache, and the
kernels a wheel ships (``tdacm bench --compile [JOB]``, ``benchmarks/bench_compile.py``).

A *job* (:data:`JOBS`) is what a user's first use runs: ``run`` (``tdacm run paper-in-fov
--duration 1``: the scenario's loop built, warmed up and run, its run folder written),
``engine`` (the batched engine's first ``build_batch(...).run()`` of 4 worlds for 0.1 s, then
a step and a reset), ``vector-env`` (``gym.make_vec("tdacm/TipServo-v0", num_envs=64)``: a
reset, the imitation teacher and 100 random steps) and ``identify`` (a one-iteration fit on
the explicit and on the stiff shooting path).

:func:`profile` runs a job in a fresh process on an empty cache (a temporary
``NUMBA_CACHE_DIR``, the shipped kernels ignored, one process: ``TDACM_PARALLEL_COMPILE=0``)
and records numba's ``numba:compile`` events (``numba.core.event``: one per function and
argument types compiled, nested when a caller compiles its callees): each kernel's inclusive
and exclusive seconds (exclusive: without the callees compiled inside it), its argument types
and its runtime mode (numba's reference counting on or off). :func:`table` ranks them.

:func:`ship` compiles every job for the portable target into a folder (the wheel build,
``buildsys/tdacm_build.py``; :mod:`tdacm._jitcache`), in two processes, merges their caches
and writes the manifest; :func:`verify` runs the jobs again in a fresh process on that
folder and counts the package's kernels that still compile (none, for a complete cache).

The jobs discover nothing by name: whatever the package compiles while a job runs is
recorded, so the tables stay right when kernels move between modules.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


# ------------------------------------------------------------------ the jobs
def _job_run(work: Path) -> None:
    """``tdacm run paper-in-fov --duration 1``: the run's data (its figures compile nothing)."""
    from .._compiling import compiling
    from ..sim import Simulation
    from ..sim.scenario import check_run, load_scenario

    with compiling("run"):
        sc = load_scenario("paper-in-fov")
        check_run(sc, 1.0, None, flags=True)
        sim = Simulation(sc, duration=1.0)
        sim.build()
        sim.run(work / "run")


def _job_engine(work: Path) -> None:
    """The engine's first ``build_batch(...).run()`` (:func:`tdacm.bench.batch.first_call`),
    then a step and a reset."""
    from .batch import _batch

    b = _batch(4, 2, 0.1)
    b.run()
    b.step()
    b.reset()


def _job_vector_env(work: Path) -> None:
    """``gym.make_vec(..., num_envs=64)``: reset, the imitation teacher, 100 random steps."""
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the env)

    from ..envs.teacher import teacher_twists

    env = gym.make_vec("tdacm/TipServo-v0", num_envs=64, vectorization_mode="vector_entry_point")
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        teacher_twists(env)
        for _ in range(100):
            env.step(env.action_space.sample())
    finally:
        env.close()


def _job_identify(work: Path) -> None:
    """One iteration of a fit of E on the explicit (RK4) and the stiff shooting path."""
    from ..identify import identify, synthesize

    for basis in ("bending:0", "bending:2"):
        rec = synthesize("tendon-steps-loaded", seed=3, duration=3.0).decimated(2)
        identify(rec.with_basis(basis), ["E"], segment=1.0, max_nfev=1)


def _job_touch(work: Path) -> None:
    """Servoing into contact on the block loop: ``touch-target`` on the true state and on the
    EKF's estimates (0.5 s each: the touch servo's and the force estimate's steps compile at
    their first call, whatever the phase), and ``dual-squeeze`` started 1 cm above its contact
    pose until both probes press (2.5 s: the arms' Python law calls its compiled helpers only
    in contact)."""
    from ..sim import Simulation
    from ..sim.scenario import load_scenario

    sc = load_scenario("touch-target")
    q0 = list(sc.data["initial"]["q"])
    q0[5] = 2.0  # 0.18 m above the standoff view
    for source in ("true", "estimated"):
        over = {"initial": {"q": q0}, "duration": 0.5, "estimation": {"source": source}}
        Simulation(sc.with_overrides(over), seed=1).run(None)
    sc = load_scenario("dual-squeeze")
    q0 = list(sc.config.desired.q)
    q0[5] += 0.01
    over = {"initial": {"q": q0}, "duration": 2.5, "model": {"perturbation": 0.0},
            "touch": {"standoff": 0.01, "dwell": 0.1}}  # fmt: skip
    Simulation(sc.with_overrides(over), seed=1).run(None)


def _job_stiff(work: Path) -> None:
    """The stiff integrators (Radau IIA, Rosenbrock-W) on a clamped six-strain rod: fixed and
    adaptive steps, held and callable inputs (0.02 s each); the tip pose, the energy and a
    static equilibrium, with which their runs are started and read."""
    import numpy as np

    from .. import StrainBasis, paper_system, simulate

    system = paper_system(fixed_base_pose=np.eye(4), basis=StrainBasis.full(0))
    q0 = np.zeros(system.n)
    q0[1:3] = [0.5, -0.3]
    held = np.zeros(system.n_u)
    for method in ("radau", "rosenbrock"):
        simulate(system, q0, None, 0.02, u=held, method=method, record_dt=0.01)
        simulate(system, q0, None, 0.02, method=method, rtol=1e-4, atol=1e-6, record_dt=0.01)
        res = simulate(system, q0, None, 0.02, method=method, record_dt=0.01,
                       u=lambda t, q, qd: held)  # fmt: skip
    # the tip along a result of the fixed-step and of the adaptive (DOP853) path, whose rows
    # are strided: another specialization
    system.tip_pose(res.q[-1])
    system.tip_pose(simulate(system, q0, None, 0.01, method="adaptive", record_dt=0.01).q[-1])
    system.energy(q0, np.zeros(system.n))
    floating = paper_system()  # a rod's static equilibrium, the start of a release
    u = np.zeros(floating.n_u)
    u[4] = 1.0
    floating.static_equilibrium(u, q0=np.r_[np.zeros(5), 3.0, np.zeros(floating.n - 6)],
                                load_steps=1)  # fmt: skip


#: name -> (what it is, the function running it in this process)
JOBS = {
    "run": ("tdacm run paper-in-fov --duration 1", _job_run),
    "engine": ("the engine's first build_batch(...).run() (4 worlds, 0.1 s)", _job_engine),
    "vector-env": ("gym.make_vec(..., num_envs=64): reset and 100 steps", _job_vector_env),
    "identify": ("identify: one iteration, explicit and stiff shooting", _job_identify),
}
#: what the warm-up and the wheel compile besides the jobs (not a first use the bench times:
#: ``tdacm run touch-target`` is a ``run``): the contact scenarios' and the stiff integrators'
#: kernels, which the test suite would otherwise compile
EXTRAS = {
    "touch": ("touch-target (true, estimated) and dual-squeeze on the block loop", _job_touch),
    "stiff": ("the stiff integrators: Radau IIA and Rosenbrock-W, fixed and adaptive", _job_stiff),
}
#: every job the warm-up and the wheel run
ALL_JOBS = {**JOBS, **EXTRAS}


# ------------------------------------------------------------------ recording compiles
class Recorder:
    """A listener of numba's ``numba:compile`` events: one record per compiled function and
    argument types, with inclusive and exclusive seconds of wall time and of the compiling
    thread's CPU time (the CPU time does not count other processes' load)."""

    def __init__(self):
        self.stack: list[list[float]] = []
        self.records: list[dict] = []

    def on_start(self, ev) -> None:
        self.stack.append([time.perf_counter(), time.thread_time(), 0.0, 0.0, _mode(ev)])

    def on_end(self, ev) -> None:
        t0, c0, inner_wall, inner_cpu, nrt = self.stack.pop()
        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if self.stack:
            self.stack[-1][2] += wall
            self.stack[-1][3] += cpu
        data = ev.data or {}
        disp = data.get("dispatcher")
        args = tuple(data.get("args") or ())
        fn = getattr(disp, "py_func", None)
        opts = getattr(disp, "targetoptions", {})
        self.records.append(
            {
                "module": getattr(fn, "__module__", "?"),
                "qualname": getattr(fn, "__qualname__", "?"),
                "types": str(args),
                "nrt": nrt,
                "declared_nrt": opts.get("_nrt"),
                "inline": opts.get("inline"),
                "depth": len(self.stack),
                "inclusive_s": wall,
                "exclusive_s": wall - inner_wall,
                "inclusive_cpu_s": cpu,
                "exclusive_cpu_s": cpu - inner_cpu,
                "failed": _failed(ev),
            }
        )


def _failed(ev) -> bool:
    """Whether the compile ended by an exception (numba retries some, e.g. to fold literal
    arguments). Read from the end event's exception details: numba 0.68's ``is_failed`` is
    true when they are missing, which most compile events' are."""
    exc = getattr(ev, "_exc_details", None)
    return bool(exc) and exc[0] is not None


def _mode(ev) -> bool | None:
    """Whether numba compiles the event's function with its runtime (reference counting):
    its own ``_nrt`` if declared, else its caller's (numba's ``ConfigStack``: the flags of the
    function being compiled when this one is reached), else on."""
    from numba.core.targetconfig import ConfigStack

    disp = (ev.data or {}).get("dispatcher")
    declared = getattr(disp, "targetoptions", {}).get("_nrt")
    if declared is not None:
        return bool(declared)
    try:
        stack = ConfigStack()
        return bool(stack.top().nrt) if stack else True
    except Exception:  # pragma: no cover - another numba's internals
        return None


def record(job: str, work: Path) -> dict:
    """Run ``job`` in this process, recording its compiles (:class:`Recorder`)."""
    from numba.core import event

    rec = Recorder()

    class _Listener(event.Listener):
        def on_start(self, ev):
            rec.on_start(ev)

        def on_end(self, ev):
            rec.on_end(ev)

    t0, c0 = time.perf_counter(), time.process_time()
    with event.install_listener("numba:compile", _Listener()):
        JOBS[job][1](work)
    return {
        "job": job,
        "what": JOBS[job][0],
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "records": rec.records,
    }


def _child_env(cache: str, extra: dict | None = None) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, TDACM_PARALLEL_COMPILE="0")
    env["TDACM_KERNEL_CACHE"] = "local"
    env.pop("TDACM_KERNEL_CACHE_BUILD", None)
    env.update(extra or {})
    return env


def _run_child(args: list[str], env: dict, timeout: float | None) -> dict:
    with tempfile.TemporaryDirectory(prefix="tdacm-compile-") as work:
        out = Path(work) / "result.json"
        cmd = [
            sys.executable,
            "-m",
            "tdacm.bench.compile",
            *args,
            "--work",
            work,
            "--json",
            str(out),
        ]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
        if proc.returncode != 0 or not out.is_file():
            raise RuntimeError(f"{' '.join(args)} failed:\n{proc.stderr[-3000:]}")
        return json.loads(out.read_text())


def profile(job: str, timeout: float | None = None) -> dict:
    """:func:`record` of ``job`` in a fresh process on an empty numba cache (module
    docstring), with the load average before and after."""
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="tdacm-empty-cache-") as cache:
        res = _run_child(["record", job], _child_env(cache), timeout)
    res["load"] = [load0, os.getloadavg()]
    return res


# ------------------------------------------------------------------ tables
def summary(res: dict) -> dict:
    """Totals of a :func:`record` result: compiled kernels (function and argument types), the
    distinct functions, the compile seconds (CPU of the compiling thread, and wall: the sums
    of the exclusive seconds, i.e. of the top-level compiles' inclusive ones), and the waste
    it shows: functions compiled for several argument types and functions compiled in both
    runtime modes."""
    recs = res["records"]
    by_fn: dict = {}
    for r in recs:
        by_fn.setdefault((r["module"], r["qualname"]), []).append(r)
    return {
        "kernels": len(recs),
        "functions": len(by_fn),
        "compile_cpu_s": float(sum(r["exclusive_cpu_s"] for r in recs)),
        "compile_s": float(sum(r["exclusive_s"] for r in recs)),
        "wall_s": res["wall_s"],
        "several_types": sorted(
            f"{m}.{q}" for (m, q), rs in by_fn.items() if len({r["types"] for r in rs}) > 1
        ),
        "both_modes": sorted(
            f"{m}.{q}" for (m, q), rs in by_fn.items() if len({r["nrt"] for r in rs}) > 1
        ),
    }


def table(res: dict, top: int = 15) -> str:
    """A markdown table of ``res``'s functions by exclusive compile CPU seconds (the first
    ``top``), then the totals."""
    by_fn: dict = {}
    for r in res["records"]:
        e = by_fn.setdefault(f"{r['module']}.{r['qualname']}", [0, 0.0, 0.0, set()])
        e[0] += 1
        e[1] += r["exclusive_cpu_s"]
        e[2] += r["exclusive_s"]
        e[3].add("off" if r["nrt"] is False else "on")
    ranked = sorted(by_fn.items(), key=lambda kv: -kv[1][1])
    s = summary(res)
    total = max(s["compile_cpu_s"], 1e-12)
    load = res.get("load")
    lines = [
        f"`{res['what']}` on an empty cache: {s['kernels']} kernels ({s['functions']} "
        f"functions), {s['compile_cpu_s']:.1f} s of compile CPU ({s['compile_s']:.1f} s wall), "
        f"the job {s['wall_s']:.1f} s wall"
        + (f", load average {load[0][0]:.1f} -> {load[1][0]:.1f}" if load else ""),
        "",
        "| function | kernels | compile CPU s (exclusive) | share | wall s | reference counting |",
        "|---|---|---|---|---|---|",
    ]
    for name, (n, cpu, wall, modes) in ranked[:top]:
        lines.append(f"| `{name}` | {n} | {cpu:.2f} | {cpu / total:.1%} | {wall:.2f} | "
                     f"{'/'.join(sorted(modes))} |")  # fmt: skip
    rest = ranked[top:]
    if rest:
        cpu = sum(v[1] for _, v in rest)
        lines.append(f"| {len(rest)} others | {sum(v[0] for _, v in rest)} | {cpu:.2f} | "
                     f"{cpu / total:.1%} | {sum(v[2] for _, v in rest):.2f} | |")  # fmt: skip
    lines.append(f"| **total** | **{s['kernels']}** | **{s['compile_cpu_s']:.1f}** | | "
                 f"**{s['compile_s']:.1f}** | |")  # fmt: skip
    if s["both_modes"]:
        lines += ["", "compiled in both runtime modes: " + ", ".join(s["both_modes"])]
    if s["several_types"]:
        lines += ["", "compiled for several argument types: " + ", ".join(s["several_types"])]
    return "\n".join(lines)


def estimates_of(results: dict) -> dict:
    """The compile-time estimates of the notice (:data:`tdacm._compiling.ESTIMATES`) from
    :func:`profile` results of several jobs."""
    jobs = {}
    for job, res in results.items():
        jobs[job] = {
            "seconds": round(summary(res)["compile_cpu_s"], 1),
            "kernels": [
                [r["module"], r["qualname"], r["types"], round(r["exclusive_cpu_s"], 3)]
                for r in res["records"]  # a failed attempt costs its time at every first use too
                if (r["module"] or "").startswith("tdacm")
            ],
        }
    return {
        "measured": "tdacm bench --compile JOB --write-estimates (empty cache, one process)",
        "load": {job: res.get("load") for job, res in results.items()},
        "jobs": jobs,
    }


def write_estimates(results: dict, path: Path | None = None) -> Path:
    """Store :func:`estimates_of` ``results`` in the compile notice's estimates file
    (:data:`tdacm._compiling.ESTIMATES`), keeping the jobs measured before and not in
    ``results``. Returns the file's path."""
    from .._compiling import ESTIMATES

    path = Path(path or ESTIMATES)
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        old = {}
    new = estimates_of(results)
    merged = {
        "measured": new["measured"],
        "load": {**old.get("load", {}), **new["load"]},
        "jobs": {**old.get("jobs", {}), **new["jobs"]},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(merged) + "\n")
    return path


# ------------------------------------------------------------------ the shipped cache
#: the jobs compiled into a wheel's cache and by ``make test``'s warm-up, in two phases of at most
#: two processes each (one group of jobs per process): ``tdacm run`` and the contact
#: scenarios (:data:`EXTRAS`) beside identification and the stiff integrators (its stiff
#: shooting path shares their kernels), then the engine with the vector env, which loads the
#: blocks' compiled steps the first phase cached instead of compiling them again (the engine
#: calls the same steps as the block loop); the engine's own functions then compile in two
#: processes (:mod:`tdacm.sim.compile_engine`, on in a phase of one group: :func:`_phase_env`)
PHASES = ((("run", "touch"), ("identify", "stiff")), (("engine", "vector-env"),))


def _merge(src: Path, dst: Path) -> int:
    """Add ``src``'s cache entries to ``dst``'s (same layout and source stamp): each index's
    entries that ``dst`` lacks, with their data files. Returns the number of entries added."""
    import pickle

    from numba.core.caching import IndexDataCacheFile

    added = 0
    for index in sorted(src.rglob("*.nbi")):
        rel = index.parent.relative_to(src)
        base = index.name[: -len(".nbi")]
        with open(index, "rb") as f:
            pickle.load(f)  # numba's version
            stamp, _ = pickle.loads(f.read())
        a = IndexDataCacheFile(str(index.parent), base, stamp)
        b = IndexDataCacheFile(str(dst / rel), base, stamp)
        (dst / rel).mkdir(parents=True, exist_ok=True)
        have = b._load_index()
        for key, name in a._load_index().items():
            if key not in have:
                b.save(key, a._load_data(name))
                added += 1
    return added


def _phase_env(env: dict, k: int) -> dict:
    """``env`` for a process of phase ``k``: the second compiling processes of the jobs
    (:mod:`tdacm.loop.precompile`, :mod:`tdacm.sim.compile_engine`) off while the phase's
    process groups share the cores, on in a phase of one group (the engine's: its ``act``
    compiles beside its ``sense``)."""
    return dict(env, TDACM_PARALLEL_COMPILE="0" if len(PHASES[k]) > 1 else "1")


def _run_phase(k: int, env_of, tmp: Path, t0: float, timeout: float | None, progress) -> list:
    """Run phase ``k`` of :data:`PHASES`: its process groups at once (``python -m
    tdacm.bench.compile run-jobs JOB ...``, the environment ``env_of(k, process)``); returns
    the failures' messages (empty: all compiled). ``timeout`` counts from ``t0``."""
    failures = []
    procs = []
    for i, jobs in enumerate(PHASES[k]):
        cmd = [sys.executable, "-m", "tdacm.bench.compile", "run-jobs", *jobs,
               "--work", str(tmp / f"work{k}-{i}")]  # fmt: skip
        log = open(tmp / f"log{k}-{i}", "w")
        proc = subprocess.Popen(cmd, env=env_of(k, i), stdin=subprocess.DEVNULL, stdout=log,
                                stderr=log)  # fmt: skip
        procs.append((jobs, log, proc))
    for jobs, log, proc in procs:
        try:
            left = None if timeout is None else max(1.0, timeout - (time.perf_counter() - t0))
            rc = proc.wait(timeout=left)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
        log.close()
        if rc != 0:
            text = Path(log.name).read_text()[-3000:]
            failures.append(f"compiling {', '.join(jobs)} failed:\n{text}")
        else:
            progress(f"tdacm: compiled {', '.join(jobs)} ({time.perf_counter() - t0:.0f} s)")
    return failures


def ship(folder: Path, timeout: float | None = None, progress=print) -> dict:
    """Compile every job for the portable target into ``folder`` (module docstring), phase by
    phase (:data:`PHASES`): a phase's processes each compile into a copy of ``folder``, merged
    back before the next phase, so that no two processes write one index. Then the manifest.
    Returns the manifest."""
    import shutil

    from .. import __version__
    from .._jitcache import ENV_BUILD

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tdacm-ship-") as tmp:
        tmp = Path(tmp)

        def env_of(k, i):
            part = tmp / f"part{k}-{i}"
            if len(PHASES[k]) > 1:  # its own copy of what the earlier phases compiled
                shutil.copytree(folder, part)
            env = _child_env(str(tmp / "unused"),
                             {ENV_BUILD: str(part if len(PHASES[k]) > 1 else folder)})  # fmt: skip
            env.pop("TDACM_KERNEL_CACHE")
            return _phase_env(env, k)

        for k, phase in enumerate(PHASES):
            failures = _run_phase(k, env_of, tmp, t0, timeout, progress)
            if failures:
                raise RuntimeError("\n".join(failures))
            if len(phase) > 1:
                for i in range(len(phase)):
                    _merge(tmp / f"part{k}-{i}", folder)
    # the manifest, written by a build-mode process (its numba, Python and target)
    env = _child_env(str(folder / "unused"), {ENV_BUILD: str(folder)})
    env.pop("TDACM_KERNEL_CACHE")
    code = (
        "import sys, json\nfrom tdacm._jitcache import write_manifest\n"
        f"m = write_manifest(sys.argv[1], version={__version__!r}, jobs={sorted(ALL_JOBS)!r})\n"
        "print(json.dumps(m))\n"
    )
    out = subprocess.run([sys.executable, "-c", code, str(folder)], env=env, capture_output=True,
                         text=True, check=True)  # fmt: skip
    manifest = json.loads(out.stdout.strip().splitlines()[-1])
    entries = sum(1 for _ in folder.rglob("*.nbc"))
    progress(f"{entries} compiled kernels in {folder} ({time.perf_counter() - t0:.0f} s)")
    return manifest


def fill(timeout: float | None = None, progress=print) -> int:
    """Compile every job into numba's cache as this process finds it (a checkout's
    ``__pycache__`` folders, or ``NUMBA_CACHE_DIR``), phase by phase (:data:`PHASES`;
    ``make test``'s warm-up, so that the suite loads the kernels). Returns the number of
    process groups that failed (a failure only leaves kernels to compile at first use)."""
    t0 = time.perf_counter()
    progress("tdacm: compiling the kernels of " + ", ".join(ALL_JOBS) + " (once; minutes) ...")
    with tempfile.TemporaryDirectory(prefix="tdacm-fill-") as tmp:
        failures = []
        for k in range(len(PHASES)):
            env_of = lambda k, i: _phase_env(dict(os.environ), k)  # noqa: E731
            failures += _run_phase(k, env_of, Path(tmp), t0, timeout, progress)
    for text in failures:
        progress(f"tdacm: {text}")
    progress(f"tdacm: kernels cached in {time.perf_counter() - t0:.0f} s")
    return len(failures)


def verify(timeout: float | None = None) -> dict:
    """Run every job in a fresh process with the installed package's shipped kernels (an
    empty ``NUMBA_CACHE_DIR`` besides): per job, the package's kernels that still compiled
    (the dispatchers' cache misses) and the job's wall seconds."""
    with tempfile.TemporaryDirectory(prefix="tdacm-verify-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, TDACM_PARALLEL_COMPILE="0")
        env.pop("TDACM_KERNEL_CACHE", None)
        env.pop("TDACM_KERNEL_CACHE_BUILD", None)
        return _run_child(["verify"], env, timeout)


def compiled_dispatchers() -> list:
    """Every numba dispatcher of the package's imported modules with its cache misses (the
    argument types compiled in this process rather than loaded)."""
    from numba.core.registry import CPUDispatcher

    seen, out = set(), []
    for name, mod in list(sys.modules.items()):
        if not (name == "tdacm" or name.startswith("tdacm.")) or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, CPUDispatcher) and id(obj) not in seen:
                seen.add(id(obj))
                misses = sum(obj.stats.cache_misses.values())
                if misses:
                    out.append((f"{obj.py_func.__module__}.{obj.py_func.__qualname__}", misses))
    return out


# ------------------------------------------------------------------ run-time speed
#: the speed measures of a fresh process (APIs of any version of the package, so that two
#: source trees compare), in CPU time of this process, the least of several repeats (the
#: figures a shared machine's load changes least): the paper system's forward dynamics in a
#: compiled loop (us per evaluation) and called from Python, ``terms`` from Python, and the
#: engine's CPU per world-period (256 worlds, 2 threads, 1 s runs) with its world-periods/s
SPEED_CODE = """
import json, os, time
import numpy as np
from tdacm.bench.model import _fd_loop, bench_state
from tdacm.bench.batch import _batch
from tdacm.system import kernels as K
from tdacm.system.paper import paper_system

def least(fn, number, repeats=7):
    fn()
    best = float("inf")
    for _ in range(repeats):
        c0 = time.process_time()
        for _ in range(number):
            fn()
        best = min(best, (time.process_time() - c0) / number)
    return best * 1e6

s = paper_system()
q, qd, u = bench_state(s)
m, loads = s.model_arrays, s.loads.packed()
out = {"model_in_numba_us": least(lambda: _fd_loop(q, qd, u, m, loads, 1000), 1) / 1000,
       "model_python_us": least(lambda: K.forward_dynamics(q, qd, u, m, loads), 2000),
       "terms_python_us": least(lambda: s.terms(q, qd), 1000)}
_batch(2, 1, 0.1).run()
b = _batch(256, 2, 1.0)
cpus, rates = [], []
for _ in range(5):
    t0, c0 = time.perf_counter(), time.process_time()
    res = b.run()
    n = float(res.samples.sum())
    cpus.append(1e3 * (time.process_time() - c0) / n)
    rates.append(n / (time.perf_counter() - t0))
out.update(engine_cpu_ms_per_world_period=min(cpus), engine_world_periods_per_s=max(rates),
           load=os.getloadavg()[0])
from numba.core import config
import tdacm
jc = getattr(tdacm, "_jitcache", None)
print(json.dumps({**out, "cpu": config.CPU_NAME or "host",
                  "kernels": jc.status["mode"] if jc else "local"}))
"""


def speed_ab(variants: dict, rounds: int = 2, progress=print) -> dict:
    """:data:`SPEED_CODE` in fresh processes, alternating ``variants`` (name -> extra
    environment, e.g. a ``PYTHONPATH`` of another source tree or numba's portable target),
    ``rounds`` of each; per variant the list of results and the medians, and each measure's
    ratio of the medians of the later variants to the first one's (their kernels are compiled
    by a first, untimed process of each variant)."""
    import statistics

    def once(extra):
        env = dict(os.environ)
        env.update(extra)
        proc = subprocess.run([sys.executable, "-c", SPEED_CODE], env=env, capture_output=True,
                              text=True)  # fmt: skip
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-3000:])
        return json.loads(proc.stdout.strip().splitlines()[-1])

    for name, extra in variants.items():  # compile (or load) each variant's kernels first
        progress(f"warming {name} ...")
        once(extra)
    runs: dict = {name: [] for name in variants}
    for r in range(rounds):
        for name, extra in variants.items():
            runs[name].append(res := once(extra))
            progress(f"round {r + 1} {name}: {res}")
    medians = {
        name: {k: statistics.median(x[k] for x in rs) for k in rs[0] if k not in ("cpu", "kernels")}
        for name, rs in runs.items()
    }
    first = next(iter(variants))
    ratios = {
        name: {k: medians[name][k] / medians[first][k] for k in medians[first] if k != "load"}
        for name in variants
        if name != first
    }
    return {"runs": runs, "medians": medians, "ratios_to_" + first: ratios}


def portable_env(cache: Path) -> dict:
    """The environment of a process compiling for the shipped kernels' portable target into
    ``cache`` (numba's own caching there; :mod:`tdacm._jitcache`)."""
    from .._jitcache import PORTABLE_CPU, PORTABLE_FEATURES

    return {
        "NUMBA_CPU_NAME": PORTABLE_CPU,
        "NUMBA_CPU_FEATURES": PORTABLE_FEATURES,
        "NUMBA_CACHE_DIR": str(cache),
        "TDACM_KERNEL_CACHE": "local",
    }


# ------------------------------------------------------------------ the child processes
def _main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m tdacm.bench.compile")
    p.add_argument("action", choices=["record", "run-jobs", "verify", "ship", "fill"])
    p.add_argument("jobs", nargs="*")
    p.add_argument("--work", default=None)
    p.add_argument("--json", default=None)
    p.add_argument("--out", default=None, help="ship: the folder of the cache")
    p.add_argument("--strict", action="store_true", help="verify: fail unless all loaded")
    a = p.parse_args(argv)
    work = Path(a.work or tempfile.mkdtemp(prefix="tdacm-compile-work-"))
    work.mkdir(parents=True, exist_ok=True)
    if a.action == "ship":
        ship(Path(a.out))
        return 0
    if a.action == "fill":
        fill()
        return 0  # never fails the install: the kernels then compile at their first use
    if a.action == "record":
        res = record(a.jobs[0], work)
    elif a.action == "run-jobs":
        for job in a.jobs:
            ALL_JOBS[job][1](work)
        res = {}
    else:
        from .._jitcache import status

        res = {"mode": status["mode"], "reason": status["reason"], "jobs": {}}
        for job in a.jobs or list(ALL_JOBS):
            t0 = time.perf_counter()
            ALL_JOBS[job][1](work)
            res["jobs"][job] = {"wall_s": time.perf_counter() - t0}
        res["compiled"] = compiled_dispatchers()
        if a.strict and (status["mode"] != "shipped" or res["compiled"]):
            print(f"the shipped kernels are not complete: mode {status['mode']} "
                  f"({status['reason']}), compiled {res['compiled']}", file=sys.stderr)  # fmt: skip
            return 1
    if a.json:
        Path(a.json).write_text(json.dumps(res))
    return 0


if __name__ == "__main__":  # pragma: no cover - the child processes above
    sys.exit(_main())
