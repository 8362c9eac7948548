"""Excitation experiments a lab can run, and the synthetic recordings they give.

Six documented experiments (``EXPERIMENTS``; ``docs/identify.md`` says what each identifies):

* ``tendon-steps`` (clamped rod, the robot of ``ground-test-a``): 20 s of tension steps, a new
  step every 2 s (0.5 s rise) on one tendon or two neighbouring ones, levels 1.5-6 N; the
  largest swing the rod past the horizontal, where the gravity moment is far from linear in
  the curvature;
* ``tendon-steps-loaded``: the same with a known 20 g clip-on mass at the tip
  (:data:`CALIBRATION_MASS`, recorded in ``Recording.added``): the known mass fixes the common
  scale of ``E``, damping, tip mass and moment arm that one clamped experiment leaves loose;
* ``tendon-chirp`` (clamped rod): 20 s of antagonistic tension chirps, ``2 +- 0.5 N`` on the pairs
  (0, 2) and (1, 3), 0.1 -> 2.5 Hz (a quarter period apart), across the rod's first bending
  mode (0.8 Hz for the paper robot);
* ``hover`` (flying): 10 s of hover under a PID position / PD attitude controller (nominal
  values, as the lab's controller knows them), with collective-thrust steps (0.4-0.75 N up or
  down every 1.5 s), body-torque chirps (0.03 N m, 0.2 -> 2 Hz) and tendon steps (0-4 N);
* ``camera-chirp`` (clamped rod): the chirps at ``2 +- 0.12 N``, small enough that the target
  of ``ground-test-a`` stays in the tip camera's view (for the camera-alone study);
* ``held-out`` (clamped rod): 5 s from rest of two tension sines (0.7 and 1.9 Hz) over a ramp
  on tendons 0 and 1: not used for fitting, only to validate a fitted model's prediction.

:func:`synthesize` runs an experiment on the robot with hidden "true" parameters
(:data:`DEFAULT_TRUTH` unless given) and records what a lab measures, with the noise of
:data:`NOISE`: motion capture of the drone and the tip (0.5 mm per position axis, 0.1 deg per
rotation axis, white, at 100 Hz), load cells with 2 % (1 sigma) multiplicative white noise on
each tension; the thrust commands are recorded exactly (they are commands). The integration
runs at a quarter of the sample period (2.5 ms) so the fit's 10 ms model is not the generator.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..sim import parse_scenario
from .data import Recording, matrix_to_pose7, model_of_scenario

log = logging.getLogger(__name__)

#: Measurement noise of the synthetic recordings (1 sigma, white).
NOISE = {
    "position": 0.5e-3,  # m, per axis (motion capture)
    "rotation_deg": 0.1,  # deg, per axis (motion capture)
    "tension": 0.02,  # relative (load cells)
    "pixel": 1.0,  # px, per coordinate (tip camera)
}

#: The hidden parameters of the synthetic example. The fit's nominal start is the paper's robot
#: (E 5e10 Pa, tip mass 10 g, radius 10 mm, drone 0.7331 kg) with the damping of
#: :data:`PRIOR_DAMPING`: the paper's 100 Pa s damps the first bending mode by a ratio of
#: 1e-8 (no visible decay, nothing to identify); a real backbone with its tendons and guides
#: damps it by a few percent: 3.1e8 Pa s is 2 % of critical for the paper robot.
DEFAULT_TRUTH = {
    "E": 4.3e10,
    "damping": 3.1e8,
    "tip_mass": 0.0117,
    "radius": 0.0093,
    "drone_mass": 0.7685,
}

#: The lab's prior guess of the rod damping (Pa s) written into the synthetic recordings'
#: scenario (1.5 % of critical; the paper's 100 Pa s has no measurable effect).
PRIOR_DAMPING = 2.3e8

SAMPLE_DT = 0.01
GENERATOR_SUBSTEPS = 4


@dataclass(frozen=True)
class Experiment:
    """``scenario``: the shipped scenario whose robot runs it; ``profile(t, rng)`` the (T, n_a)
    tensions (clamped) or ``None`` for the controlled hover; ``q0`` the start (at rest)."""

    name: str
    scenario: str
    duration: float
    doc: str
    profile: Callable | None = None
    q0: tuple = ()
    added: tuple = ()  # known additions to parameters: (("tip_mass", 0.02),)


def _steps(t: np.ndarray, rng) -> np.ndarray:
    u = np.zeros((len(t), 4))
    hold = 2.0
    for k in range(int(np.ceil(t[-1] / hold)) + 1):
        sl = (t >= k * hold) & (t < (k + 1) * hold)
        if k == 0:
            continue  # 2 s at rest: the static hanging state
        i = int(rng.integers(4))
        u[sl, i] = float(rng.choice(STEP_LEVELS))
        if rng.random() < 0.4:
            u[sl, (i + 1) % 4] = float(rng.choice(STEP_LEVELS[:2]))
    # each step rises over STEP_RISE seconds (a moving average): large deflections with
    # less overshoot than a sharp step
    w = max(1, int(round(STEP_RISE / (t[1] - t[0]))))
    pad = np.vstack([np.repeat(u[:1], w - 1, axis=0), u])
    c = np.cumsum(np.vstack([np.zeros((1, 4)), pad]), axis=0)
    return (c[w:] - c[:-w]) / w


#: The known clip-on mass of ``tendon-steps-loaded`` (kg).
CALIBRATION_MASS = 0.02

#: Tension levels of the steps (N) and their rise time (s).
STEP_LEVELS = (1.5, 3.0, 4.5, 6.0)
STEP_RISE = 0.5


#: Amplitude of the tension chirps (N) around a 2 N pretension.
CHIRP = 0.5
#: The same for the tip-camera experiment: small enough that the target stays in C_L's view.
CAMERA_CHIRP = 0.12


def _chirp(t, f0, f1, duration):
    return np.sin(2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / duration * t**2))


def _chirps(t: np.ndarray, rng) -> np.ndarray:
    d = t[-1] + (t[1] - t[0])
    a = _chirp(t, 0.1, 2.5, d)
    b = _chirp(t + 0.25 / 0.8, 0.1, 2.5, d)
    return np.column_stack([2 + CHIRP * a, 2 + CHIRP * b, 2 - CHIRP * a, 2 - CHIRP * b])


def _camera_chirps(t: np.ndarray, rng) -> np.ndarray:
    d = t[-1] + (t[1] - t[0])
    a = _chirp(t, 0.1, 2.5, d)
    b = _chirp(t + 0.25 / 0.8, 0.1, 2.5, d)
    c = CAMERA_CHIRP
    return np.column_stack([2 + c * a, 2 + c * b, 2 - c * a, 2 - c * b])


def _held_out(t: np.ndarray, rng) -> np.ndarray:
    ramp = np.minimum(t / 2.0, 1.0)
    u0 = 1.5 * ramp + 1.0 * (1 + np.sin(2 * np.pi * 0.7 * t))
    u1 = 1.0 * ramp + 1.0 * (1 + np.sin(2 * np.pi * 1.9 * t + 1.0))
    return np.column_stack([u0, u1, np.zeros_like(t), np.zeros_like(t)])


EXPERIMENTS = {
    e.name: e
    for e in (
        Experiment("tendon-steps", "ground-test-a", 20.0, "clamped rod, tension steps", _steps),
        Experiment(
            "tendon-steps-loaded",
            "ground-test-a",
            20.0,
            "clamped rod, tension steps, a known 20 g clip-on mass at the tip",
            _steps,
            (),
            (("tip_mass", CALIBRATION_MASS),),
        ),
        Experiment("tendon-chirp", "ground-test-a", 20.0, "clamped rod, tension chirps", _chirps),
        Experiment(
            "hover",
            "flight-test-c",
            10.0,
            "hover with thrust and torque excitation",
            None,
            (0.0, 0.0, 0.0, 0.0, 0.0, 2.6, 0.0, 0.0),
        ),
        Experiment(
            "camera-chirp",
            "ground-test-a",
            20.0,
            "clamped rod, small tension chirps keeping the target in the tip camera's view",
            _camera_chirps,
        ),
        Experiment("held-out", "ground-test-a", 5.0, "validation: sines over a ramp", _held_out),
    )
}


def scenario_text(exp: Experiment, basis: str | None = None) -> str:
    """The scenario of a synthetic recording: the experiment's shipped scenario with the
    lab's prior rod damping (:data:`PRIOR_DAMPING`); ``basis`` replaces the scenario's strain
    basis (the hidden robot of :func:`synthesize`)."""
    from .. import __file__ as pkg

    text = (Path(pkg).parent / "scenarios" / f"{exp.scenario}.toml").read_text()
    text = (
        text.rstrip()
        + "\n\n# the lab's prior guess of the backbone's damping (identification start)\n"
        + f"[robot.rod]\ndamping = {PRIOR_DAMPING:g}\n"
    )
    if basis is None:
        return text
    import tomllib

    import tomli_w

    from ..sim.robot import parse_basis

    data = tomllib.loads(text)
    data["robot"]["rod"]["basis"] = basis
    ns = parse_basis(basis).n
    for key in ("initial", "desired"):  # strains of the scenario's basis: straight instead
        if "q" in data.get(key, {}):
            data[key]["q"] = [0.0] * ns
    data.pop("expect", None)
    return tomli_w.dumps(data)


def experiment(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[name]


#: Gains of the hover experiment's controller (position: 1/s^2, 1/s, 1/s^3; attitude).
GAINS = {"kp": 4.0, "kd": 3.0, "ki": 1.0, "kp_att": 60.0, "kd_att": 14.0}


def _hover_controller(model, q_ref):
    """A PD position/attitude controller with the nominal mass and inertia (what the lab's
    controller knows), returning the four thrusts."""
    s = model.system
    mass = s.total_mass
    inertia = np.asarray(s.base.inertia)
    gam = s.base.gamma[[0, 1, 2, 5]]
    g = 9.81

    state = {"iz": 0.0, "dt": 0.01}

    def control(q, qd):
        p, v = q[3:6], qd[3:6]
        ez = q_ref[5] - p[2]
        state["iz"] += ez * state["dt"]
        a = GAINS["kp"] * (q_ref[3:6] - p) - GAINS["kd"] * v
        a[2] += GAINS["ki"] * state["iz"]
        f = mass * (g + a[2]) / (np.cos(q[0]) * np.cos(q[1]))
        att_d = np.array([-a[1] / g, a[0] / g, 0.0])
        tau = inertia * (GAINS["kp_att"] * (att_d - q[:3]) - GAINS["kd_att"] * qd[:3])
        return np.linalg.solve(gam, np.r_[tau, f])

    return control


def _hover_excitation(t: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """(T, 4) wrench excitation ``[tau_x, tau_y, tau_z, f]`` and (T, 4) tensions."""
    d = t[-1] + (t[1] - t[0])
    ex = np.zeros((len(t), 4))
    for k in range(int(np.ceil(d / 1.5))):
        sl = (t >= k * 1.5) & (t < (k + 1) * 1.5)
        ex[sl, 3] = float(rng.choice([-0.75, -0.4, 0.4, 0.75]))
    for i, ph in enumerate((0.0, 1.0, 2.0)):
        ex[:, i] = 0.03 * _chirp(t + ph, 0.2, 2.0, d)
    ten = np.zeros((len(t), 4))
    for k in range(int(np.ceil(d / 2.5))):
        sl = (t >= k * 2.5) & (t < (k + 1) * 2.5)
        ten[sl, int(rng.integers(4))] = float(rng.choice([1.0, 2.0, 4.0]))
    return ex, ten


def synthesize(
    name: str,
    out=None,
    truth: dict | None = None,
    seed: int = 0,
    noise: dict | None = None,
    pixels: bool = False,
    duration: float | None = None,
    basis: str | None = None,
) -> Recording:
    """Run experiment ``name`` on the robot with the hidden ``truth`` parameters and return the
    noisy :class:`~tdacm.identify.data.Recording` (written to folder ``out`` if given:
    ``scenario.toml``, ``timeseries.npz`` with the true ``t, q, qd, u``, ``measurements.npz``
    with what the fit reads, ``truth.toml``). ``seed`` draws the step levels and the noise.
    ``pixels``: also record the tip camera's four target points (1 px noise); ``duration``
    shortens the experiment (s; its profile is the same up to there). ``basis``: the hidden
    robot's strain basis (e.g. ``"bending:2"``: a backbone richer than the scenario's
    constant curvature, as a real one is); the recording's model, the one the lab states
    and the fit starts from, keeps the scenario's basis, and ``Recording.q`` is then
    ``None`` (the true states are the hidden robot's, in its own coordinates; they are
    written to ``timeseries.npz`` and the basis to ``truth.toml``)."""
    exp = experiment(name)
    truth = dict(DEFAULT_TRUTH if truth is None else truth)
    noise = {**NOISE, **(noise or {})}
    model, world = model_of_scenario(parse_scenario(scenario_text(exp)))
    lab = model
    if basis is not None:
        model, world = model_of_scenario(parse_scenario(scenario_text(exp, basis)))
    sysm = model.system
    valid = {k: v for k, v in truth.items() if k in model.nominal}
    added = dict(exp.added)
    sim_values = model.values(valid)
    for k, a in added.items():
        sim_values[k] += a
    rng_profile = np.random.default_rng([seed, 1])
    rng_noise = np.random.default_rng([seed, 2])
    nsamp = int(round((exp.duration if duration is None else duration) / SAMPLE_DT))
    t = np.arange(nsamp) * SAMPLE_DT
    q0 = np.zeros(sysm.n) if not exp.q0 else np.asarray(exp.q0, float)
    if exp.profile is not None:
        u = exp.profile(t, rng_profile)
        pred = model.simulate(sim_values, q0[None], np.zeros((1, sysm.n)), [0], [nsamp], u,
                              SAMPLE_DT, GENERATOR_SUBSTEPS)  # fmt: skip
        q, qd = pred.q, pred.qd
    else:
        control = _hover_controller(model, q0)
        ex, ten = _hover_excitation(t, rng_profile)
        gam = sysm.base.gamma[[0, 1, 2, 5]]
        q = np.zeros((nsamp, sysm.n))
        qd = np.zeros((nsamp, sysm.n))
        u = np.zeros((nsamp, sysm.n_u))
        qk, qdk = q0.copy(), np.zeros(sysm.n)
        top = sysm.base.max_thrust
        for k in range(nsamp):
            q[k], qd[k] = qk, qdk
            f = control(qk, qdk) + np.linalg.solve(gam, ex[k])
            u[k] = np.r_[np.clip(f, 0.0, top), ten[k]]
            if k + 1 < nsamp:
                pred = model.simulate(sim_values, qk[None], qdk[None], [0], [2], u[k : k + 2],
                                      SAMPLE_DT, GENERATOR_SUBSTEPS)  # fmt: skip
                if not pred.ok:
                    raise RuntimeError(f"{name}: the synthetic run failed at t = {t[k]:.2f} s")
                qk, qdk = pred.q[1], pred.qd[1]
    true_sys = model.build(sim_values)
    base, tip = model.poses(true_sys, q)
    rec_u = u.copy()
    na = sysm.n_a
    rec_u[:, -na:] *= 1.0 + noise["tension"] * rng_noise.standard_normal((nsamp, na))
    tip_m = _noisy_poses(tip, noise, rng_noise)
    drone_m = _noisy_poses(base, noise, rng_noise) if sysm.floating else None
    px = None
    if pixels:
        px = project_points(
            tip, model.camera_mount(valid.get("camera_offset")), world.robot.local_camera,
            world.scene.target_points_world(),
        )  # fmt: skip
        px = px + noise["pixel"] * rng_noise.standard_normal(px.shape)
        cam = world.robot.local_camera
        seen = (px[..., 0] >= 0) & (px[..., 0] < cam.width) & (px[..., 1] >= 0)
        seen &= px[..., 1] < cam.height
        px[~seen] = np.nan  # a point outside the image is not detected
    rec = Recording(
        name, t, rec_u, lab, tip_m, drone_m, px, world.scene.target_points_world(),
        world.robot.local_camera, valid, q if basis is None else None, added,
    )  # fmt: skip
    if out is not None:
        write_recording(rec, out, exp, qd, u, seed, noise, q, basis)
    return rec


def _noisy_poses(g: np.ndarray, noise: dict, rng) -> np.ndarray:
    out = g.copy()
    n = len(g)
    out[:, :3, 3] += noise["position"] * rng.standard_normal((n, 3))
    rv = np.radians(noise["rotation_deg"]) * rng.standard_normal((n, 3))
    out[:, :3, :3] = g[:, :3, :3] @ Rotation.from_rotvec(rv).as_matrix()
    return out


def project_points(tip, mount, camera, points) -> np.ndarray:
    """(T, P, 2) pixels of the world ``points`` seen by an ideal pinhole camera (no distortion)
    mounted at ``mount`` on the tip poses ``tip`` (T, 4, 4); NaN behind the camera."""
    cam = tip @ mount
    r = cam[:, :3, :3]
    pc = np.einsum("tji,tpj->tpi", r, points[None, :, :] - cam[:, None, :3, 3])
    z = pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack(
            [camera.fx * pc[..., 0] / z + camera.cx, camera.fy * pc[..., 1] / z + camera.cy],
            axis=-1,
        )
    uv[z <= 1e-6] = np.nan
    return uv


def write_recording(
    rec: Recording, out, exp: Experiment, qd, u_true, seed, noise, q=None, basis=None
) -> Path:
    """The synthetic run folder (see :func:`synthesize`); ``q`` the true states (default
    ``rec.q``), ``basis`` the hidden robot's strain basis when not the scenario's."""
    import tomli_w

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.toml").write_text(scenario_text(exp))
    np.savez(out / "timeseries.npz", t=rec.t, q=rec.q if q is None else q, qd=qd, u=u_true)
    meas = {"t": rec.t, "u": rec.u, "tip_pose": matrix_to_pose7(rec.tip)}
    if rec.added:
        (out / "experiment.toml").write_text(
            "# known additions to the robot during this experiment (read by the fit)\n"
            + tomli_w.dumps({"experiment": exp.name, "added": rec.added})
        )
    if rec.drone is not None:
        meas["drone_pose"] = matrix_to_pose7(rec.drone)
    if rec.pixels is not None:
        meas["pixels"] = rec.pixels
    np.savez(out / "measurements.npz", **meas)
    info = {
        "experiment": exp.name,
        "seed": seed,
        "parameters": {k: float(v) for k, v in rec.truth.items()},
        "noise": {k: float(v) for k, v in noise.items()},
    }
    if basis is not None:
        info["basis"] = basis
    (out / "truth.toml").write_text(
        "# The hidden parameters of this synthetic recording (the fit never reads this file).\n"
        + tomli_w.dumps(info)
    )
    log.info("synthetic recording %s written to %s", exp.name, out)
    return out
