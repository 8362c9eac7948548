"""Model benchmark (``tdacm bench``): median cost of the dynamics and passive real-time factor.

Measured in one run, for the paper system (``n = 8``) and a richer rod (torsion and both
bendings of order 3, ``n = 18``):

* ``terms``: one full :meth:`TDACM.terms` call (M, C, D, K, tau_ext, B) from Python;
* ``forward_dynamics`` through the Python API, through the numba kernel called from Python (its
  dispatch included: numba types and unboxes the 34 arrays of the model at every call) and
  inside numba (a compiled loop of calls: what the integrators and batched callers pay);
* the real-time factor of 5 s of passive motion with the default integrator (RK4 at
  :meth:`TDACM.suggested_dt`), from a bent, moving initial state.

Medians over ``repeats`` repetitions; the spread is the interquartile range.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
from numba import njit

from .._log import REPORT
from .._timing import batch_times
from ..rod import StrainBasis
from ..system import kernels as K
from ..system import paper_system, simulate

log = logging.getLogger(__name__)
report = logging.getLogger(REPORT)  # the tables: stdout of `tdacm bench`


def _stage(text: str, end: bool = False) -> None:
    """One progress line on stderr (overwritten in a terminal), drawn like a progress bar:
    not with ``tdacm -q``."""
    import sys

    from .._log import progress_enabled

    if not progress_enabled():
        return
    tty = sys.stderr.isatty()
    sys.stderr.write(
        ("\r\033[K" if tty else "") + f"bench: {text}" + ("\n" if end or not tty else "")
    )
    sys.stderr.flush()


@njit(cache=True)
def _fd_loop(q, qd, u, m, loads, count):
    """``count`` forward-dynamics evaluations inside numba (no Python dispatch per call)."""
    acc = 0.0
    for _ in range(count):
        a, _ok = K.forward_dynamics(q, qd, u, m, loads)
        acc += a[0]
    return acc


def _median_time(fn, number, repeats):
    a = np.array(batch_times(fn, number, repeats))
    return float(np.median(a)), float(np.percentile(a, 75) - np.percentile(a, 25))


def bench_state(system):
    """The benchmarks' state of a floating ``system``: the drone 3 m up, the strains bent and
    every coordinate moving (seeded), the rotors carrying the weight and the tendons slack:
    ``(q, qd, u)``."""
    rng = np.random.default_rng(0)
    q = np.zeros(system.n)
    q[5] = 3.0
    q[6:] = rng.normal(size=system.n_s) * 0.3
    qd = rng.normal(size=system.n) * 0.1
    u = np.r_[np.full(4, system.total_mass * 9.81 / 4), np.zeros(system.n_a)]
    return q, qd, u


def bench_system(name, system, repeats=7, duration=5.0):
    """Per-call costs and the RK4 passive real-time factor (:func:`bench_state`)."""
    q, qd, u = bench_state(system)
    m, loads = system.model_arrays, system.loads.packed()
    # warm-up (compilation is cached on disk after the first run)
    system.terms(q, qd)
    system.forward_dynamics(q, qd, u)
    simulate(system, q, qd, duration=0.02, u=u, method="rk4")
    t_terms = _median_time(lambda: system.terms(q, qd), 2000, repeats)
    t_fd_api = _median_time(lambda: system.forward_dynamics(q, qd, u), 5000, repeats)
    t_fd_kernel = _median_time(lambda: K.forward_dynamics(q, qd, u, m, loads), 5000, repeats)
    _fd_loop(q, qd, u, m, loads, 1)
    loop = _median_time(lambda: _fd_loop(q, qd, u, m, loads, 1000), 1, repeats)
    dt = system.suggested_dt()
    walls = []
    for _ in range(max(3, repeats // 2)):
        t0 = time.perf_counter()
        res = simulate(system, q, qd, duration=duration, dt=dt, u=u, record_dt=0.01, method="rk4")
        walls.append(time.perf_counter() - t0)
    wall = float(np.median(walls))
    return {
        "system": name,
        "n": system.n,
        "n_gauss": system.rod.n_gauss,
        "terms_us": t_terms[0] * 1e6,
        "terms_iqr_us": t_terms[1] * 1e6,
        "forward_dynamics_api_us": t_fd_api[0] * 1e6,
        "forward_dynamics_kernel_us": t_fd_kernel[0] * 1e6,
        "forward_dynamics_kernel_iqr_us": t_fd_kernel[1] * 1e6,
        "forward_dynamics_in_numba_us": loop[0] / 1000 * 1e6,
        "rk4_dt_s": dt,
        "passive_sim_s": duration,
        "passive_wall_s": wall,
        "real_time_factor": duration / wall,
        "completed": bool(res.completed),
    }


def _released(system):
    """The rod held by tendons 0 and 1 (2 N, 1 N) below the drone held at 3 m, in equilibrium;
    released with hover thrust (the stiff benchmark's passive case)."""
    q0 = np.zeros(system.n)
    q0[5] = 3.0
    ut = np.zeros(system.n_u)
    ut[4:6] = [2.0, 1.0]
    q = system.static_equilibrium(ut, q0=q0, load_steps=4)
    u = np.r_[np.full(4, system.total_mass * 9.81 / 4), np.zeros(system.n_a)]
    return q, u


def bench_stiff(
    name,
    system,
    method="rosenbrock",
    duration=5.0,
    check=0.5,
    reference="dop853",
    repeats=3,
    ref=None,
):
    """A stiff integrator (``"rosenbrock"``: ROS34PW2 at 2.5 ms, ``"radau"``: Radau IIA at 10 ms,
    fixed steps) on a stiff rod: median wall time of ``duration`` s of the released passive case,
    and the tip error over the first ``check`` s against a converged reference: DOP853 at rtol
    1e-10 (``reference="dop853"``) or, when DOP853 cannot afford the stiffness, Radau IIA at a
    tenth of its step with a Newton tolerance of 1e-10 (``"radau/10"``; checked once against
    RK4 at a resolved step, ``docs/benchmarks.md``).  ``ref`` reuses a reference simulation."""
    from ..system import stiff as ST
    from ..system.integrate import RADAU_DT, ROSENBROCK_DT, SimulationResult

    step = ROSENBROCK_DT if method == "rosenbrock" else RADAU_DT
    q, u = _released(system)
    simulate(system, q, None, duration=0.02, u=u, method=method, record_dt=0.01)  # warm-up
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = simulate(system, q, None, duration=duration, u=u, method=method, record_dt=0.01)
        walls.append(time.perf_counter() - t0)
    wall = float(np.median(walls))
    t0 = time.perf_counter()
    if ref is not None:
        pass
    elif reference == "dop853":
        ref = simulate(
            system, q, None, check, u=u, method="adaptive", rtol=1e-10, atol=1e-12, record_dt=0.01
        )
    else:
        m, loads = system.model_arrays, system.loads.packed()
        h = RADAU_DT / 10
        t, qs, qds, ok, _ = ST.radau_run(
            q, np.zeros(system.n), u, check, 0.01, h, h, 0.0, 0.0, 0.0, 1e-10, 12, m, loads
        )
        ref = SimulationResult(t, qs, qds, np.tile(u, (t.shape[0], 1)), ok)
    ref_wall = time.perf_counter() - t0
    k = min(ref.q.shape[0], res.q.shape[0])
    tip = np.array([system.tip_pose(x)[:3, 3] for x in res.q[:k]])
    tref = np.array([system.tip_pose(x)[:3, 3] for x in ref.q[:k]])
    e = [system.energy(a, b)["total"] for a, b in zip(res.q, res.qd, strict=True)]
    return {
        "system": name,
        "n": system.n,
        "w_max_rad_s": float(system.natural_frequencies().max()),
        "rk4_stable_dt_s": system.suggested_dt(),
        "method": method,
        "dt_s": step,
        "passive_sim_s": duration,
        "passive_wall_s": wall,
        "real_time_factor": duration / wall,
        "completed": bool(res.completed),
        "reference": reference,
        "reference_wall_s": ref_wall,
        "check_s": check,
        "tip_error_max_m": float(np.abs(tip - tref).max()),
        "tip_travel_m": float(np.abs(tref - tref[0]).max()),
        "energy_change_J": float(e[-1] - e[0]),
        "energy_span_J": float(max(e) - min(e)),
        "kinetic_max_J": float(
            max(system.energy(a, b)["kinetic"] for a, b in zip(res.q, res.qd, strict=True))
        ),
        "_ref": ref,
    }


def run_model_bench(out="out/bench", repeats=7) -> dict:
    rich = paper_system(basis=StrainBasis((3, 3, 3, None, None, None)), n_gauss=8, magnus_order=4)
    systems = [
        ("paper (2 bending, order 0)", paper_system(), 5.0),
        ("rich (torsion + 2 bending, order 3)", rich, 1.0),
    ]
    rows = []
    for i, (name, s, d) in enumerate(systems):
        _stage(f"model {i + 1}/{len(systems)}: {name}")
        rows.append(bench_system(name, s, repeats, duration=d))
    _stage("model: done", end=True)
    report.info(
        f"{'system':38s} {'n':>3s} {'terms':>10s} {'fd(api)':>10s} {'fd(kernel)':>11s} "
        f"{'fd(numba)':>10s} {'RK4 dt':>9s} {'RTF':>8s}"
    )
    for r in rows:
        report.info(
            f"{r['system']:38s} {r['n']:3d} {r['terms_us']:8.1f}us {r['forward_dynamics_api_us']:8.1f}us "
            f"{r['forward_dynamics_kernel_us']:9.1f}us {r.get('forward_dynamics_in_numba_us', np.nan):8.1f}us "
            f"{r['rk4_dt_s']:9.2e} {r['real_time_factor']:7.1f}x"
        )
    full = paper_system(basis=StrainBasis.full(2))
    stiff = []
    for sysname, s_, refname in (
        ("18-DoF (torsion + 2 bending, order 3)", rich, "dop853"),
        ("full 6 strains, order 2 (n = 24)", full, "radau/10"),
    ):
        ref = None
        for method in ("rosenbrock", "radau"):
            _stage(f"stiff integrators: {sysname}, {method}")
            row = bench_stiff(sysname, s_, method, reference=refname, ref=ref)
            ref = row.pop("_ref")
            stiff.append(row)
    report.info(
        f"\n{'stiff rod, fixed steps':38s} {'n':>3s} {'w_max':>9s} {'RTF':>8s} {'tip err':>10s} (first s, reference)"
    )
    for r in stiff:
        report.info(
            f"{r['system'][:26] + ', ' + r['method']:38s} {r['n']:3d} {r['w_max_rad_s']:9.3g} {r['real_time_factor']:7.1f}x "
            f"{r['tip_error_max_m'] * 1e3:8.3f}mm ({r['check_s']} s, {r['reference']}, "
            f"travel {r['tip_travel_m'] * 1e3:.0f} mm, completed {r['completed']})"
        )
    from .loop import loop_bench

    _stage("closed loop (paper-in-fov, 5 s, rendered and analytic C_L)")
    loop = loop_bench(repeats=5, cold=False, progress=_stage)
    report.info(
        f"\n{'closed loop, paper-in-fov 5 s':38s} {'wall/sim s':>10s} {'RTF':>8s} "
        f"{'compiled':>9s} {'cap':>7s}"
    )
    for name in ("rendered", "analytic"):
        r = loop[name]
        c = r.get("compiled")
        extra = f" {c['compiled_ms']:7.2f}ms {c['cap_real_time_factor']:6.1f}x" if c else ""
        report.info(
            f"{name + ' C_L':38s} {r['wall_per_sim_second']:10.3f} {r['real_time_factor']:7.1f}x"
            + extra
        )
    r = loop["shipped"]
    report.info(
        f"{'tdacm run paper-in-fov (as shipped)':38s} {r['wall_per_sim_second']:10.3f} "
        f"{r['real_time_factor']:7.1f}x (target >= {r['target_real_time_factor']:.0f}x: "
        f"ratio {r['ratio_to_target']:.2f})"
    )
    env = _env_section()
    load = open("/proc/loadavg").read().split()[:3] if Path("/proc/loadavg").exists() else []
    result = {
        "model": rows,
        "stiff": stiff,
        "loop": loop,
        "env": env,
        "load_average": load,
        "machine_note": "medians; IQR in *_iqr_us",
    }
    report.info(f"load average (1, 5, 15 min) at the end: {load}")
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    (path / "bench.json").write_text(json.dumps(result, indent=2))
    log.info(f"written {path.resolve() / 'bench.json'}")
    return result


def _env_section() -> dict | None:
    """The env figures (:mod:`.env`), ``None`` without the ``env`` extra."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return None
    from .env import env_bench

    _stage("env (tdacm/TipServo-v0): one env, reset, 2 async envs")
    e = env_bench(progress=_stage)
    q = e["ratios"]
    report.info(
        f"\n{'env tdacm/TipServo-v0':38s} one env {e['single_steps_per_s']:.0f} steps/s "
        f"(ratio {q['single_steps_per_s']:.2f}), 2 async {e['async2_steps_per_s']:.0f} "
        f"env-steps/s (ratio {q['async2_steps_per_s']:.2f}), reset {e['reset_ms']:.2f} ms "
        f"(ratio {q['reset_ms']:.1f})"
    )
    return e


def run_full_bench(out="out/bench", repeats=7, accuracy=True, scaling=True) -> dict:
    """The model benchmark plus the GVS-vs-CC comparison, in one run.

    Sections (see :mod:`tdacm.baselines.study` and ``docs/benchmarks.md``): the model timings of
    :func:`run_model_bench`; the CC Lagrangian baseline's derivation/cache figures; per-call and
    per-closed-loop-iteration times of GVS and CC with the same Python RK4 and step (median,
    IQR, ratio); GVS cost against strain DoFs and Gauss points; tip accuracy of CC and GVS
    orders 0..3 against a converged GVS reference; PyElastica when installed.  Writes
    ``bench.json``, ``time_vs_dofs.png`` and ``error_vs_time.png`` to ``out``.
    """
    from ..baselines import study

    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    walls = {}
    t0 = time.perf_counter()
    result = run_model_bench(out=out, repeats=repeats)
    walls["model"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _stage("full 1/4: GVS vs CC timing")
    timing = study.timing_study()
    walls["baseline_timing"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _stage("full 2/4: DoF scaling")
    # 10 and 16 points: a mode of order p needs p + 2 points (tdacm.rod.min_gauss_points), so
    # the 4- and 8-point columns of the earlier runs are refused for orders above 2 and 6
    rows = study.scaling_study(gauss=(10, 16)) if scaling else []
    walls["scaling"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _stage("full 3/4: accuracy study")
    acc = study.accuracy_study() if accuracy else {"duration_s": 0, "rk4_dt_s": 0, "cases": {}}
    walls["accuracy"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    swing = acc["cases"].get("swing")
    ref = dict(swing, record_dt_s=acc["record_dt_s"]) if swing else None
    _stage("full 4/4: PyElastica")
    elastica = study.pyelastica_study(reference=ref)
    walls["pyelastica"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    from .loop import time_cold_start

    _stage("full: cold first run (empty numba cache)")
    result["loop"]["cold_start"] = time_cold_start()
    walls["cold_start"] = time.perf_counter() - t0
    _stage("full: done", end=True)
    study.print_report(timing, rows, acc, elastica)
    report.info("\nsection wall times (s): " + ", ".join(f"{k} {v:.1f}" for k, v in walls.items()))
    result.update(
        {
            "baseline": timing,
            "scaling": rows,
            "accuracy": acc,
            "pyelastica": elastica,
            "section_wall_s": walls,
        }
    )
    (path / "bench.json").write_text(json.dumps(result, indent=2))
    if rows:
        cc_fd = timing["model"]["cc"]["forward_dynamics"]["median_s"]
        study.plot_scaling(rows, path / "time_vs_dofs.png", cc_fd_s=cc_fd)
    if acc["cases"]:
        study.plot_accuracy(acc, path / "error_vs_time.png", elastica=elastica)
    log.info(f"written {path.resolve() / 'bench.json'} and plots")
    return result
