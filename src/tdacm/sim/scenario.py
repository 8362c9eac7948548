"""Scenarios as data: TOML files shipped in ``tdacm/scenarios/``, validated on load.

A scenario file has top-level ``name``, ``description``, ``duration``, ``dt``, ``substeps``,
``seed`` and the sections of :class:`~tdacm.sim.config.ScenarioConfig` (every key optional
except ``name``, ``initial.q`` and ``desired.q``; the defaults, ranges and meanings are on the
records, listed in docs/scenario-reference.md). Unknown sections or keys, wrong types, values
out of range and wrong vector lengths raise :class:`ScenarioError` of one line naming the file
and the dotted key. ``--config FILE`` overrides use the same layout (merged section by
section; an ``extends`` there is refused). ``extends = "NAME"`` (a shipped scenario, or a TOML
file relative to the extending file) inherits every value the file does not set; chains are
followed, cycles rejected.
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, replace
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np
import tomli_w
from pydantic import ValidationError

from ..loop.ablation import parse_controller_truth
from ..vision.camera import world_to_camera
from ..vision.mounts import tip_camera_pose
from .config import SECTIONS, TOP_KEYS, ScenarioConfig, error_line
from .robot import RobotError, strain_count


class ScenarioError(ValueError):
    """Invalid scenario data."""


_NUM = (int, float)


def _drop_none(d: dict) -> dict:
    return {k: _drop_none_value(v) for k, v in d.items() if v is not None}


def _drop_none_value(v):
    if isinstance(v, dict):
        return _drop_none(v)
    if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):  # array of tables
        return [_drop_none(x) for x in v]
    return v


def _deep_merge(base: dict, over: dict) -> dict:
    """``over`` merged into a copy of ``base`` section by section (tables merge, values
    replace)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _resolve(data: dict, source: str) -> ScenarioConfig:
    """Validate ``data`` (raw TOML tables, defaults not filled in) against the records of
    :mod:`tdacm.sim.config`: the typed record with every default filled in, or a
    :class:`ScenarioError` of one line naming ``source`` and the key."""
    try:
        return ScenarioConfig.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(f"{source}: {error_line(exc)}") from None


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: ``config`` is its typed record
    (:class:`~tdacm.sim.config.ScenarioConfig`, every default filled in), what the assembly
    reads; ``data`` the same values as a nested dict (for writing and merging). ``folder`` is
    the folder of the scenario file (searched for a user controller's module), ``None`` for a
    shipped scenario."""

    config: ScenarioConfig
    source: str
    folder: str | None = None

    @cached_property
    def data(self) -> dict:
        """The record as the nested dict of the file's keys (defaults filled in)."""
        return self.config.model_dump(by_alias=True)

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def floating(self) -> bool:
        return self.config.system.base == "floating"

    def __getitem__(self, key):
        return self.data[key]

    def with_overrides(self, data: dict, source: str = "overrides") -> Scenario:
        src = f"{self.source} + {source}"
        try:  # the overrides alone first, so that an error names their source
            ScenarioConfig.model_validate(data)
        except ValidationError as exc:
            raise ScenarioError(f"{source}: {error_line(exc)}") from None
        merged = _resolve(_deep_merge(_drop_none(self.data), data), src)
        return replace(self, config=validate(merged, src).config, source=src)


def validate(cfg: ScenarioConfig, source: str) -> Scenario:
    """Cross-field checks on a record already validated key by key (:func:`_resolve`): the
    name, ``dt`` against ``duration``, the lengths of ``q`` against the robot's strain count,
    the ablation's ``controller_truth``. A ``[robot.base]`` clamp sets
    ``system.base = "fixed"``."""
    if not cfg.name:
        raise ScenarioError(f"{source}: 'name' is required")
    if cfg.dt > cfg.duration:
        raise ScenarioError(
            f"{source}: dt ({cfg.dt} s) must not exceed duration ({cfg.duration} s)"
        )
    if cfg.robot.base.pose_q is not None:  # [robot.base] is a clamp at that pose
        cfg = cfg.model_copy(update={"system": cfg.system.model_copy(update={"base": "fixed"})})
    base = cfg.system.base
    try:
        n_s = strain_count(cfg.robot)
    except RobotError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    n = n_s + (6 if base == "floating" else 0)
    names = (["phi", "theta", "psi", "x", "y", "z"] if base == "floating" else []) + [
        f"q_s{i + 1}" for i in range(n_s)
    ]
    for sec, q in (("initial", cfg.initial.q), ("desired", cfg.desired.q)):
        if q is None:
            raise ScenarioError(f"{source}: {sec}.q is required")
        if len(q) != n:
            raise ScenarioError(
                f"{source}: {sec}.q must have {n} entries for a {base} base "
                f"(q = [{', '.join(names)}]), got {len(q)}"
            )
    qd = cfg.initial.qd
    if qd is not None and len(qd) != n:
        raise ScenarioError(f"{source}: initial.qd must have {n} entries, got {len(qd)}")
    aero = cfg.aerodynamics
    if not aero.enabled and cfg.wind.active:
        raise ScenarioError(
            f"{source}: [wind] acts through the drag: set aerodynamics.enabled = true"
        )
    if aero.enabled and aero.fixed_thrusts is not None and base == "floating":
        raise ScenarioError(
            f"{source}: aerodynamics.fixed_thrusts is for a fixed base (a floating drone's "
            "wake follows its own thrusts)"
        )
    est = cfg.estimation
    try:
        truth = parse_controller_truth(est.controller_truth)
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    if any(truth) and est.source != "estimated":
        raise ScenarioError(
            f"{source}: estimation.controller_truth needs estimation.source = 'estimated' "
            "(on the true state the controller reads the plant already)"
        )
    return Scenario(cfg, source)


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
        dt = scenario.config.dt
        if dt > duration:
            raise ScenarioError(
                f"{dn} ({duration} s) is shorter than the control period dt = {dt} s"
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
    cfg = scenario.config
    src = scenario.source
    system = world.robot.system
    if cfg.dt > MAX_CONTROL_PERIOD:
        raise ScenarioError(
            f"{src}: dt = {cfg.dt} s is longer than {MAX_CONTROL_PERIOD} s: the sampled closed "
            f"loop is unstable there (measured: stopped at 0.05 s, diverges at 0.1 s; paper: 0.02 s)"
        )
    h = cfg.dt / cfg.substeps
    h_max = MAX_STEP_FACTOR * system.suggested_dt()
    if h > h_max:
        raise ScenarioError(
            f"{src}: dt / substeps = {h:.4g} s exceeds the plant's RK4 step limit "
            f"{h_max:.4g} s ({MAX_STEP_FACTOR:g} x suggested_dt()); raise substeps or lower dt"
        )
    try:
        parse_controller_truth(cfg.estimation.controller_truth, system.n)
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
    for key, q in (("initial.q", world.q0), ("desired.q", world.q_star)):
        if (problem := below_ground(system, q)) is not None:
            raise ScenarioError(f"{src}: {key} {problem}")
    if (problem := target_unseen(world)) is not None:
        raise ScenarioError(f"{src}: initial.q {problem}")


def below_ground(system, q) -> str | None:
    """What of the robot lies below the ground (z < 0, the plane the target's box stands on)
    at configuration ``q``: the drone (its centre), or a rod's backbone (21 points each); else
    ``None``."""
    z_b = float(system.base_pose(q)[2, 3])
    if z_b < 0:
        return f"puts the drone {-z_b:.3g} m below the ground (z = {z_b:.3g} m)"
    for rod in range(system.n_rods):
        z = system.backbone(q, 21, rod)[:, 2, 3]
        if z.min() < 0:
            which = "the rod" if system.n_rods == 1 else f"rod {rod}"
            return (
                f"puts {which} {-z.min():.3g} m below the ground (lowest backbone point at "
                f"z = {z.min():.3g} m, drone at z = {z_b:.3g} m)"
            )
    return None


def target_unseen(world) -> str | None:
    """Why the run cannot start: a target (each arm's marker) whose four corners are in
    neither the tip camera C_L's view nor the drone camera C_G's at the initial configuration
    (the servo starts in IBVS on a C_L view, else it recovers from a C_G view; with the target
    in neither, the recovery fails at once), or ``None``. A pinhole check without rendering
    (the corners in front, between the clipping planes and inside the image)."""
    robot, q0 = world.robot, world.q0
    system = robot.system
    g_g = system.base_pose(q0) @ robot.drone_mount
    arms = robot.arms or (None,)
    for k, arm in enumerate(arms):
        cam, mount, rod = (
            (robot.local_camera, robot.tip_mount, 0)
            if arm is None
            else (arm.local_camera, arm.tip_mount, arm.rod)
        )
        pts = (
            world.arm(k).scene.target_points_world()
            if arm is not None
            else (world.scene.target_points_world())
        )
        g_l = tip_camera_pose(system, q0, mount, rod)
        in_local = cam.all_in_fov(world_to_camera(pts, g_l))
        in_global = robot.global_camera.all_in_fov(world_to_camera(pts, g_g))
        if not (in_local or in_global):
            what = "the target" if arm is None else f"arm {k}'s marker"
            return (
                f"starts with {what} in neither camera's view (C_L at the tip nor C_G on the "
                "drone): the servo needs it in C_L, or in C_G to recover; move the start "
                "(initial.q) or the target (scene.box_xy)"
            )
    return None


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


def _parse_toml(text: str, source: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: invalid TOML: {exc}") from None


def _shipped(name: str):
    f = _package_files() / f"{name}.toml"
    if not f.is_file():
        raise ScenarioError(f"unknown scenario {name!r}; available: {', '.join(list_scenarios())}")
    return f


def _extends(data: dict, source: str, folder: Path | None, chain: tuple) -> dict:
    """``data`` with its ``extends`` chain merged in (the parent's values under the file's);
    ``folder`` is the extending file's folder (relative paths), ``chain`` the files already
    on the way (a cycle raises)."""
    if "extends" not in data:
        return data
    parent = data["extends"]
    data = {k: v for k, v in data.items() if k != "extends"}
    if not isinstance(parent, str) or not parent:
        raise ScenarioError(f"{source}: extends must be a scenario name or a TOML file path")
    p = Path(parent)
    if p.suffix == ".toml" or len(p.parts) > 1:  # a file, relative to the extending file
        path = p if p.is_absolute() or folder is None else folder / p
        ident = str(path.resolve())
        text = _read_text(path, f"{source}: extends file")
        psource, pfolder = str(path), path.parent
    else:
        f = _shipped(parent)
        ident = psource = f"scenario {parent}"
        text, pfolder = f.read_text(encoding="utf-8"), None
    if ident in chain:
        raise ScenarioError(f"{source}: extends cycle: {' -> '.join((*chain, ident))}")
    pdata = _extends(_parse_toml(text, psource), psource, pfolder, (*chain, ident))
    return _deep_merge(pdata, data)


def parse_scenario(
    text: str, source: str = "<string>", folder: Path | str | None = None, _chain: tuple = ()
) -> Scenario:
    """A :class:`Scenario` from TOML text (``folder``: where relative ``extends`` paths and a
    user controller's module are looked for)."""
    data = _parse_toml(text, source)
    folder = Path(folder) if folder is not None else None
    data = _extends(data, source, folder, _chain or (source,))
    sc = validate(_resolve(data, source), source)
    return replace(sc, folder=str(folder) if folder is not None else None)


def _package_files():
    return resources.files("tdacm") / "scenarios"


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(p.name[:-5] for p in _package_files().iterdir() if p.name.endswith(".toml"))


def load_scenario(name_or_path, config=None) -> Scenario:
    """Load a shipped scenario by name, a TOML file by path, or pass a :class:`Scenario`
    through; ``config`` (a path) overrides it. A shipped name (``tdacm scenarios``) is the
    shipped scenario even where a file or folder of that name exists (name it ``./NAME``). Errors (unknown name, a directory, a missing or
    non-UTF-8 file, invalid TOML or values, an ``extends`` cycle, an ``extends`` in ``config``,
    which would replace the scenario it overrides) raise :class:`ScenarioError` naming the
    file."""
    if isinstance(name_or_path, Scenario):
        sc = name_or_path
    else:
        p = Path(str(name_or_path))
        shipped = str(name_or_path) in list_scenarios()
        if p.is_dir() and not shipped:
            inside = p / "scenario.toml"
            raise ScenarioError(
                f"scenario {p} is a directory, not a scenario name or TOML file"
                + (f" (the scenario of the run in it: {inside})" if inside.is_file() else "")
            )
        # a shipped name wins over a folder or file of that name in the current folder (e.g.
        # a run folder written with --out NAME); ./NAME or NAME.toml names the file
        if not shipped and (p.suffix == ".toml" or p.exists() or len(p.parts) > 1):
            if not p.exists() and p.suffix != ".toml":
                raise ScenarioError(
                    f"unknown scenario {str(name_or_path)!r}; available: {', '.join(list_scenarios())}"
                )
            sc = parse_scenario(
                _read_text(p, "scenario file"), str(p), p.parent,
                (str(p.resolve()),),
            )  # fmt: skip
        else:
            f = _shipped(str(name_or_path))
            src = f"scenario {name_or_path}"
            sc = parse_scenario(f.read_text(encoding="utf-8"), src, None, (src,))
    if config is not None:
        cp = Path(config)
        text = _read_text(cp, "--config file")
        data = _parse_toml(text, str(cp))
        if "extends" in data:
            raise ScenarioError(
                f"{cp}: extends is not allowed in a --config file: it would replace the "
                f"scenario {sc.name!r} it overrides (run `tdacm run {cp}` to run the file alone)"
            )
        sc = sc.with_overrides(data, str(cp))
    return sc


def dict_to_toml(data: dict, header: str | None = None) -> str:
    """Nested data (scalars, lists, tables) as TOML text by ``tomli_w``; ``None`` values (keys
    left unset) are omitted, ``header`` (a ``# comment``) goes first."""
    text = tomli_w.dumps(_drop_none(data))
    return f"{header}\n{text}" if header else text


def scenario_to_toml(scenario: Scenario) -> str:
    """The resolved scenario (defaults filled in) as TOML text; ``load_scenario`` of the
    written file gives the same data (keys left unset, such as ``initial.qd``, are omitted)."""
    data = scenario.data
    ordered = {k: data.get(k) for k in TOP_KEYS}
    ordered.update({sec: data.get(sec) for sec in SECTIONS})
    return dict_to_toml(ordered, f"# resolved from {scenario.source}")


def vec(x) -> np.ndarray:
    return np.asarray(x, dtype=float)
