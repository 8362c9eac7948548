"""Benchmark studies GVS vs the CC Lagrangian baseline (used by ``tdacm bench``).

* :func:`timing_study`: per-iteration cost of the model alone and of a 50 Hz closed loop (the
  paper's low-level loop without rendering), GVS and CC, same Python-level RK4 and step;
* :func:`scaling_study`: GVS cost against the number of strain DoFs and of Gauss points;
* :func:`accuracy_study`: tip error of CC and GVS orders 0..3 against a converged GVS reference
  (clamped rod swinging under gravity; tendon-bent rod with a tip dead load);
* :func:`pyelastica_study`: the swinging rod in PyElastica, when that optional extra is installed.

Every function returns plain dicts/lists (JSON-ready).  Times are wall-clock seconds from
``time.perf_counter``; "median" and "IQR" are over individually timed iterations or batches.
"""

from __future__ import annotations

import contextlib
import io
import logging
import time
from functools import partial

import numpy as np

from .._log import REPORT
from .._timing import batch_times
from ..control import CubicTrajectory, EstimatedModel, TDACMController, default_gains
from ..rod import StrainBasis
from ..system import Loads, paper_system, simulate
from ..system import kernels as K
from .cc import CCLagrangian
from .integrate import rk4_step

#: the paper's first scenario (``scenarios/paper-in-fov.toml``): initial and desired states
PAPER_Q0 = np.array([0.0, 0.0, np.pi / 18, -0.5, 0.5, 5.0, -0.3, -0.4])
PAPER_QD = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0])

report = logging.getLogger(REPORT)  # the tables: stdout of `tdacm bench`


def _stats(samples) -> dict:
    a = np.asarray(samples, dtype=float)
    return {
        "median_s": float(np.median(a)),
        "iqr_s": float(np.percentile(a, 75) - np.percentile(a, 25)),
        "mean_s": float(a.mean()),
        "std_s": float(a.std()),
        "min_s": float(a.min()),
        "n": int(a.size),
    }


# ---------------------------------------------------------------------------------- timing
def _paper_controller(gvs, model, q0, duration):
    """The project's low-level controller (:class:`tdacm.control.TDACMController`, 10 %
    perturbed estimated model) tracking a cubic joint trajectory ``PAPER_Q0 -> PAPER_QD``.
    Its estimated model is the GVS one for either plant: the controller's step is compiled
    over the GVS model's arrays (:func:`tdacm.control.hierarchical.controller_step`), so the
    CC run differs from the GVS run in its plant only."""
    est = EstimatedModel(gvs, level=0.1, seed=0)
    gains = default_gains(gvs, q0)
    ctl = TDACMController(gvs, model=est, gains=gains)
    ctl.reset(q0)
    traj = CubicTrajectory(q0, PAPER_QD, 0.0, duration)
    return ctl, traj


class TimedControlLoop:
    """What the timing study needs of the closed loop, on any model (GVS or the CC baseline,
    which the loop's plant cannot hold): per 50 Hz period the low-level controller, then
    ``substeps`` RK4 steps with the input held (the Python-level :func:`rk4_step`, or for a GVS
    model with ``numba=True`` the numba loop :func:`tdacm.system.kernels.rk4_run`); no sensors
    or servo. :meth:`step` runs one period and returns its wall time, so several loops can be
    advanced in lockstep (the machine's background load then hits all of them alike)."""

    def __init__(self, model, gvs, duration=5.0, period=0.02, substeps=4, numba=False):
        self.model, self.period, self.substeps, self.numba = model, period, substeps, numba
        self.q, self.qd = PAPER_Q0.copy(), np.zeros(8)
        self.k = 0
        self.h = period / substeps
        self.controller, self.trajectory = _paper_controller(gvs, model, self.q, duration)
        if numba:
            self._marr, self._loads = model.model_arrays, model.loads.packed()

    def step(self) -> float:
        t0 = time.perf_counter()
        q, qd = self.q, self.qd
        qr, qdr, qddr = self.trajectory(self.k * self.period)
        u = self.controller.step(q, qd, qr, qdr, qddr, self.period).u
        if self.numba:
            qs_, qds_, _ = K.rk4_run(
                q, qd, u, self.h, self.substeps, self.substeps, self._marr, self._loads
            )
            q, qd = qs_[-1], qds_[-1]
        else:
            for _ in range(self.substeps):
                q, qd = rk4_step(self.model, q, qd, u, self.h)
        self.q, self.qd = q, qd
        self.k += 1
        return time.perf_counter() - t0


def closed_loop(model, gvs, duration=5.0, period=0.02, substeps=4, numba=False):
    """Run one :class:`TimedControlLoop` to the end: per-iteration wall times and the final
    state."""
    loop = TimedControlLoop(model, gvs, duration, period, substeps, numba)
    times = [loop.step() for _ in range(int(round(duration / period)))]
    return np.array(times), loop.q


def _paired(fns, numbers, repeats):
    """Batch times of several functions, alternating batches (fair under background load)."""
    out = [[] for _ in fns]
    for _ in range(repeats):
        for i, (fn, number) in enumerate(zip(fns, numbers, strict=True)):
            out[i] += batch_times(fn, number, 1)
    return [_stats(a) for a in out]


def timing_study(repeats=15, duration=5.0, period=0.02, substeps=4) -> dict:
    """Per-iteration cost, GVS (paper system) vs CC baseline, same Python-level RK4.

    Model calls are timed in alternating batches (GVS batch, CC batch, ...); the three closed
    loops advance in lockstep.  Ratios are given for the medians and for the minima (the
    least disturbed estimate of the intrinsic cost on a shared machine)."""
    gvs = paper_system()
    t0 = time.perf_counter()
    cc = CCLagrangian.from_system(gvs)
    build = time.perf_counter() - t0
    q = PAPER_Q0.copy()
    qd = np.array([0.05, -0.03, 0.02, 0.1, -0.1, 0.2, 0.3, -0.2])
    u = np.r_[np.full(4, gvs.total_mass * 9.81 / 4), 0.5, 1.0, 0.5, 0.2]
    m, loads = gvs.model_arrays, gvs.loads.packed()
    h = period / substeps
    out = {
        "system": "paper (floating, 2 bending order 0, 5 Gauss points)",
        "cc_build": {
            "first_call_s": build,
            "from_cache": bool(cc.build_info["from_cache"]),
            "derivation_s": cc.derivation_seconds,
            "cse_s": float(cc.module.CSE_SECONDS),
            "generated_ops": int(cc.module.N_OPS),
            "cache_file": cc.build_info["path"],
        },
        "model": {"gvs": {}, "cc": {}},
    }
    # warm-up (numba compilation is cached on disk)
    for mdl in (gvs, cc):
        mdl.terms(q, qd)
        mdl.forward_dynamics(q, qd, u)
    simulate(gvs, q, qd, duration=h, dt=h, u=u)
    params = cc._params()
    pairs = {
        "forward_dynamics": (
            lambda: gvs.forward_dynamics(q, qd, u),
            lambda: cc.forward_dynamics(q, qd, u),
        ),
        "forward_dynamics_kernel": (
            lambda: K.forward_dynamics(q, qd, u, m, loads),
            lambda: cc.forward_dynamics_unchecked(q, qd, u, params),
        ),
        "terms": (lambda: gvs.terms(q, qd), lambda: cc.terms(q, qd)),
        "rk4_step": (lambda: rk4_step(gvs, q, qd, u, h), lambda: rk4_step(cc, q, qd, u, h)),
    }
    for key, (fg, fc) in pairs.items():
        nb = 25 if key == "rk4_step" else 100
        sg, sc = _paired((fg, fc), (8 * nb, nb), repeats)
        out["model"]["gvs"][key], out["model"]["cc"][key] = sg, sc
    out["model"]["gvs_numba_rk4_step"] = _stats(
        batch_times(lambda: K.rk4_run(q, qd, u, h, 1, 1, m, loads), 1000, repeats)
    )
    keys = tuple(pairs)
    out["model"]["ratio_cc_over_gvs"] = {
        k: out["model"]["cc"][k]["median_s"] / out["model"]["gvs"][k]["median_s"] for k in keys
    }
    out["model"]["ratio_cc_over_gvs_min"] = {
        k: out["model"]["cc"][k]["min_s"] / out["model"]["gvs"][k]["min_s"] for k in keys
    }
    # closed loop
    loops = {}
    closed_loop(gvs, gvs, duration=0.1, period=period, substeps=substeps)  # warm-up
    runs = {
        "gvs": TimedControlLoop(gvs, gvs, duration, period, substeps),
        "cc": TimedControlLoop(cc, gvs, duration, period, substeps),
        "gvs_numba_rk4": TimedControlLoop(gvs, gvs, duration, period, substeps, numba=True),
    }
    times = {k: [] for k in runs}
    for _ in range(int(round(duration / period))):
        for k, loop in runs.items():
            times[k].append(loop.step())
    for k in runs:
        loops[k] = _stats(times[k])
    loops["law"] = (
        "tdacm.control.TDACMController (adaptive, 10 % perturbed model) tracking a cubic joint "
        "trajectory from the paper's initial to its desired state"
    )
    loops["period_s"] = period
    loops["rk4_substeps"] = substeps
    loops["duration_s"] = duration
    for suffix, stat in (("", "median_s"), ("_min", "min_s")):
        loops["ratio_cc_over_gvs" + suffix] = loops["cc"][stat] / loops["gvs"][stat]
        loops["ratio_cc_over_gvs_numba" + suffix] = loops["cc"][stat] / loops["gvs_numba_rk4"][stat]
    loops["final_state_difference"] = float(np.abs(runs["gvs"].q - runs["cc"].q).max())
    loops["final_state_gvs"] = runs["gvs"].q.tolist()
    out["closed_loop"] = loops
    return out


# ---------------------------------------------------------------------------------- scaling
def scaling_study(orders=range(0, 9), gauss=(4, 8, 16), repeats=9, number=100) -> list:
    """GVS ``forward_dynamics`` (numba kernel and Python API) and ``terms`` for a floating rod
    with both bendings of order ``p`` (``n_s = 2 (p + 1)``), Zanna (order-4) Magnus steps.

    All systems are built first, then timed in ``repeats`` rounds that visit every system once
    (one batch of ``number`` calls each), so background load spreads over all of them."""
    cases = []
    for p in orders:
        for g in gauss:
            s = paper_system(basis=StrainBasis.bending(p), n_gauss=g, magnus_order=4)
            rng = np.random.default_rng(0)
            q = np.zeros(s.n)
            q[5] = 3.0
            q[6:] = rng.normal(size=s.n_s) * 0.2
            qd = rng.normal(size=s.n) * 0.1
            u = np.r_[np.full(4, s.total_mass * 9.81 / 4), np.zeros(4)]
            m, loads = s.model_arrays, s.loads.packed()
            fns = (
                partial(K.forward_dynamics, q, qd, u, m, loads),
                partial(s.forward_dynamics, q, qd, u),
                partial(s.terms, q, qd),
            )
            for fn in fns:
                fn()
            cases.append((p, g, s, fns))
    samples = [[[], [], []] for _ in cases]
    for _ in range(repeats):
        for c, (_, _, _, fns) in enumerate(cases):
            for i, fn in enumerate(fns):
                t0 = time.perf_counter()
                for _ in range(number):
                    fn()
                samples[c][i].append((time.perf_counter() - t0) / number)
    rows = []
    for (p, g, s, _), smp in zip(cases, samples, strict=True):
        kern, api, terms = (_stats(x) for x in smp)
        rows.append(
            {
                "order": int(p),
                "n_s": int(s.n_s),
                "n": int(s.n),
                "n_gauss": int(g),
                "fd_kernel_us": kern["median_s"] * 1e6,
                "fd_kernel_iqr_us": kern["iqr_s"] * 1e6,
                "fd_kernel_min_us": kern["min_s"] * 1e6,
                "fd_api_us": api["median_s"] * 1e6,
                "fd_api_min_us": api["min_s"] * 1e6,
                "terms_us": terms["median_s"] * 1e6,
                "terms_min_us": terms["min_s"] * 1e6,
            }
        )
    return rows


# ---------------------------------------------------------------------------------- accuracy
ACCURACY_CASES = {
    "swing": {
        "description": "clamped rod hanging down, released at rest from a constant-curvature "
        "bend k = [1.0, -0.6] 1/m, gravity only",
        "k0": (1.0, -0.6),
        "tensions": (0.0, 0.0, 0.0, 0.0),
        "tip_force": (0.0, 0.0, 0.0),
    },
    "loaded": {
        "description": "clamped rod hanging down, straight at rest; at t = 0 tendon 2 (+z) "
        "pulls with 3 N and a horizontal dead load [0.15, 0.05, 0] N acts on the tip",
        "k0": (0.0, 0.0),
        "tensions": (0.0, 3.0, 0.0, 0.0),
        "tip_force": (0.15, 0.05, 0.0),
    },
}


def _clamped(order, n_gauss, tip_force):
    loads = Loads(tip_force=np.asarray(tip_force, float))
    return paper_system(
        fixed_base_pose=np.eye(4),
        basis=StrainBasis.bending(order),
        n_gauss=n_gauss,
        magnus_order=4,
        loads=loads,
    )


def _q0(order, k0):
    q = np.zeros(2 * (order + 1))
    q[0], q[order + 1] = k0  # Legendre P0 coefficient of each bending = the mean curvature
    return q


def _tips(model, qs):
    return np.array([model.tip_pose(q)[:3, 3] for q in qs])


def _reference_run(model, q0, u, duration, record_dt, refine):
    """Numba RK4 at ``suggested_dt / refine`` rounded down to divide ``record_dt``."""
    dt = model.suggested_dt() / refine
    dt = record_dt / int(np.ceil(record_dt / dt))
    return simulate(model, q0, None, duration, dt=dt, u=u, record_dt=record_dt), dt


def _gauss_for(order):
    return max(5, 2 * order + 2)


def accuracy_study(
    duration=1.5, record_dt=0.01, dt=0.005, ref_order=7, ref_gauss=16, orders=(0, 1, 2, 3)
) -> dict:
    """Tip position error against a converged GVS reference (fine-step RK4)."""
    if abs(record_dt / dt - round(record_dt / dt)) > 1e-9:
        raise ValueError("dt must divide record_dt")
    out = {
        "duration_s": duration,
        "record_dt_s": record_dt,
        "rk4_dt_s": dt,
        "reference": f"GVS, both bendings of order {ref_order} (n_s = {2 * ref_order + 2}), "
        f"{ref_gauss} Gauss points, Magnus order 4, numba RK4 at a quarter of its stable step; "
        "self-check: one order and four Gauss points more at an eighth of its step",
        "candidates_gauss": {str(p): _gauss_for(p) for p in orders},
        "cases": {},
    }
    every = int(round(record_dt / dt))
    nsteps = int(round(duration / dt))
    for case, spec in ACCURACY_CASES.items():
        u = np.asarray(spec["tensions"], float)
        res = {"description": spec["description"], "models": {}}
        # reference (numba RK4 at a quarter of its stable step) and its own convergence check
        # (one order and four Gauss points more, half that step)
        t0 = time.perf_counter()
        ref = _clamped(ref_order, ref_gauss, spec["tip_force"])
        r, ref_dt = _reference_run(ref, _q0(ref_order, spec["k0"]), u, duration, record_dt, 4)
        ref_tip = _tips(ref, r.q)
        res["reference_wall_s"] = time.perf_counter() - t0
        res["reference_dt_s"] = ref_dt
        chk = _clamped(ref_order + 1, ref_gauss + 4, spec["tip_force"])
        rc, _ = _reference_run(chk, _q0(ref_order + 1, spec["k0"]), u, duration, record_dt, 8)
        res["reference_self_error_m"] = float(
            np.linalg.norm(_tips(chk, rc.q) - ref_tip, axis=1).max()
        )
        res["t"] = r.t.tolist()
        res["reference_tip"] = ref_tip.tolist()
        tip_travel = float(np.linalg.norm(ref_tip - ref_tip[0], axis=1).max())
        res["reference_tip_travel_m"] = tip_travel
        models = [("CC", None)] + [(f"GVS-{p}", p) for p in orders]
        for name, p in models:
            if p is None:
                gsys = _clamped(0, 5, spec["tip_force"])
                mdl = CCLagrangian.from_system(gsys)
                q = np.asarray(spec["k0"], float)
            else:
                mdl = _clamped(p, _gauss_for(p), spec["tip_force"])
                q = _q0(p, spec["k0"])
            qd = np.zeros_like(q)
            mdl.forward_dynamics(q, qd, u)
            fd = _stats(
                batch_times(lambda mdl=mdl, q=q, qd=qd, u=u: mdl.forward_dynamics(q, qd, u), 200, 5)
            )
            # same Python-level RK4 for every model
            t0 = time.perf_counter()
            qs = [q.copy()]
            for k in range(nsteps):
                q, qd = rk4_step(mdl, q, qd, u, dt)
                if (k + 1) % every == 0:
                    qs.append(q.copy())
            wall = time.perf_counter() - t0
            tip = _tips(mdl, qs)
            n = min(len(tip), len(ref_tip))
            err = np.linalg.norm(tip[:n] - ref_tip[:n], axis=1)
            row = {
                "n_s": int(q.size),
                "n_gauss": 5 if p is None else _gauss_for(p),
                "fd_us": fd["median_s"] * 1e6,
                "sim_wall_python_rk4_s": wall,
                "max_error_m": float(err.max()),
                "rms_error_m": float(np.sqrt(np.mean(err**2))),
                "final_error_m": float(err[-1]),
                "error_m": err.tolist(),
            }
            if p is not None:
                t0 = time.perf_counter()
                simulate(mdl, _q0(p, spec["k0"]), None, duration, dt=dt, u=u)
                row["sim_wall_numba_rk4_s"] = time.perf_counter() - t0
            res["models"][name] = row
        out["cases"][case] = res
    return out


# ---------------------------------------------------------------------------------- PyElastica
def _dist_version(name):
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "?"


def _arc_frames(k0, s):
    """Rotations ``R(s)`` (k, 3, 3) and positions (k, 3) of the swing case's initial arc
    (clamp at the identity, default attachment), from the GVS order-0 model."""
    model = _clamped(0, 5, (0.0, 0.0, 0.0))
    q = np.asarray(k0, float)
    poses = np.array([model.pose(q, si) for si in s])
    return poses[:, :3, :3], poses[:, :3, 3]


def pyelastica_study(duration=1.0, n_elements=50, dt=5e-7, reference=None) -> dict:
    """The swing case in PyElastica (optional extra): wall time to simulate ``duration`` and
    tip agreement with the GVS reference (``reference`` = the swing case of
    :func:`accuracy_study`, whose reference tip is compared every ``record_dt``).

    PyElastica rod: ``n_elements`` elements, the paper's material (shear modulus from
    ``nu = 0.33``), gravity, the tip mass added to the last node, no damping, position Verlet
    at ``dt``; the initial shape is the same constant-curvature arc (nodes on the arc, element
    directors = section frames at the element midpoints, director rows ``[y, z, x]`` of the
    local frame).  The clamp (``OneEndFixedBC``) holds node 0 and element 0, i.e. the frame at
    ``s = ds/2``: a clamp rotated by ``kappa ds/2`` against the GVS one, an ``O(ds)`` offset.
    The explicit stepper needs ``dt`` of about 5e-7 s for this stiff, thin Nitinol rod (its
    shear-rotation mode, ``omega^2 ~ G A / (rho I)``, does not soften with coarser elements);
    2.5e-6 s diverges.
    """
    try:
        import elastica as ea
    except ImportError:
        return {"skipped": "pyelastica is not installed (optional extra: pip install pyelastica)"}
    spec = ACCURACY_CASES["swing"]
    rod_p = paper_system().rod
    length, radius = rod_p.length, rod_p.diameter / 2
    shear = rod_p.youngs_modulus / (2 * (1 + rod_p.poisson_ratio))

    class _Sim(ea.BaseSystemCollection, ea.Constraints, ea.Forcing):
        pass

    sim = _Sim()
    rod = ea.CosseratRod.straight_rod(
        n_elements,
        np.zeros(3),
        np.array([0.0, 0.0, -1.0]),
        np.array([1.0, 0.0, 0.0]),
        length,
        radius,
        rod_p.density,
        youngs_modulus=rod_p.youngs_modulus,
        shear_modulus=shear,
    )
    ds = length / n_elements
    s_nodes = np.linspace(0.0, length, n_elements + 1)
    s_mid = (np.arange(n_elements) + 0.5) * ds
    _, p_nodes = _arc_frames(spec["k0"], s_nodes)
    r_mid, _ = _arc_frames(spec["k0"], s_mid)
    p0 = p_nodes[0].copy()
    rod.position_collection[:] = (p_nodes - p0).T
    for k in range(n_elements):
        rr = r_mid[k]
        rod.director_collection[:, :, k] = np.vstack([rr[:, 1], rr[:, 2], rr[:, 0]])
    rod.mass[-1] += rod_p.tip_mass
    sim.append(rod)
    sim.constrain(rod).using(
        ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,)
    )
    sim.add_forcing_to(rod).using(ea.GravityForces, acc_gravity=np.array([0.0, 0.0, -9.81]))
    sim.finalize()
    stepper = ea.PositionVerlet()
    record_dt = 0.01 if reference is None else float(reference.get("record_dt_s", 0.01))
    per = int(round(record_dt / dt))
    nrec = int(round(duration / record_dt))
    tips = [rod.position_collection[:, -1] + p0]
    t = 0.0
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):  # integrate() prints the final time
        for _ in range(nrec):
            t = ea.integrate(stepper, sim, record_dt, per, restart_time=t, progress_bar=False)
            tips.append(rod.position_collection[:, -1] + p0)
    wall = time.perf_counter() - t0
    tips = np.array(tips)
    out = {
        "version": _dist_version("pyelastica"),
        "n_elements": n_elements,
        "dt_s": dt,
        "duration_s": duration,
        "wall_s": wall,
        "finite": bool(np.all(np.isfinite(tips))),
        "tip": tips.tolist(),
    }
    if not out["finite"]:
        out["tip"] = None
        out["note"] = (
            "unstable: reduce dt (the shear-rotation mode of this stiff, thin rod needs about 5e-7 s)"
        )
    elif reference is not None:
        ref = np.asarray(reference["reference_tip"])[: len(tips)]
        err = np.linalg.norm(tips[: len(ref)] - ref, axis=1)
        out["max_error_m"] = float(err.max())
        out["rms_error_m"] = float(np.sqrt(np.mean(err**2)))
        out["error_m"] = err.tolist()
    return out


# ---------------------------------------------------------------------------------- output
def plot_scaling(rows, path, cc_fd_s=None) -> None:
    """Time of one GVS forward-dynamics call against the strain DoFs, one line per Gauss
    count (medians of batches interleaved over all systems)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for i, g in enumerate(sorted({r["n_gauss"] for r in rows})):
        sel = [r for r in rows if r["n_gauss"] == g]
        ns = [r["n_s"] for r in sel]
        color = f"C{i}"
        ax.plot(ns, [r["fd_kernel_us"] for r in sel], "o-", color=color, label=f"kernel, {g} Gauss")
        ax.plot(
            ns,
            [r["fd_api_us"] for r in sel],
            "x--",
            color=color,
            alpha=0.6,
            label=f"Python API, {g} Gauss",
        )
    if cc_fd_s is not None:
        ax.plot([2], [cc_fd_s * 1e6], "k*", ms=12, label="CC baseline (n_s = 2)")
    ax.set_xlabel("strain DoFs n_s (both bendings, order n_s/2 - 1; + 6 drone DoFs)")
    ax.set_ylabel("forward dynamics [us]")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("GVS cost vs strain DoFs and quadrature points")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_accuracy(acc, path, elastica=None) -> None:
    """Tip position error against the converged reference, per case (plus PyElastica on the
    swing case when ``elastica`` holds its errors)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = acc["cases"]
    fig, axes = plt.subplots(1, len(cases), figsize=(6.0 * len(cases), 4.0), squeeze=False)
    for ax, (case, res) in zip(axes[0], cases.items(), strict=True):
        t = np.asarray(res["t"])
        order = [k for k in res["models"] if k != "CC"] + ["CC"]  # CC on top of GVS-0
        for name in order:
            row = res["models"][name]
            err = np.asarray(row["error_m"])[1:]  # t = 0: same initial state, zero error
            kw = {"color": "k", "ls": "--", "lw": 1.2} if name == "CC" else {"lw": 1.2}
            label = f"{name} ({row['fd_us']:.0f} us/call)" + (" = GVS-0" if name == "CC" else "")
            ax.semilogy(t[1 : err.size + 1], np.maximum(err, 1e-9) * 1e3, label=label, **kw)
        ax.axhline(
            res["reference_self_error_m"] * 1e3,
            color="gray",
            lw=0.8,
            ls=":",
            label="reference self-check",
        )
        if case == "swing" and elastica and "error_m" in elastica:
            err = np.asarray(elastica["error_m"])[1:]
            ax.semilogy(
                t[1 : err.size + 1],
                np.maximum(err, 1e-9) * 1e3,
                color="gray",
                lw=1.0,
                label=f"PyElastica ({elastica['n_elements']} elements)",
            )
        ax.set_title(case)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("tip position error [mm]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def print_report(timing, scaling, accuracy, elastica) -> None:
    """Terminal tables."""
    b = timing["cc_build"]
    report.info(
        f"\nCC baseline code: {b['generated_ops']} operations after CSE; symbolic derivation "
        f"{b['derivation_s']:.1f} s + CSE {b['cse_s']:.1f} s when generated; this build "
        f"{b['first_call_s']:.2f} s ({'cache' if b['from_cache'] else 'derived now'})"
    )
    m = timing["model"]
    report.info(f"\nPer call / step, {timing['system']} (median +- IQR, us):")
    report.info(f"{'':26s} {'GVS':>16s} {'CC':>18s} {'CC/GVS':>7s} {'(min)':>6s}")
    for k in ("forward_dynamics", "forward_dynamics_kernel", "terms", "rk4_step"):
        g, c = m["gvs"][k], m["cc"][k]
        report.info(
            f"{k + (' (Python RK4)' if k == 'rk4_step' else ''):26s} {g['median_s'] * 1e6:9.1f} +- {g['iqr_s'] * 1e6:4.1f}"
            f" {c['median_s'] * 1e6:10.1f} +- {c['iqr_s'] * 1e6:5.1f} {m['ratio_cc_over_gvs'][k]:7.1f}"
            f" {m['ratio_cc_over_gvs_min'][k]:6.1f}"
        )
    report.info(f"{'rk4_step (numba GVS)':26s} {m['gvs_numba_rk4_step']['median_s'] * 1e6:9.1f}")
    cl = timing["closed_loop"]
    report.info(
        f"\nClosed loop, {1 / cl['period_s']:.0f} Hz, {cl['rk4_substeps']} RK4 substeps, "
        f"{cl['duration_s']} s ({cl['law']}); per iteration (ms):"
    )
    for name, key in (
        ("GVS, Python RK4", "gvs"),
        ("CC,  Python RK4", "cc"),
        ("GVS, numba RK4", "gvs_numba_rk4"),
    ):
        r = cl[key]
        report.info(
            f"  {name:18s} median {r['median_s'] * 1e3:7.3f}  IQR {r['iqr_s'] * 1e3:6.3f}  "
            f"mean {r['mean_s'] * 1e3:7.3f} +- {r['std_s'] * 1e3:6.3f}  min {r['min_s'] * 1e3:7.3f}"
        )
    report.info(
        f"  CC/GVS medians (minima): {cl['ratio_cc_over_gvs']:.1f} ({cl['ratio_cc_over_gvs_min']:.1f}) "
        f"same integrator, {cl['ratio_cc_over_gvs_numba']:.1f} ({cl['ratio_cc_over_gvs_numba_min']:.1f}) "
        "GVS with its numba RK4; "
        f"final states differ by {cl['final_state_difference']:.2e}"
    )
    report.info(
        "\nGVS forward dynamics vs strain DoFs (floating, numba kernel, median of interleaved batches, us):"
    )
    gauss = sorted({r["n_gauss"] for r in scaling})
    report.info(f"{'n_s':>4s} " + " ".join(f"{g:>6d}G" for g in gauss))
    for ns in sorted({r["n_s"] for r in scaling}):
        vals = {r["n_gauss"]: r["fd_kernel_us"] for r in scaling if r["n_s"] == ns}
        report.info(f"{ns:4d} " + " ".join(f"{vals[g]:7.1f}" for g in gauss))
    report.info(
        f"\nAccuracy (clamped rod, {accuracy['duration_s']} s, Python RK4 dt = {accuracy['rk4_dt_s']} s):"
    )
    for case, res in accuracy["cases"].items():
        report.info(
            f"  {case}: {res['description']}\n    reference self-check {res['reference_self_error_m'] * 1e3:.3f} mm, "
            f"tip travel {res['reference_tip_travel_m']:.3f} m"
        )
        report.info(
            f"    {'model':6s} {'n_s':>3s} {'fd us':>7s} {'max mm':>8s} {'rms mm':>8s} {'final mm':>8s}"
        )
        for name, row in res["models"].items():
            report.info(
                f"    {name:6s} {row['n_s']:3d} {row['fd_us']:7.1f} {row['max_error_m'] * 1e3:8.2f} "
                f"{row['rms_error_m'] * 1e3:8.2f} {row['final_error_m'] * 1e3:8.2f}"
            )
    if "skipped" in elastica:
        report.info(f"\nPyElastica: {elastica['skipped']}")
    else:
        line = (
            f"\nPyElastica {elastica['version']}: swing case, {elastica['n_elements']} elements, "
            f"position Verlet dt = {elastica['dt_s']:g} s: {elastica['duration_s']} s simulated in "
            f"{elastica['wall_s']:.1f} s"
        )
        if "max_error_m" in elastica:
            line += (
                f"; tip vs GVS reference: max {elastica['max_error_m'] * 1e3:.2f} mm, "
                f"RMS {elastica['rms_error_m'] * 1e3:.2f} mm"
            )
        report.info(line)
