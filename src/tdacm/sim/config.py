"""The scenario file's model: one typed record per section, composed from the blocks' records.

Layout (one default per value, imports one way): each block declares the record of the
section it reads next to its code - :mod:`tdacm.loop.config` (``[ibvs]``, ``[recovery]``,
``[controller]``, ``[cameras]``, ``[safety]``, ``[disturbances]``, the camera keys of
``[sensors]``), :mod:`tdacm.control.config` (``[model]``), :mod:`tdacm.contact.config`
(``[scene.contact]``, ``[[scene.obstacles]]``), :mod:`tdacm.aero.config` (``[aerodynamics]``,
``[wind]``), :mod:`tdacm.estimation.config` (``[estimation]``, the proprioceptive keys of
``[sensors]``), :mod:`tdacm.sim.robot` (``[robot]``, defaults from :mod:`tdacm.paper_values`) -
and this module composes them with the sections that only the simulation reads (``[system]``,
``[initial]``, ``[desired]``, ``[scene]`` with the defaults of the rendered scene
:class:`~tdacm.vision.scene.SceneConfig`, ``[expect]``).
The records are pydantic models (:mod:`tdacm._config`): the same declaration gives the
validation, the JSON Schema (``tdacm schema``) and docs/scenario-reference.md
(:func:`reference_markdown`).

Cross-field checks (``q`` lengths against the robot's strain count, ...) are in
:func:`tdacm.sim.scenario.validate`; :func:`error_line` turns a pydantic ``ValidationError``
into the one-line message of a :class:`~tdacm.sim.scenario.ScenarioError`.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ValidationError, create_model, field_validator

from .._config import ConfigModel, Field
from ..aero.config import AerodynamicsConfig, WindConfig
from ..contact.config import ContactConfig, ObstacleConfig
from ..control.config import ModelConfig
from ..estimation.config import EstimationConfig, ProprioceptiveSensors
from ..loop.config import (
    PLANT_SUBSTEPS,
    CamerasConfig,
    ControllerConfig,
    DisturbancesConfig,
    IbvsConfig,
    RecoveryConfig,
    SafetyConfig,
    SensorModel,
    ServoConfig,
    TouchConfig,
    Vec2,
    Vec6,
)
from ..vision.scene import SceneConfig
from .robot import RobotConfig


class SystemConfig(ConfigModel):
    """Section ``[system]``: the base of the robot."""

    base: Literal["floating", "fixed"] = Field(
        "floating", description="'floating': the drone flies; 'fixed': the rod is clamped"
    )
    held_base_q: Vec6 = Field(
        [0.0, 0.0, 0.0, 0.0, 0.0, 3.0],
        description="[phi, theta, psi, x, y, z] (rad, m): the clamp's pose for base = 'fixed'",
    )


class InitialConfig(ConfigModel):
    """Section ``[initial]``: the initial state (``q`` required)."""

    q: list[float] | None = Field(
        None,
        json_schema_extra={"required_in_file": True},
        description="initial configuration: [phi, theta, psi, x, y, z] (floating base) then "
        "the strains q_s (rad/m)",
    )
    qd: list[float] | None = Field(None, description="initial velocities (unset: zero)")


class DesiredConfig(ConfigModel):
    """Section ``[desired]``: the configuration whose C_L view is the IBVS reference
    (``q`` required)."""

    q: list[float] | None = Field(
        None,
        json_schema_extra={"required_in_file": True},
        description="desired configuration q* (as initial.q)",
    )


_SCENE = SceneConfig()  # the box and the target's pose (one source: tdacm.vision.scene)


class SceneSection(ConfigModel):
    """Section ``[scene]``: the target on its box, and the obstacles the arm touches."""

    target: Literal["aruco", "apriltag"] = Field("aruco", description="fiducial target")
    box_size: float = Field(
        _SCENE.box_size, gt=0, description="m, edge of the box the target lies on"
    )
    box_xy: Vec2 = Field(list(_SCENE.box_xy), description="m, the box's position in the world")
    target_yaw_deg: float = Field(
        _SCENE.target_yaw_deg, description="deg, the target's yaw about world z"
    )
    target_tilt_deg: Vec2 = Field(
        list(_SCENE.target_tilt_deg),
        description="deg, the target's tilt about world x, y (within +-30)",
    )
    obstacles: list[ObstacleConfig] = Field(
        [], description="[[scene.obstacles]]: planes, spheres, boxes, cylinders the arm touches"
    )
    contact: ContactConfig = ContactConfig()

    @field_validator("target_tilt_deg")
    @classmethod
    def _tilt(cls, v):
        if any(abs(x) > 30.0 for x in v):
            raise ValueError("must lie within +-30 deg")
        return v


class ExpectConfig(ConfigModel):
    """Section ``[expect]``: assertions checked at the start of a run (unset: none)."""

    initial_in_local_fov: bool | None = Field(None, description="target seen by C_L at start")
    initial_in_global_fov: bool | None = Field(None, description="target seen by C_G at start")


#: ``[sensors]``: the local camera's imperfections, then the proprioceptive sensors.
SensorsConfig = create_model(
    "SensorsConfig",
    __base__=ConfigModel,
    __doc__="Section ``[sensors]``: the local camera's imperfections and the proprioceptive "
    "sensors (drone pose, IMU, tendon encoders; used when estimation.source = 'estimated').",
    **{k: (f.annotation, f) for k, f in SensorModel.model_fields.items()},
    **{k: (f.annotation, f) for k, f in ProprioceptiveSensors.model_fields.items()},
)


class ScenarioConfig(ConfigModel):
    """A scenario file (top-level keys, then the sections)."""

    name: str | None = Field(
        None, description="scenario name", json_schema_extra={"required_in_file": True}
    )
    description: str = Field("", description="one line shown by `tdacm scenarios`")
    duration: float = Field(5.0, gt=0, description="s, simulated time")
    dt: float = Field(0.02, gt=0, description="s, control period")
    substeps: int = Field(PLANT_SUBSTEPS, ge=1, description="plant RK4 steps per control period")
    seed: int = Field(0, ge=0, description="seed of every random draw of the run")
    system: SystemConfig = SystemConfig()
    robot: RobotConfig = RobotConfig()
    initial: InitialConfig = InitialConfig()
    desired: DesiredConfig = DesiredConfig()
    model: ModelConfig = ModelConfig()
    controller: ControllerConfig = ControllerConfig()
    ibvs: IbvsConfig = IbvsConfig()
    servo: ServoConfig = ServoConfig()
    recovery: RecoveryConfig = RecoveryConfig()
    scene: SceneSection = SceneSection()
    cameras: CamerasConfig = CamerasConfig()
    safety: SafetyConfig = SafetyConfig()
    disturbances: DisturbancesConfig = DisturbancesConfig()
    aerodynamics: AerodynamicsConfig = AerodynamicsConfig()
    wind: WindConfig = WindConfig()
    sensors: SensorsConfig = SensorsConfig()  # type: ignore[valid-type]
    estimation: EstimationConfig = EstimationConfig()
    touch: TouchConfig = TouchConfig()
    expect: ExpectConfig = ExpectConfig()


# ----------------------------------------------------------------------------- introspection
def _model_of(annotation):
    """The record class a field holds (or the item record of an array of tables), or ``None``
    for a leaf value."""
    if _is_table_array(annotation):
        annotation = annotation.__args__[0]
    return (
        annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None
    )


def _is_table_array(annotation) -> bool:
    """``list[Record]``: an array of tables (``[[section.key]]``)."""
    args = getattr(annotation, "__args__", ())
    return (
        getattr(annotation, "__origin__", None) is list
        and len(args) == 1
        and (isinstance(args[0], type) and issubclass(args[0], BaseModel))
    )


def _by_key(model) -> dict:
    """Scenario key (the alias where one is set) -> field info."""
    return {(f.alias or k): f for k, f in model.model_fields.items()}


#: top-level keys that are values (not sections)
TOP_KEYS = tuple(k for k, f in _by_key(ScenarioConfig).items() if _model_of(f.annotation) is None)
#: the sections, in file order
SECTIONS = tuple(k for k, f in _by_key(ScenarioConfig).items() if _model_of(f.annotation))


def _walk(path, root=None):
    """``(record, field)`` of a dotted key given as parts (``("ibvs", "gain")``) in ``root``
    (default :class:`ScenarioConfig`); list indices are skipped. ``field`` is ``None`` for a
    section; raises ``KeyError`` if unknown."""
    model, field = root or ScenarioConfig, None
    table = False  # the previous part was a table of records (dict[str, Record]): skip a key
    for part in path:
        if isinstance(part, int) or table:
            table = False
            continue
        if model is None:
            raise KeyError(part)
        field = _by_key(model)[part]
        ann = field.annotation
        if getattr(ann, "__origin__", None) is dict and _model_of(ann.__args__[1]) is not None:
            model, field, table = ann.__args__[1], None, True
            continue
        model = _model_of(field.annotation)
        if model is not None:
            field = None
    return model, field


def bounds(key: str, root=None):
    """``(low, low_inclusive, high, high_inclusive)`` of a numeric scenario key (``None`` for an
    open side), from the record's constraints; ``KeyError`` for an unknown key."""
    _, field = _walk(key.split("."), root)
    if field is None:
        raise KeyError(key)
    lo = hi = None
    lo_in = hi_in = False
    for m in field.metadata:
        for attr, is_lo, inc in (("gt", True, False), ("ge", True, True), ("lt", False, False),
                                 ("le", False, True)):  # fmt: skip
            v = getattr(m, attr, None)
            if v is not None:
                if is_lo:
                    lo, lo_in = float(v), inc
                else:
                    hi, hi_in = float(v), inc
    return lo, lo_in, hi, hi_in


def key_type(key: str):
    """The annotation of a scenario key (``KeyError`` if unknown or a section)."""
    _, field = _walk(key.split("."))
    if field is None:
        raise KeyError(key)
    return field.annotation


def range_text(key: str, root=None) -> str:
    """``"> 0"``, ``">= 0"``, ``"in [0, 1)"`` ... for a key's numeric range ("" if none)."""
    lo, lo_in, hi, hi_in = bounds(key, root)
    if lo is not None and hi is not None:
        return f"in {'[' if lo_in else '('}{lo:g}, {hi:g}{']' if hi_in else ')'}"
    if lo is not None:
        return f"{'>=' if lo_in else '>'} {lo:g}"
    if hi is not None:
        return f"{'<=' if hi_in else '<'} {hi:g}"
    return ""


def _dotted(loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, str) and "." in part:  # a table's key that is a dotted path
            part = repr(part)
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


#: a part of a pydantic error location that names a member of a union type (``bool``,
#: ``list[float]``, ``literal['auto']``, ``function-after[...]``), not a key
_UNION_TAG = re.compile(
    r"(bool|int|float|str|bytes|none|list|dict|constrained-[\w-]+|[\w-]+\[.*\])"
)
#: what a union member's tag accepts, in words
_TAG_WORDS = {"bool": "true or false", "int": "an integer", "float": "a number",
              "str": "a string", "list[float]": "a list of numbers", "list[int]":
              "a list of integers", "list": "a list", "dict": "a table"}  # fmt: skip


def _is_tag(part) -> bool:
    return isinstance(part, str) and _UNION_TAG.fullmatch(part) is not None


def _union_line(errors, loc) -> str | None:
    """One line for the errors of a value that matched no member of its union type (their
    locations carry the members' tags): what each member accepts, or ``None`` if ``loc`` is
    not in a union."""
    if not any(_is_tag(p) for p in loc):
        return None
    base = tuple(p for p in loc[: next(i for i, p in enumerate(loc) if _is_tag(p))])
    words, value = [], None
    for e in errors:
        eloc = e["loc"]
        if (
            tuple(eloc[: len(base)]) != base
            or len(eloc) <= len(base)
            or not _is_tag(eloc[len(base)])
        ):
            continue
        tag = eloc[len(base)]
        if value is None and len(eloc) == len(base) + 1:
            value = e.get("input")
        if tag == "none":
            continue
        if tag.startswith("literal["):
            w = " or ".join(tag[len("literal[") : -1].split(", "))
        else:
            w = _TAG_WORDS.get(tag, "a list" if tag.startswith("list[") else tag)
        if w not in words:
            words.append(w)
    text = ", ".join(words[:-1]) + (", or " if len(words) > 1 else "") + words[-1]
    return f"{_dotted(base)} must be {text}, got {value!r}"


def error_line(exc: ValidationError, root=None) -> str:
    """The first error of ``exc`` (a validation of ``root``, default :class:`ScenarioConfig`)
    as one line naming the dotted key and what it must be (the allowed range or values, the
    known keys; for a value of a union type, what each of its members accepts)."""
    errors = exc.errors()
    err = errors[0]
    loc, kind, value = err["loc"], err["type"], err.get("input")
    if (union := _union_line(errors, loc)) is not None:
        return union
    key = _dotted(loc)
    if kind == "missing":
        return f"{key} is required"
    if kind == "extra_forbidden":
        model, _ = _walk(loc[:-1], root)
        known = ", ".join(_by_key(model))
        if len(loc) == 1 and root is None:
            if isinstance(value, dict):
                return f"unknown section [{key}] (known: {', '.join(SECTIONS)})"
            return f"unknown key {key!r} (known: {', '.join(TOP_KEYS)}, or a section)"
        return f"unknown key {key} (known: {known})"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"{key} must be a section [{key}], got {value!r}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        rng = range_text(".".join(str(p) for p in loc if not isinstance(p, int)), root)
        return f"{key} must be {rng}, got {value!r}"
    if kind == "literal_error":
        return f"{key} must be one of {err['ctx']['expected']}, got {value!r}"
    if kind in ("too_short", "too_long"):
        _, field = _walk(loc, root)
        meta = field.metadata if field is not None else []
        lo = {m.min_length for m in meta if getattr(m, "min_length", None) is not None}
        hi = {m.max_length for m in meta if getattr(m, "max_length", None) is not None}
        n = len(value) if isinstance(value, list | tuple) else "?"
        if lo and lo == hi:
            return f"{key} must have {lo.pop()} entries, got {n}"
        if lo and not hi:
            k = lo.pop()
            return f"{key} must have at least {k} entr{'y' if k == 1 else 'ies'}, got {n}"
        return f"{key}: {err['msg']}"
    simple = {
        "float_type": "a finite number",
        "float_parsing": "a finite number",
        "finite_number": "a finite number",
        "int_type": "an integer",
        "int_from_float": "an integer",
        "bool_type": "true or false",
        "string_type": "a string",
        "list_type": "a list",
        "dict_type": "a table",
    }
    if kind in simple:
        return f"{key} must be {simple[kind]}, got {value!r}"
    msg = err["msg"].removeprefix("Value error, ")
    return f"{key}: {msg}" if not msg.startswith(key) else msg


# ----------------------------------------------------------------------------- schema, docs
def json_schema() -> dict:
    """The JSON Schema of a scenario file (``tdacm schema``), with ``extends``."""
    schema = ScenarioConfig.model_json_schema(by_alias=True)
    schema["title"] = "tdacm scenario"
    schema["properties"] = {
        "extends": {
            "type": "string",
            "description": "a shipped scenario name or a TOML file (relative to this file) "
            "whose values this file inherits; chains allowed, cycles rejected",
        },
        **schema["properties"],
    }
    return schema


def _field_type(field) -> str:
    ann = field.annotation
    if getattr(ann, "__origin__", None) is Literal:
        return " \\| ".join(f"`{v!r}`".replace("'", '"') for v in ann.__args__)
    lens = {getattr(m, "min_length", None) for m in field.metadata} - {None}
    base = {float: "number", int: "integer", bool: "boolean", str: "string"}
    if ann in base:
        return base[ann]
    text = str(ann).replace("typing.", "")
    if "list[list[float]]" in text:
        return "list of [y, z]"
    if lens:
        return f"{lens.pop()} numbers"
    if "list[float]" in text:
        return "list of numbers"
    if "dict" in text:
        return "table"
    for k, v in base.items():
        if text == f"{v} | None" or text == f"{k.__name__} | None":
            return v
    return text.replace("NoneType", "None")


def _default_text(field) -> str:
    if field.is_required() or (field.json_schema_extra or {}).get("required_in_file"):
        return "required"
    d = field.get_default()
    if d is None:
        return "unset"
    if isinstance(d, bool):
        return f"`{str(d).lower()}`"
    if isinstance(d, str):
        return f'`"{d}"`'
    return f"`{d}`"


def _md_table(prefix: str, model, lines: list, first: bool = True) -> None:
    rows, subs = [], []
    for key, f in _by_key(model).items():
        sub = _model_of(f.annotation)
        if sub is not None:
            # a record inside an array of tables is a plain sub-table (``[robot.arms.rod]``)
            name = f"{prefix.strip('[]')}.{key}" if prefix else key
            subs.append((f"[{name}]" if _is_table_array(f.annotation) else name, sub))
            continue
        path = (prefix.strip("[]") + "." + key) if prefix else key
        rng = range_text(path) if f.metadata else ""
        desc = (f.description or "").replace("|", "\\|")
        rows.append(f"| `{key}` | {_field_type(f)} | {_default_text(f)} | {rng} | {desc} |")
    if rows:
        lines += [f"## `[{prefix}]`" if prefix else "## Top-level keys", ""]
        doc = _md_text(" ".join((model.__doc__ or "").split()))
        if doc:
            lines += [doc, ""]
        lines += ["| key | type | default | range | meaning |", "|---|---|---|---|---|"]
        lines += rows + [""]
    elif prefix.startswith("[") and model.__doc__:  # an array of tables of sub-tables only
        lines += [f"## `[{prefix}]`", "", _md_text(" ".join(model.__doc__.split())), ""]
    for name, sub in subs:
        _md_table(name, sub, lines, False)


def _md_text(text: str) -> str:
    """reStructuredText roles and literals of a docstring as Markdown."""
    text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", text)
    return text.replace("``", "`")


def reference_markdown() -> str:
    """docs/scenario-reference.md: every key of a scenario file with its type, default, range
    and meaning, generated from the records (``tdacm schema --markdown``)."""
    lines = [
        "# Scenario reference",
        "",
        "<!-- generated by `tdacm schema --markdown docs/scenario-reference.md`: do not edit -->",
        "",
        "A scenario is a TOML file: the top-level keys, then sections. Every key is optional "
        "except `name`, `initial.q` and `desired.q`; an omitted key takes the default below. "
        '`extends = "NAME"` (a shipped scenario or a TOML file, relative to the extending '
        "file) inherits every value the file does not set; `--config FILE` overrides the same "
        "way. `tdacm schema` prints the JSON Schema (for editor completion).",
        "",
    ]
    _md_table("", ScenarioConfig, lines)
    return "\n".join(lines).rstrip() + "\n"
