"""Plant + sensors + estimator, without the visual loop (the estimation benchmark and tests).

The plant is the true paper system integrated with :func:`tdacm.system.kernels.rk4_run`; its
input comes from the project's low-level controller acting on the *true* state (the loop under
test is the estimator alone), tracking a drone hover with strain steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..control import EstimatedModel, TDACMController, default_gains
from ..estimation import EstimatorConfig, ExtendedKalmanFilter, SensorSuite, SensorSuiteConfig
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
