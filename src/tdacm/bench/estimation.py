"""Plant + sensors + estimator, without the visual loop (the estimation benchmark and tests).

The plant is the true paper system integrated with :func:`tdacm.system.kernels.rk4_run`; its
input comes from the project's low-level controller acting on the *true* state (the loop under
test is the estimator alone), tracking a drone hover with strain steps.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..control import EstimatedModel, TDACMController, default_gains
from ..estimation import EstimatorConfig, ExtendedKalmanFilter, SensorSuite, SensorSuiteConfig
from ..estimation import ekf_step as ES
from ..estimation import kernels as EK
from ..estimation.camera import TargetViewMeasurement
from ..system import kernels as K
from ..system.paper import paper_system

Q0 = np.array([0.0, 0.0, 0.17453292519943295, -0.5, 0.5, 5.0, -0.3, -0.4])


@dataclass
class Run:
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    q_hat: np.ndarray
    qd_hat: np.ndarray
    P: np.ndarray  # (k, 2n, 2n)
    timings: np.ndarray
    estimator: ExtendedKalmanFilter


def strain_reference(t):
    """Hover at the initial drone pose; strains step at 0.5 s and 1.5 s."""
    if t < 0.5:
        return np.array([-0.3, -0.4])
    if t < 1.5:
        return np.array([0.2, -0.1])
    return np.array([-0.1, 0.3])


def run(
    seed=0,
    duration=2.0,
    dt=0.02,
    substeps=4,
    strain_error=0.3,
    sensors: SensorSuiteConfig | None = None,
    config: EstimatorConfig | None = None,
    drop=None,
    level=0.1,
    q0=Q0,
    camera=None,
):
    """One seeded run. ``drop(t) -> set of sensor names`` withholds those sensors' output.
    ``camera = (TargetCamera, target_pose, pixel_sigma_normalized)`` also feeds the filter the
    tip camera's view of a static target (exact projection plus seeded noise, every period)."""
    s = paper_system()
    n = s.n
    model = EstimatedModel(s, level, seed)
    ctl = TDACMController(s, EstimatedModel(s, level, seed), default_gains(s, q0))
    suite = SensorSuite(s, sensors, seed)
    est = ExtendedKalmanFilter(
        model, suite.config, config, camera=None if camera is None else camera[0]
    )
    view_rng = np.random.default_rng([seed, 77])
    q, qd = np.asarray(q0, float).copy(), np.zeros(n)
    loads = s.loads.packed().copy()
    meas = suite.sample(0.0, q, qd, np.zeros(n))
    guess = q.copy()
    guess[6:] += strain_error
    est.reset(guess, t0=0.0)
    e = est.step(0.0, None, [m for m in meas if type(m).__name__ != "ImuMeasurement"])
    out = {k: [] for k in ("t", "q", "qd", "q_hat", "qd_hat", "P")}
    nsteps = int(round(duration / dt))
    u_prev = None
    for k in range(nsteps + 1):
        t = k * dt
        if k > 0:
            qdd, _ = K.forward_dynamics(q, qd, u_prev, s.model_arrays, loads)
            meas = suite.sample(t, q, qd, qdd)
            if camera is not None:
                meas.append(target_view(s, q, *camera, view_rng, t))
            if drop is not None:
                gone = drop(t)
                meas = [m for m in meas if _name(m) not in gone]
            e = est.step(t, u_prev, meas)
        out["t"].append(t)
        out["q"].append(q.copy())
        out["qd"].append(qd.copy())
        out["q_hat"].append(e.q)
        out["qd_hat"].append(e.qd)
        out["P"].append(e.P)
        if k == nsteps:
            break
        q_d = q0.copy()
        q_d[:2] = 0.0
        q_d[6:] = strain_reference(t)
        cs = ctl.step(q, qd, q_d, np.zeros(n), np.zeros(n), dt)
        u_prev = cs.u
        qs_, qds_, ok = K.rk4_run(
            q, qd, cs.u, dt / substeps, substeps, substeps, s.model_arrays, loads
        )
        assert ok
        q, qd = qs_[-1].copy(), qds_[-1].copy()
    a = {k: np.asarray(v) for k, v in out.items()}
    return Run(
        a["t"], a["q"], a["qd"], a["q_hat"], a["qd_hat"], a["P"], np.asarray(est.timings), est
    )


def target_view(system, q, cam, target_pose, sigma, rng, t):
    """C_L's view of the target at the true ``q``: normalized points plus N(0, sigma^2)."""
    g_c = system.tip_pose(q) @ cam.tip_mount
    pw = cam.object_points @ target_pose[:3, :3].T + target_pose[:3, 3]
    c = (pw - g_c[:3, 3]) @ g_c[:3, :3]
    z = c[:, :2] / c[:, 2:]
    return TargetViewMeasurement(t, z + rng.normal(0.0, sigma, z.shape))


def target_below(system, q, cam, depth=1.5):
    """A level target (z axis down, its face up) ``depth`` m along C_L's axis at ``q``."""
    g_c = system.tip_pose(q) @ cam.tip_mount
    g = np.eye(4)
    g[:3, :3] = np.diag([1.0, -1.0, -1.0])
    g[:3, 3] = g_c[:3, 3] + depth * g_c[:3, 2]
    return g


def _name(m):
    return {
        "PoseMeasurement": "pose",
        "ImuMeasurement": "imu",
        "EncoderMeasurement": "encoders",
        "TargetViewMeasurement": "camera",
    }[type(m).__name__]


def nees(r: Run):
    """Normalized estimation error squared of [q, qd] at every step."""
    err = np.concatenate([r.q_hat - r.q, r.qd_hat - r.qd], axis=1)
    return np.array([e @ np.linalg.solve(p, e) for e, p in zip(err, r.P, strict=True)])


@njit
def _time_model(p, m, x, u, reps):
    acc = 0.0
    for _ in range(reps):
        acc += ES.model_acceleration(p, m, x, u)[0][0]
    return acc


@njit
def _time_linearize(p, m, x, u, reps):
    n, acc = p.n, 0.0
    for _ in range(reps):
        acc += EK.linearize(x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], m, p.loads, p.mass_scale,
                            p.damping_scale, p.stiffness_scale, p.gravity_scale, p.rotor_drag,
                            p.skip)[1][0, 0]  # fmt: skip
    return acc


@njit
def _time_propagate(p, m, x, u, dt, reps):
    n, acc = p.n, 0.0
    for _ in range(reps):
        acc += EK.propagate_mean(x[:n], x[n : 2 * n], u, x[2 * n : 3 * n], dt, p.rk4_steps, m,
                                 p.loads, p.mass_scale, p.damping_scale, p.stiffness_scale,
                                 p.gravity_scale, p.rotor_drag)[0][0]  # fmt: skip
    return acc


@njit
def _time_covariance(a, qc, cov, dt, reps):
    acc = 0.0
    for _ in range(reps):
        phi = EK.transition(a, dt)
        acc += (phi @ cov @ phi.T + EK.discrete_noise(a, qc, dt))[0, 0]
    return acc


def filter_parts(repeats: int = 3, seed: int = 0) -> dict:
    """Microseconds per call of the EKF's prediction parts (:mod:`tdacm.estimation.ekf_step`)
    on `paper-in-fov`'s filter (n = 8, default sensors, 10 % model error) at hover thrust,
    each called in a compiled loop (best of ``repeats``): the process model's acceleration
    (``model_acceleration``: the perturbed ``M``, ``C``, ``D``, ``K``, ``B(q) u`` and a
    Cholesky solve), its forward-difference Jacobian (``linearize``: one evaluation per
    column that the dynamics depend on, plus one), the RK4 mean (``propagate_mean``) and the
    covariance's ``Phi``, ``Q`` and ``Phi P Phi^T``. ``evaluations``: the model evaluations
    a period makes (the Jacobian's and RK4's)."""
    from ..sim import build_loop, load_scenario

    sc = load_scenario("paper-in-fov").with_overrides(
        {"estimation": {"source": "estimated"}}, "filter parts"
    )
    f = build_loop(sc, seed=seed).loop.estimator.filter
    p, m = f.params, f.model_arrays
    n, dt = p.n, 0.02
    x = np.zeros(p.nx)
    x[:n] = Q0
    u = np.zeros(p.n_u)
    u[:4] = f.system.total_mass * 9.81 / 4.0
    a = np.zeros((p.nx, p.nx))
    a[:n, n : 2 * n] = np.eye(n)
    a[n : 2 * n, : 2 * n] = np.random.default_rng(seed).normal(size=(n, 2 * n))
    cov = np.eye(p.nx)
    parts = {
        "model_acceleration": (_time_model, (p, m, x, u), 2000),
        "linearize": (_time_linearize, (p, m, x, u), 200),
        "propagate_mean": (_time_propagate, (p, m, x, u, dt), 500),
        "covariance": (_time_covariance, (a, p.qc, cov, dt), 500),
    }
    out = {}
    for name, (fn, args, reps) in parts.items():
        fn(*args, 1)  # compiles
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn(*args, reps)
            times.append(1e6 * (time.perf_counter() - t0) / reps)
        out[name + "_us"] = min(times)
    out["evaluations"] = int(1 + 2 * n - int(np.sum(p.skip)) + 4 * p.rk4_steps)
    return out
