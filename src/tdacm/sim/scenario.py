"""Scenarios as data: TOML files shipped in ``tdacm/scenarios/``, validated on load.

A scenario file has top-level ``name``, ``description``, ``duration``, ``dt``, ``substeps``,
``seed`` and the sections of :data:`SCHEMA` (every key optional except ``initial.q`` and
``desired.q``; defaults below). Unknown sections or keys, wrong types and wrong vector
lengths raise :class:`ScenarioError` naming the file and the key. ``--config FILE`` overrides
use the same layout (merged section by section).
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from .._validate import unit_vector
from ..loop.ablation import parse_controller_truth
from ..vision.mounts import tip_camera_pose
from .robot import ROBOT_SCHEMA, RobotError, strain_count


class ScenarioError(ValueError):
    """Invalid scenario data."""


_NUM = (int, float)

#: section -> key -> (type, default); type "vec:N" is a list of N numbers ("vec" any length)
SCHEMA = {
    "": {
        "name": (str, None),
        "description": (str, ""),
        "duration": (float, 5.0),
        "dt": (float, 0.02),
        "substeps": (int, 4),
        "seed": (int, 0),
    },
    "system": {
        "base": (str, "floating"),  # "floating" | "fixed"
        "held_base_q": ("vec:6", [0.0, 0.0, 0.0, 0.0, 0.0, 3.0]),  # drone pose for "fixed"
    },
    "robot": ROBOT_SCHEMA,  # nested subsections: see tdacm.sim.robot
    "initial": {"q": ("vec", None), "qd": ("vec", None)},
    "desired": {"q": ("vec", None)},
    "model": {"perturbation": (float, 0.1), "gravity_feedforward": (bool, True)},
    "controller": {
        # "default": the robust servo (target filter, predicted features, floored solve,
        # shaping); "paper": the paper's literal choices (docs/control.md, "Profiles")
        "profile": (str, "default"),
        "class": (str, ""),  # "package.module:ClassName" of a user controller ("": adaptive)
        "pretension": (float, 0.5),
        "max_tilt": (float, 0.35),
        "attitude_filter": (float, 0.05),
        "max_tilt_rate": (float, 1.5),
    },
    "ibvs": {
        "gain": (float, 1.0),
        "mode": (str, "current"),
        "compensation": (str, "exact"),
        "max_joint_rate": (float, 0.4),  # rad/s, rod strains and yaw
        "max_drone_speed": (float, 0.3),  # m/s, horizontal
        "max_vertical_speed": (float, 1.0),  # m/s
        "soft_start": (float, 1.0),
        "rate_filter": (float, 0.15),  # s, time constant of the joint-rate command filter
        "accel_feedforward": (bool, True),  # qdd_d from the filtered rate command
        "reference_leak": (float, 4.0),  # 1/s, pull of q_d toward q (anti wind-up)
        # robust servo (docs/control.md, "Robust servo")
        "features": (str, "predicted"),  # "predicted" (target filter) | "measured"
        "floor": (float, 0.05),  # singular-value floor of the J_img solve (0: plain inverse)
        "solver": (str, "floor"),  # "floor" | "damped"
        "filter_pixel_sigma": (float, 1.0),  # px, corner noise assumed by the target filter
        "filter_window": (int, 250),  # frames fused by the target filter (sliding window)
        "filter_smoothing": (float, 1.0),  # s, smoothing of the estimate used for prediction
        # deg, the target filter's prior that the target lies level, facing up (0: none)
        "target_level_prior_deg": (float, 0.5),
        # the direction the prior believes the target's z axis (into its surface) has in the
        # world: straight down for a target lying face up; e.g. [1, 0, 0] for a wall facing -x
        "target_level_normal": ("vec:3", [0.0, 0.0, -1.0]),
    },
    "recovery": {
        "max_speed": (float, 0.3),
        "margin_px": (float, 20.0),
        "confirm": (int, 2),
        "lose": (int, 5),
        # predicted features: recovery only if no detection for this long (s) or the
        # predicted points leave C_L's image for `lose` frames
        "lost_timeout": (float, 1.0),
    },
    "scene": {
        "target": (str, "aruco"),  # "aruco" | "apriltag"
        "box_size": (float, 0.4),
        "box_xy": ("vec:2", [0.0, 0.0]),
        "target_yaw_deg": (float, 0.0),
        "target_tilt_deg": ("vec:2", [0.0, 0.0]),  # deg, about world x, y (the truth)
    },
    "cameras": {  # the cameras' intrinsics and mounts are in [robot.cameras.*]
        "local_renderer": (str, "planar"),  # "planar" (image + detector) | "analytic"
        "global_every": (int, 1),
        "global_renderer": (str, "pybullet"),  # "pybullet" | "planar"
        "global_backend": (str, "auto"),  # PyBullet: "auto" (EGL if available), "egl", "tiny"
    },
    "safety": {
        "enabled": (bool, True),
        "growth_limit": (float, 0.05),
        "min_increase": (float, 0.005),
        "grace": (float, 0.5),
    },
    "disturbances": {
        "base_wrench_amplitude": ("vec:6", [0.0] * 6),
        "base_wrench_frequency": (float, 0.0),
        "downwash": ("vec:3", [0.0, 0.0, 0.0]),
        "downwash_noise": (float, 0.0),
    },
    "sensors": {  # imperfections of the local camera (see tdacm.loop.sensors.SensorModel)
        "pixel_noise": (float, 0.0),  # px, std of the noise on detected points
        "dropout": (float, 0.0),  # probability that a frame has no detection
        "latency_steps": (int, 0),  # control steps between image and use
        "intrinsics_error": (float, 0.0),  # relative std of the controller's fx, fy, cx, cy
        # proprioceptive sensors (tdacm.estimation.sensors; used when estimation.source =
        # "estimated"): drone pose (mocap/VIO), IMU at the drone's CoM, tendon encoders
        "pose_enabled": (bool, True),
        "pose_rate": (float, 50.0),  # Hz
        "pose_latency": (float, 0.02),  # s
        "pose_position_noise": (float, 0.003),  # m
        "pose_attitude_noise": (float, 0.005),  # rad (body-frame rotation vector)
        "pose_dropout": (float, 0.0),  # probability that a sample is lost
        "imu_enabled": (bool, True),
        "imu_rate": (float, 50.0),  # Hz
        "imu_latency": (float, 0.0),  # s
        "gyro_noise": (float, 0.005),  # rad/s per sample
        "gyro_bias": (float, 0.005),  # rad/s, std of the turn-on bias
        "gyro_bias_walk": (float, 0.0),  # rad/s/sqrt(s)
        "accel_noise": (float, 0.05),  # m/s^2 per sample
        "accel_bias": (float, 0.05),  # m/s^2, std of the turn-on bias
        "accel_bias_walk": (float, 0.0),  # m/s^2/sqrt(s)
        "imu_dropout": (float, 0.0),
        "encoder_enabled": (bool, True),
        "encoder_rate": (float, 50.0),  # Hz
        "encoder_latency": (float, 0.0),  # s
        "encoder_resolution": (float, 1e-5),  # m of tendon per count
        "encoder_noise": (float, 5e-6),  # m
        "encoder_bias": (float, 0.0),  # m, std of a constant per-tendon offset (slack)
        "encoder_dropout": (float, 0.0),
    },
    "estimation": {  # state source of everything downstream of the sensors (tdacm.estimation)
        "source": (str, "true"),  # "true" (plant state) | "estimated" (EKF)
        "initial_guess": (str, "measured"),  # "measured" (pose + tendon inversion) | "true"
        "initial_strain_error": (float, 0.0),  # rad/m added to every strain of the guess
        "initial_position_error": (float, 0.0),  # m added to every drone position coordinate
        "rk4_steps": (int, 1),
        "accel_noise_angular": (float, 0.3),  # rad/s^2/sqrt(Hz)
        "accel_noise_linear": (float, 0.005),  # m/s^2/sqrt(Hz)
        "accel_noise_strain": (float, 0.2),  # rad/m/s^2/sqrt(Hz)
        "disturbance_walk_angular": (float, 1.0),  # rad/s^3/sqrt(Hz)
        "disturbance_walk_linear": (float, 0.02),  # m/s^3/sqrt(Hz)
        "disturbance_walk_strain": (float, 0.3),  # rad/m/s^3/sqrt(Hz)
        "accel_model_error": (float, 0.03),  # m/s^2
        "model_error_fraction": (float, 0.1),  # relative error of the predicted acceleration
        "initial_attitude_std": (float, 0.02),  # rad
        "initial_position_std": (float, 0.02),  # m
        "initial_strain_std": (float, 0.3),  # rad/m
        "initial_velocity_std": (float, 0.1),
        "initial_disturbance_angular_std": (float, 2.0),
        "initial_disturbance_linear_std": (float, 1.5),
        "initial_disturbance_strain_std": (float, 5.0),
        "max_delay": (float, 0.2),  # s of filter history kept for late measurements
        # the tip camera's view of the static target fused in the filter (target pose states)
        "fuse_local_camera": (bool, True),
        "camera_pixel_sigma": (float, 1.0),  # px, corner noise the filter assumes
        "target_initial_position_std": (float, 0.05),  # m, prior at the target's first view
        "target_initial_attitude_std": (float, 0.05),  # rad
        # ablation (a diagnostic, off): coordinates the low-level controller reads from the
        # plant instead of the estimate, e.g. "qd[3:5]" (tdacm.loop.ablation)
        "controller_truth": (str, ""),
    },
    "expect": {
        "initial_in_local_fov": (bool, None),
        "initial_in_global_fov": (bool, None),
    },
}


def _check(where: str, typ, value):
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, _NUM) or not math.isfinite(value):
            raise ScenarioError(f"{where} must be a finite number, got {value!r}")
        return float(value)
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ScenarioError(f"{where} must be an integer, got {value!r}")
        return value
    if typ is bool:
        if not isinstance(value, bool):
            raise ScenarioError(f"{where} must be true or false, got {value!r}")
        return value
    if typ is str:
        if not isinstance(value, str):
            raise ScenarioError(f"{where} must be a string, got {value!r}")
        return value
    if typ == "points":  # a list of equal-length lists of numbers
        if not isinstance(value, list) or not value or not all(isinstance(r, list) for r in value):
            raise ScenarioError(f"{where} must be a list of [y, z] lists, got {value!r}")
        rows = [_check(f"{where}[{i}]", "vec", r) for i, r in enumerate(value)]
        if len({len(r) for r in rows}) != 1:
            raise ScenarioError(f"{where}: every entry must have the same length")
        return rows
    # vectors
    if not isinstance(value, list) or not all(
        isinstance(v, _NUM) and not isinstance(v, bool) and math.isfinite(v) for v in value
    ):
        raise ScenarioError(f"{where} must be a list of finite numbers, got {value!r}")
    if ":" in typ and len(value) != int(typ.split(":")[1]):
        raise ScenarioError(f"{where} must have {typ.split(':')[1]} entries, got {len(value)}")
    return [float(v) for v in value]


def _is_leaf(entry) -> bool:
    return isinstance(entry, tuple)


def _section_defaults(schema: dict) -> dict:
    return {
        k: copy.deepcopy(v[1]) if _is_leaf(v) else _section_defaults(v) for k, v in schema.items()
    }


def _defaults() -> dict:
    out = _section_defaults({k: v for k, v in SCHEMA.items() if k})
    out.update(_section_defaults(SCHEMA[""]))
    return out


def _merge_section(out: dict, schema: dict, data: dict, where: str, source: str) -> None:
    for k, v in data.items():
        if k not in schema:
            raise ScenarioError(f"{source}: unknown key {where}.{k} (known: {', '.join(schema)})")
        entry = schema[k]
        if _is_leaf(entry):
            out[k] = _check(f"{source}: {where}.{k}", entry[0], v)
        elif not isinstance(v, dict):
            raise ScenarioError(f"{source}: {where}.{k} must be a section [{where}.{k}]")
        else:
            _merge_section(out[k], entry, v, f"{where}.{k}", source)


def _merge(base: dict, data: dict, source: str) -> dict:
    out = copy.deepcopy(base)
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in SCHEMA or key == "":
                raise ScenarioError(
                    f"{source}: unknown section [{key}] "
                    f"(known: {', '.join(k for k in SCHEMA if k)})"
                )
            _merge_section(out[key], SCHEMA[key], value, key, source)
        else:
            if key not in SCHEMA[""]:
                raise ScenarioError(
                    f"{source}: unknown key {key!r} (known: {', '.join(SCHEMA[''])}, or a section)"
                )
            out[key] = _check(f"{source}: {key}", SCHEMA[""][key][0], value)
    return out


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (``data`` is the full nested dict with defaults filled in)."""

    data: dict
    source: str

    @property
    def name(self) -> str:
        return self.data["name"]

    @property
    def floating(self) -> bool:
        return self.data["system"]["base"] == "floating"

    def __getitem__(self, key):
        return self.data[key]

    def with_overrides(self, data: dict, source: str = "overrides") -> Scenario:
        return validate(_merge(self.data, data, source), f"{self.source} + {source}")


def validate(d: dict, source: str) -> Scenario:
    """Cross-field checks (on a dict already merged with the defaults)."""
    if not d.get("name"):
        raise ScenarioError(f"{source}: 'name' is required")
    for key in ("duration", "dt"):
        if d[key] <= 0:
            raise ScenarioError(f"{source}: {key} must be positive, got {d[key]!r}")
    if d["substeps"] < 1:
        raise ScenarioError(f"{source}: substeps must be >= 1")
    if d["dt"] > d["duration"]:
        raise ScenarioError(
            f"{source}: dt ({d['dt']} s) must not exceed duration ({d['duration']} s)"
        )
    if d["seed"] < 0:
        raise ScenarioError(f"{source}: seed must be a non-negative integer, got {d['seed']}")
    base = d["system"]["base"]
    if base not in ("floating", "fixed"):
        raise ScenarioError(f"{source}: system.base must be 'floating' or 'fixed', got {base!r}")
    if d["robot"]["base"]["pose_q"] is not None:  # [robot.base] is a clamp at that pose
        d["system"]["base"] = base = "fixed"
    try:
        n_s = strain_count(d["robot"])
    except RobotError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    n = n_s + (6 if base == "floating" else 0)
    names = (["phi", "theta", "psi", "x", "y", "z"] if base == "floating" else []) + [
        f"q_s{i + 1}" for i in range(n_s)
    ]
    for sec in ("initial", "desired"):
        q = d[sec]["q"]
        if q is None:
            raise ScenarioError(f"{source}: {sec}.q is required")
        if len(q) != n:
            raise ScenarioError(
                f"{source}: {sec}.q must have {n} entries for a {base} base "
                f"(q = [{', '.join(names)}]), got {len(q)}"
            )
    qd = d["initial"]["qd"]
    if qd is not None and len(qd) != n:
        raise ScenarioError(f"{source}: initial.qd must have {n} entries, got {len(qd)}")
    if d["scene"]["target"] not in ("aruco", "apriltag"):
        raise ScenarioError(f"{source}: scene.target must be 'aruco' or 'apriltag'")
    if d["ibvs"]["mode"] not in ("current", "desired", "mean"):
        raise ScenarioError(f"{source}: ibvs.mode must be current, desired or mean")
    if d["controller"]["profile"] not in ("default", "paper"):
        raise ScenarioError(f"{source}: controller.profile must be 'default' or 'paper'")
    if d["ibvs"]["features"] not in ("predicted", "measured"):
        raise ScenarioError(f"{source}: ibvs.features must be 'predicted' or 'measured'")
    if d["ibvs"]["solver"] not in ("floor", "damped"):
        raise ScenarioError(f"{source}: ibvs.solver must be 'floor' or 'damped'")
    if d["ibvs"]["floor"] < 0:
        raise ScenarioError(f"{source}: ibvs.floor must be >= 0")
    if d["ibvs"]["filter_pixel_sigma"] <= 0:
        raise ScenarioError(f"{source}: ibvs.filter_pixel_sigma must be positive")
    if d["ibvs"]["filter_smoothing"] < 0:
        raise ScenarioError(f"{source}: ibvs.filter_smoothing must be >= 0")
    if not d["ibvs"]["target_level_prior_deg"] >= 0:
        raise ScenarioError(f"{source}: ibvs.target_level_prior_deg must be >= 0")
    try:
        unit_vector("ibvs.target_level_normal", d["ibvs"]["target_level_normal"])
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    if any(abs(v) > 30.0 for v in d["scene"]["target_tilt_deg"]):
        raise ScenarioError(f"{source}: scene.target_tilt_deg must lie within +-30 deg")
    if d["ibvs"]["filter_window"] < 1:
        raise ScenarioError(f"{source}: ibvs.filter_window must be >= 1")
    if d["recovery"]["lost_timeout"] <= 0:
        raise ScenarioError(f"{source}: recovery.lost_timeout must be positive")
    if d["ibvs"]["compensation"] not in ("exact", "rotation", "approx"):
        raise ScenarioError(f"{source}: ibvs.compensation must be exact, rotation or approx")
    if d["cameras"]["global_backend"] not in ("auto", "egl", "tiny"):
        raise ScenarioError(f"{source}: cameras.global_backend must be auto, egl or tiny")
    if d["cameras"]["local_renderer"] not in ("planar", "analytic"):
        raise ScenarioError(f"{source}: cameras.local_renderer must be planar or analytic")
    if d["cameras"]["global_renderer"] not in ("pybullet", "planar"):
        raise ScenarioError(f"{source}: cameras.global_renderer must be pybullet or planar")
    for sec, key in (("model", "perturbation"), ("sensors", "dropout")):
        if not 0 <= d[sec][key] < 1:
            raise ScenarioError(f"{source}: {sec}.{key} must lie in [0, 1)")
    from ..estimation import EstimatorConfig, SensorSuiteConfig
    from ..loop.sensors import SensorModel

    est = d["estimation"]
    if est["source"] not in ("true", "estimated"):
        raise ScenarioError(f"{source}: estimation.source must be 'true' or 'estimated'")
    if est["initial_guess"] not in ("measured", "true"):
        raise ScenarioError(f"{source}: estimation.initial_guess must be 'measured' or 'true'")
    try:
        truth = parse_controller_truth(est["controller_truth"])
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    if any(truth) and est["source"] != "estimated":
        raise ScenarioError(
            f"{source}: estimation.controller_truth needs estimation.source = 'estimated' "
            "(on the true state the controller reads the plant already)"
        )
    for key in ("camera_pixel_sigma", "target_initial_position_std", "target_initial_attitude_std"):
        if est[key] <= 0:
            raise ScenarioError(f"{source}: estimation.{key} must be positive, got {est[key]!r}")
    try:  # the messages name the key (sensors.<key>, estimation.<key>)
        SensorModel(**{k: d["sensors"][k] for k in SensorModel.__dataclass_fields__})
        SensorSuiteConfig.from_section(d["sensors"])
        EstimatorConfig.from_section(est)
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    for sec, key in (
        ("ibvs", "gain"),
        ("ibvs", "max_joint_rate"),
        ("ibvs", "max_drone_speed"),
        ("ibvs", "max_vertical_speed"),
        ("recovery", "max_speed"),
        ("safety", "growth_limit"),
        ("scene", "box_size"),
        ("controller", "max_tilt"),
    ):
        if d[sec][key] <= 0:
            raise ScenarioError(f"{source}: {sec}.{key} must be positive, got {d[sec][key]!r}")
    for sec, key in (
        ("controller", "pretension"),
        ("controller", "attitude_filter"),
        ("controller", "max_tilt_rate"),
        ("ibvs", "soft_start"),
        ("ibvs", "rate_filter"),
        ("recovery", "margin_px"),
        ("safety", "min_increase"),
        ("safety", "grace"),
        ("disturbances", "base_wrench_frequency"),
        ("disturbances", "downwash_noise"),
        ("cameras", "global_every"),
    ):
        if d[sec][key] < 0:
            raise ScenarioError(f"{source}: {sec}.{key} must be non-negative, got {d[sec][key]!r}")
    if d["controller"]["max_tilt"] >= math.pi / 2:
        raise ScenarioError(
            f"{source}: controller.max_tilt must be below pi/2 rad, got {d['controller']['max_tilt']!r}"
        )
    for key in ("confirm", "lose"):
        if d["recovery"][key] < 1:
            raise ScenarioError(
                f"{source}: recovery.{key} must be >= 1 (frames), got {d['recovery'][key]!r}"
            )
    return Scenario(d, source)


#: Longest plant step ``dt / substeps``, as a multiple of ``TDACM.suggested_dt()`` (10 ms for
#: the paper system: 2x keeps the tip within ~2e-5 m of an adaptive reference over 5 s).
MAX_STEP_FACTOR = 2.0
#: Longest control period accepted (s). Measured on ``paper-in-fov`` (3 s, substeps 4): dt =
#: 0.02 and 0.04 s converge alike; at 0.05 s the safety monitor stops the loop at 1.6 s (error
#: growth); at 0.1 s the rod diverges (|q_s1| = 2.5) even with the plant at 5 ms (substeps 20).
MAX_CONTROL_PERIOD = 0.04


def check_run(scenario: Scenario, duration=None, seed=None, flags: bool = True) -> None:
    """Checks of the run-time overrides (``--duration``, ``--seed``): ``duration`` finite,
    positive and at least one control period, ``seed`` a non-negative integer. The message
    names the flag (``flags=True``) or the keyword."""
    dn, sn = ("--duration", "--seed") if flags else ("duration", "seed")
    if duration is not None:
        if isinstance(duration, bool) or not isinstance(duration, _NUM):
            raise ScenarioError(f"{dn} must be a number of seconds, got {duration!r}")
        if not math.isfinite(duration) or duration <= 0:
            raise ScenarioError(f"{dn} must be a finite positive number of seconds, got {duration}")
        if scenario["dt"] > duration:
            raise ScenarioError(
                f"{dn} ({duration} s) is shorter than the control period dt = {scenario['dt']} s"
            )
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ScenarioError(f"{sn} must be a non-negative integer, got {seed!r}")


def check_with_world(scenario: Scenario, world) -> None:
    """Checks that need the built robot (:func:`tdacm.sim.assemble.build_world` runs them on
    the :class:`~tdacm.sim.assemble.World` it builds):

    * the plant's RK4 step ``dt / substeps`` at most ``MAX_STEP_FACTOR`` times
      ``system.suggested_dt()``, and the control period ``dt`` at most ``MAX_CONTROL_PERIOD``
      (the sampled closed loop diverges at longer periods, see the constant);
    * the target in front of the tip camera C_L at the desired configuration (the reference
      view of the IBVS is taken there).
    """
    d = scenario.data
    src = scenario.source
    system = world.robot.system
    if d["dt"] > MAX_CONTROL_PERIOD:
        raise ScenarioError(
            f"{src}: dt = {d['dt']} s is longer than {MAX_CONTROL_PERIOD} s: the sampled closed "
            f"loop is unstable there (measured: stopped at 0.05 s, diverges at 0.1 s; paper: 0.02 s)"
        )
    h = d["dt"] / d["substeps"]
    h_max = MAX_STEP_FACTOR * system.suggested_dt()
    if h > h_max:
        raise ScenarioError(
            f"{src}: dt / substeps = {h:.4g} s exceeds the plant's RK4 step limit "
            f"{h_max:.4g} s ({MAX_STEP_FACTOR:g} x suggested_dt()); raise substeps or lower dt"
        )
    try:
        parse_controller_truth(d["estimation"]["controller_truth"], system.n)
    except ValueError as exc:
        raise ScenarioError(f"{src}: {exc}") from None
    robot = world.robot
    g_c = tip_camera_pose(robot.system, world.q_star, robot.tip_mount)
    pts = world.scene.target_points_world()
    depth = (pts - g_c[:3, 3]) @ g_c[:3, 2]
    if np.any(depth <= 0):
        raise ScenarioError(
            f"{src}: desired.q puts the target behind the tip camera C_L (depths "
            f"{np.round(depth, 3).tolist()} m); the reference view needs the target in front"
        )


def _read_text(path: Path, what: str) -> str:
    """A text file's content; a directory, a missing file or non-UTF-8 bytes raise
    :class:`ScenarioError` naming the file."""
    if path.is_dir():
        raise ScenarioError(f"{what} {path} is a directory, not a TOML file")
    if not path.is_file():
        raise ScenarioError(f"{what} {path} does not exist")
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            f"{what} {path} is not UTF-8 text (TOML must be UTF-8): {exc}"
        ) from None


def parse_scenario(text: str, source: str = "<string>") -> Scenario:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: invalid TOML: {exc}") from None
    return validate(_merge(_defaults(), data, source), source)


def _package_files():
    return resources.files("tdacm") / "scenarios"


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(p.name[:-5] for p in _package_files().iterdir() if p.name.endswith(".toml"))


def load_scenario(name_or_path, config=None) -> Scenario:
    """Load a shipped scenario by name, a TOML file by path, or pass a :class:`Scenario`
    through; ``config`` (a path) overrides. Errors (unknown name, a directory, a missing or
    non-UTF-8 file, invalid TOML or values) raise :class:`ScenarioError` naming the file."""
    if isinstance(name_or_path, Scenario):
        sc = name_or_path
    else:
        p = Path(str(name_or_path))
        if p.is_dir():
            raise ScenarioError(f"scenario {p} is a directory, not a scenario name or TOML file")
        if p.suffix == ".toml" or p.exists() or len(p.parts) > 1:
            if not p.exists() and p.suffix != ".toml":
                raise ScenarioError(
                    f"unknown scenario {str(name_or_path)!r}; available: {', '.join(list_scenarios())}"
                )
            sc = parse_scenario(_read_text(p, "scenario file"), str(p))
        else:
            f = _package_files() / f"{name_or_path}.toml"
            if not f.is_file():
                raise ScenarioError(
                    f"unknown scenario {name_or_path!r}; available: {', '.join(list_scenarios())}"
                )
            sc = parse_scenario(f.read_text(encoding="utf-8"), f"scenario {name_or_path}")
    if config is not None:
        cp = Path(config)
        text = _read_text(cp, "--config file")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(f"{cp}: invalid TOML: {exc}") from None
        sc = sc.with_overrides(data, str(cp))
    return sc


def dict_to_toml(data: dict, header: str | None = None) -> str:
    """Nested scenario data (scalars, lists, sections, subsections) as TOML text; ``None``
    values (keys left unset) are omitted."""
    import json

    def fmt(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        raise TypeError(f"cannot write {v!r} to TOML")

    lines = [header] if header else []
    lines += [
        f"{k} = {fmt(v)}" for k, v in data.items() if v is not None and not isinstance(v, dict)
    ]

    def table(name, values):  # keys first, then the nested subsections ([robot.rod], ...)
        keys = [
            f"{k} = {fmt(v)}"
            for k, v in values.items()
            if v is not None and not isinstance(v, dict)
        ]
        if keys or not any(isinstance(v, dict) for v in values.values()):
            lines.append(f"\n[{name}]")
            lines.extend(keys)
        for k, v in values.items():
            if isinstance(v, dict):
                table(f"{name}.{k}", v)

    for sec, values in data.items():
        if isinstance(values, dict):
            table(sec, values)
    return "\n".join(lines) + "\n"


def scenario_to_toml(scenario: Scenario) -> str:
    """The resolved scenario (defaults filled in) as TOML text; ``load_scenario`` of the
    written file gives the same data (keys left unset, such as ``initial.qd``, are omitted)."""
    d = scenario.data
    ordered = {k: d[k] for k in SCHEMA[""] if k in d}
    ordered.update({sec: d[sec] for sec in SCHEMA if sec})
    return dict_to_toml(ordered, f"# resolved from {scenario.source}")


def vec(x) -> np.ndarray:
    return np.asarray(x, dtype=float)
