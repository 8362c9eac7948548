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
        "attitude_filter": (float, 0.1),
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
    "sensors": {  # imperfections of the local camera (see tdacm.sim.sensors)
        "pixel_noise": (float, 0.0),  # px, std of the noise on detected points
        "dropout": (float, 0.0),  # probability that a frame has no detection
        "latency_steps": (int, 0),  # control steps between image and use
        "intrinsics_error": (float, 0.0),  # relative std of the controller's fx, fy, cx, cy
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
    from .sensors import SensorModel

    try:
        SensorModel(**d["sensors"])
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    for sec, key in (
        ("ibvs", "gain"),
        ("recovery", "max_speed"),
        ("safety", "growth_limit"),
        ("scene", "box_size"),
    ):
        if d[sec][key] <= 0:
            raise ScenarioError(f"{source}: {sec}.{key} must be positive")
    return Scenario(d, source)


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
    """Load a shipped scenario by name, or a TOML file by path; ``config`` (a path) overrides."""
    p = Path(str(name_or_path))
    if p.suffix == ".toml" and p.exists():
        sc = parse_scenario(p.read_text(), str(p))
    else:
        f = _package_files() / f"{name_or_path}.toml"
        if not f.is_file():
            raise ScenarioError(
                f"unknown scenario {name_or_path!r}; available: {', '.join(list_scenarios())}"
            )
        sc = parse_scenario(f.read_text(), f"scenario {name_or_path}")
    if config is not None:
        cp = Path(config)
        if not cp.is_file():
            raise ScenarioError(f"config file {config} does not exist")
        try:
            data = tomllib.loads(cp.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(f"{cp}: invalid TOML: {exc}") from None
        sc = sc.with_overrides(data, str(cp))
    return sc


def vec(x) -> np.ndarray:
    return np.asarray(x, dtype=float)
