"""One default per quantity, written once: a field of the scenario's records (and the campaign
spec's) has its default as a literal in at most one place of ``src/``: the record, the library
class or function the record reads it from, or a module constant both refer to. Every other
place refers to that one (``Field(ContactModel().tip_stiffness)``, ``pretension: float =
LAW_DEFAULTS.pretension``, ``substeps: int = PLANT_SUBSTEPS``) or requires the value.

The literals are collected from the source with ``ast``: function keyword defaults and class
fields (``x: float = 0.5``, ``Field(0.5, ...)``, ``field(default=0.5)``). ``None`` ("not given")
and an empty list or tuple ("none") are not values and are skipped; another expression is a
reference, not a literal. A record field whose default is a module constant
(``Field(PLANT_SUBSTEPS)``, ``Field(PV.ROD_LENGTH)``: an upper-case name) counts as that
constant's one literal, and one declared from a dict of values (the controller's rates,
:func:`pydantic.create_model`) as the dict's.

Where a name stands for another quantity (a study's ``duration``, a rod's index ``rod``), the
place is listed in :data:`OTHER_QUANTITIES` with what the name means there and is left out; an
entry that no longer matches a literal is stale and fails.

The robot's defaults are the paper's (:mod:`tdacm.paper_values`): a record field whose
default restates one of its constants as a literal fails too (it must refer to the constant).
"""

from __future__ import annotations

import ast
import functools
import shutil
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

import pytest
from pydantic import BaseModel

from tdacm import paper_values as PV
from tdacm.campaign.spec import CampaignSpecConfig
from tdacm.sim.config import ScenarioConfig

SRC = Path(__file__).resolve().parents[1] / "src" / "tdacm"

#: The places where a record field's name means another quantity: name -> {where: what it means
#: there}, ``where`` a part of the place's ``"path Owner"`` (a folder, a file, a class or a
#: function). The other places of the name are the record's quantity and hold one literal at most.
#: (The scenario keys keep their names: the files use them.)
OTHER_QUANTITIES = {
    # robot.tendons.count: the number of tendons (paper_values')
    "count": {"viz/figures.py": "the number of snapshots"},
    # robot.rod.damping: the rod's material damping (Pa s, paper_values')
    "damping": {
        "ContactModel": "scene.contact.damping: Hunt-Crossley c (s/m)",
        "Randomization": "the env's randomize.damping: half-width of a random factor",
    },
    # robot.rod.density (paper_values')
    "density": {"Air": "the air's (aerodynamics.air_density)"},
    # sensors.dropout: C_L's frames
    "dropout": {
        "PoseSensorConfig": "a lost pose sample (sensors.pose_dropout)",
        "ImuConfig": "a lost IMU sample (sensors.imu_dropout)",
        "EncoderConfig": "a lost encoder sample (sensors.encoder_dropout)",
        "Randomization": "the env's randomize.dropout: the upper end of a range",
    },
    # the scenario's control period
    "dt": {
        "baselines/": "a study's step",
        "bench/": "a benchmark's period",
        "demo.py": "the demo's step",
        "vision/kinematic.py": "a kinematic servo's step",
    },
    # the scenario's simulated time
    "duration": {
        "baselines/": "a study's length",
        "bench/": "a benchmark's length",
        "campaign/fuzz.py": "the range of the fuzzed durations",
        "demo.py": "the demo's length",
        "system/integrate.py": "the length of a simulate() call",
    },
    # [safety]'s switch
    "enabled": {
        "AerodynamicsConfig": "[aerodynamics]'s switch",
        "TouchConfig": "[touch]'s switch",
        "PoseSensorConfig": "the pose sensor is present",
        "ImuConfig": "the IMU is present",
        "EncoderConfig": "the encoders are present",
    },
    # robot.rod.length (paper_values')
    "length": {"Cylinder": "a cylinder's length"},
    # robot.attachment.offset: the rod's base below the drone (paper_values')
    "offset": {
        "LocalCameraConfig": "robot.cameras.local.offset: C_L beyond the tip (paper_values')",
        "DistributionConfig": "a campaign distribution's switch: add the draw to the value",
        "identify/fit.py": "the first decision variable of a segment",
    },
    # sensors.pixel_noise: px std on the detected points
    "pixel_noise": {"Randomization": "the env's randomize.pixel_noise: the upper end of a range"},
    # robot.cameras.global.position: C_G's mount (paper_values')
    "position": {"ObstacleConfig": "an obstacle's position (the origin)"},
    # robot.tendons.radius is paper_values' (an obstacle record's radius is required)
    "radius": {"Sphere": "a sphere's radius", "Cylinder": "a cylinder's radius"},
    # scene.contact.rod (the backbone touches) is ContactModel's
    "rod": {
        "control/planner.py": "a rod's index",
        "estimation/contact_force.py": "a rod's index",
        "loop/sensors.py": "a rod's index",
        "loop/servo.py": "a rod's index",
        "system/aero.py": "a rod's index",
        "system/tdacm.py": "a rod's index",
        "vision/mounts.py": "a rod's index",
    },
    # the run's seed ([seed] of a scenario)
    "seed": {
        "CampaignSpecConfig": "the campaign's master seed",
        "aero/wind.py": "the turbulence's own stream",
        "bench/": "a benchmark's seed",
        "campaign/fuzz.py": "the fuzzer's seed",
        "control/model.py": "the draw of the model's perturbation",
        "estimation/proprioception.py": "the sensor suite's noise",
        "identify/": "a synthetic experiment's or an estimate's seed",
    },
    # estimation.source
    "source": {
        "campaign/spec.py": "the name of the spec in messages",
        "sim/blocks.py": "the name of the scenario in messages",
        "sim/scenario.py": "the name of the scenario's text in messages",
    },
    # the scenario's RK4 steps per control period (the plant's)
    "substeps": {
        "baselines/": "a study's own loop",
        "bench/": "a benchmark's own loop",
        "identify/": "RK4 steps per measurement sample",
    },
    # robot.rod.tip_mass: the camera at the arm's tip (paper_values')
    "tip_mass": {"rod/rod.py": "a bare rod's point mass (none unless given)"},
    # wind.velocity is SteadyWind's
    "velocity": {"wake_field": "the drone's velocity"},
    # robot.arms.marker.yaw_deg: the marker's yaw about world z
    "yaw_deg": {"viewing_pose": "the camera's rotation about its optical axis"},
}


def _records(root=(ScenarioConfig, CampaignSpecConfig)) -> list[type[BaseModel]]:
    seen: list[type[BaseModel]] = []

    def walk(model):
        if model in seen:
            return
        seen.append(model)
        for f in model.model_fields.values():
            for a in (f.annotation, *getattr(f.annotation, "__args__", ())):
                for b in (a, *getattr(a, "__args__", ())):
                    if isinstance(b, type) and issubclass(b, BaseModel):
                        walk(b)

    for r in root:
        walk(r)
    return seen


def record_fields() -> dict[str, list[str]]:
    """Field name -> ``["Record.field"]`` over the records' fields that have a default value
    (not required, not ``None``, not a section)."""
    out = defaultdict(list)
    for model in _records():
        for name, f in model.model_fields.items():
            if f.is_required():
                continue
            d = f.get_default()
            if d is None or isinstance(d, BaseModel):
                continue
            out[name].append(f"{model.__name__}.{name}")
    return out


def _is_field_call(node) -> bool:
    return isinstance(node, ast.Call) and (
        getattr(node.func, "id", None) or getattr(node.func, "attr", None)
    ) in ("Field", "field")


def _field_default(value):
    """The default expression of a class field's value (``Field(d)``, ``Field(default=d)``,
    ``field(default=d)`` or ``d``); ``None`` when there is none (``field(default_factory=...)``,
    ``Field(...)`` without one)."""
    if _is_field_call(value):
        for k in value.keywords:
            if k.arg == "default":
                return k.value
        return value.args[0] if value.args else None
    return value


def _literal(node):
    """``(True, value)`` for a literal other than ``None``, ``...`` and an empty collection;
    ``(False, None)`` for anything else (a reference, an expression)."""
    try:
        value = ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return False, None
    if value is None or value is Ellipsis or (isinstance(value, list | tuple | dict) and not value):
        return False, None
    return True, value


def _constant(node) -> str | None:
    """The module constant (an upper-case name: ``PLANT_SUBSTEPS``, ``PV.ROD_LENGTH``) a
    default refers to, through ``list(...)``/``tuple(...)``; ``None`` for anything else (a
    literal, another default: ``ContactModel().tip_stiffness``, ``_SCENE.box_size``)."""
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("list", "tuple"):
        return _constant(node.args[0]) if len(node.args) == 1 else None
    name = node.id if isinstance(node, ast.Name) else getattr(node, "attr", None)
    return name if name and name.isupper() else None


class _Default(NamedTuple):
    owner: str  # the function or class
    name: str
    line: int
    literal: bool  # written as a literal (else a reference, an expression)
    value: object
    declared: bool  # a class field declared with Field(...) / field(...): a record's field
    constant: str | None  # a record field's (Field(...)) default is this module constant


@functools.cache
def _scan(text: str) -> tuple[_Default, ...]:
    """Every keyword default and class field of a module's source (cached by its text)."""
    out = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            pos = a.posonlyargs + a.args
            pairs = list(zip(pos[len(pos) - len(a.defaults) :], a.defaults, strict=True))
            pairs += [(x, d) for x, d in zip(a.kwonlyargs, a.kw_defaults, strict=True) if d]
            for x, d in pairs:
                out.append(_Default(node.name, x.arg, d.lineno, *_literal(d), False, None))
        elif isinstance(node, ast.ClassDef):
            for st in node.body:
                if isinstance(st, ast.AnnAssign) and st.value and isinstance(st.target, ast.Name):
                    d = _field_default(st.value)
                    ok, value = _literal(d) if d is not None else (False, None)
                    declared = _is_field_call(st.value)
                    pydantic = declared and getattr(st.value.func, "id", None) == "Field"
                    const = _constant(d) if pydantic and d is not None else None
                    out.append(
                        _Default(node.name, st.target.id, st.lineno, ok, value, declared, const)
                    )
    return tuple(out)


def _scanned(root: Path):
    """``(path relative to root's parent, defaults)`` of every module under ``root``."""
    for path in sorted(root.rglob("*.py")):
        yield path.relative_to(root.parent), _scan(path.read_text(encoding="utf-8"))


def literal_defaults(root: Path = SRC) -> dict[str, list[tuple[object, str]]]:
    """Name -> ``[(literal default, "file:line Owner")]`` of every keyword default and class
    field in ``root`` written as a literal, and of every record field whose default is a module
    constant (its one literal, ``"<CONSTANT>"``; one place per constant)."""
    out = defaultdict(list)
    for rel, found in _scanned(root):
        for d in found:
            if d.literal:
                out[d.name].append((d.value, f"{rel}:{d.line} {d.owner}"))
            elif d.constant and f"<{d.constant}>" not in {v for v, _ in out[d.name]}:
                out[d.name].append((f"<{d.constant}>", f"{rel}:{d.line} {d.owner}"))
    return out


def _declared_fields(root: Path = SRC) -> set[str]:
    """Names declared as ``x: T = Field(...)`` in some class of ``root`` (a record's own
    declaration, with a literal or a reference)."""
    return {d.name for _, found in _scanned(root) for d in found if d.declared}


def _other(name: str, place: str, other: dict) -> bool:
    path, owner = place.split(":")[0], place.split()[-1]
    return any(w in f"{path} {owner}" for w in other.get(name, {}))


def written_twice(root: Path = SRC, names=None, other=None) -> dict[str, list[tuple]]:
    """The record field names (``names``, default :func:`record_fields`) whose default is a
    literal in more than one place of ``root`` where they mean the record's quantity (the
    places of ``other``, default :data:`OTHER_QUANTITIES`, left out), with those places."""
    names = record_fields() if names is None else names
    other = OTHER_QUANTITIES if other is None else other
    lit, declared = literal_defaults(root), _declared_fields(root)
    out = {}
    for name, where in names.items():
        places = [(v, w) for v, w in lit.get(name, []) if not _other(name, w, other)]
        if name not in declared:  # a record built from a dict of values: its literal is there
            places.append(("<declared from values>", ", ".join(where)))
        if len(places) > 1:
            out[name] = places
    return out


def test_every_quantity_has_one_default():
    lines = [
        f"{name}: " + "; ".join(f"{v!r} at {w}" for v, w in places)
        for name, places in sorted(written_twice().items())
    ]
    assert not lines, "defaults written more than once (keep one, refer to it):\n" + "\n".join(
        lines
    )


def test_the_list_of_other_quantities_is_current():
    """Every entry of :data:`OTHER_QUANTITIES` is a record field's name and each of its places
    still holds a literal default of that name."""
    names, lit = record_fields(), literal_defaults()
    stale = [
        f"{name}: {where}"
        for name, places in OTHER_QUANTITIES.items()
        for where in places
        if name not in names or not any(_other(name, w, {name: [where]}) for _, w in lit[name])
    ]
    assert not stale, f"no longer written there (remove from OTHER_QUANTITIES): {stale}"


def test_the_walk_sees_the_records_and_the_blocks():
    """The collection finds a record's own literal and a library record's, and takes a
    reference for what it is: ContactConfig.tip_stiffness refers to ContactModel's, the plant's
    contact_substeps to ContactConfig's."""
    lit = literal_defaults()
    where = lambda name: [(w.split(":")[0], w.split()[-1]) for _, w in lit[name]]  # noqa: E731
    assert where("confirm") == [("tdacm/loop/config.py", "RecoveryConfig")]
    assert where("tip_stiffness") == [("tdacm/contact/shapes.py", "ContactModel")]
    assert where("contact_substeps") == [("tdacm/contact/config.py", "ContactConfig")]
    assert "tilt_position_rate" not in _declared_fields()  # the controller's rates: a dict
    # the scenario's substeps: the module constant of the plant's RK4 steps
    assert where("substeps")[-1] == ("tdacm/sim/config.py", "ScenarioConfig")
    assert "<PLANT_SUBSTEPS>" in [v for v, _ in lit["substeps"]]


def _copy_src(tmp_path) -> Path:
    root = tmp_path / "tdacm"
    shutil.copytree(SRC, root, ignore=shutil.ignore_patterns("__pycache__", "*.nb*"))
    return root


def _plant(root: Path, module: str, code: str) -> None:
    target = root / module
    target.write_text(target.read_text(encoding="utf-8") + "\n\n" + code, encoding="utf-8")


@pytest.mark.parametrize(
    ("name", "code"),
    [
        ("tip_stiffness", "def _planted(x, tip_stiffness: float = 1e3):\n    return x\n"),
        ("confirm", "class _Planted:\n    confirm: int = 2\n"),
        ("margin_px", "class _Planted(ConfigModel):\n    margin_px: float = Field(20.0, ge=0)\n"),
        ("pretension", "class _Planted:\n    pretension: float = field(default=0.5)\n"),
        ("tilt_position_rate", "class _Planted:\n    tilt_position_rate: float = 6.0\n"),
        ("substeps", "def _planted(x, substeps: int = 4):\n    return x\n"),
        ("success_rmse", "class _Planted:\n    success_rmse: float = 0.01\n"),
    ],
    ids=[
        "keyword",
        "class field",
        "record field",
        "dataclass field",
        "beside a dict of values",
        "a name of other quantities elsewhere",
        "beside a module constant",
    ],
)
def test_the_walk_catches_a_planted_duplicate(tmp_path, name, code):
    root = _copy_src(tmp_path)
    assert name not in written_twice(root)
    _plant(root, "loop/touch.py", code)
    found = written_twice(root)
    assert name in found
    assert any("loop/touch.py" in w and "lanted" in w for _, w in found[name]), found[name]


def test_a_reference_is_not_a_second_literal(tmp_path):
    root = _copy_src(tmp_path)
    _plant(
        root,
        "loop/touch.py",
        "def _planted(x, confirm: int = RecoveryConfig().confirm, arms=(), lose=None):\n"
        "    return x\n",
    )
    found = written_twice(root)
    assert not {"confirm", "arms", "lose"} & set(found)


@pytest.mark.parametrize(
    "name", ["gain", "floor", "input_sigma", "level_prior", "margin_px", "confirm", "lose"]
)
def test_the_resolved_names_have_no_second_default(name):
    """The IBVS gain and floor, the force estimate's input sigma, the target filter's level
    prior and the mode switch's margin and hysteresis have their default on the scenario's
    records only (the lower-level classes take them as required arguments)."""
    places = literal_defaults().get(name, [])
    assert all(w.split(":")[0].endswith("/config.py") for _, w in places), places


# --------------------------------------------------------------------------- paper values
_INTRINSICS = ("width", "height", "fx", "fy", "cx", "cy", "near", "far")


def paper_constants() -> dict[str, list[tuple[str, object]]]:
    """Field name -> ``[(constant, value)]``: the names a record field restating a constant of
    :mod:`tdacm.paper_values` would have (the constant's name or its last words, lower case:
    ``ROD_LENGTH`` -> ``rod_length``, ``length``; the intrinsics' entries by their names)."""
    out = defaultdict(list)
    for const, value in vars(PV).items():
        if not const.isupper() or const == "PAPER_DEFAULTS_NOT_IN_PAPER":
            continue
        if const.endswith("_INTRINSICS"):
            for i, part in enumerate(_INTRINSICS):
                out[part].append((f"{const}[{i}]", value[i]))
            continue
        words = const.lower().split("_")
        for i in range(len(words)):
            out["_".join(words[i:])].append((const, value))
    return out


def _same(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, int | float) and isinstance(b, int | float):
        return float(a) == float(b)
    return a == b


def paper_values_restated(root: Path = SRC) -> list[str]:
    """The record fields (``x: T = Field(literal, ...)``) in ``root`` whose literal default is a
    :mod:`tdacm.paper_values` constant of their name."""
    consts = paper_constants()
    return [
        f"{rel}:{d.line} {d.owner}.{d.name} = {d.value!r} ({const})"
        for rel, found in _scanned(root)
        for d in found
        if d.declared and d.literal
        for const, pv in consts.get(d.name, [])
        if _same(d.value, pv)
    ]


def test_record_defaults_refer_to_the_paper_values():
    found = paper_values_restated()
    assert not found, "write these as the paper_values constant:\n" + "\n".join(found)


def test_a_restated_paper_value_is_caught(tmp_path):
    root = _copy_src(tmp_path)
    target = root / "sim" / "robot.py"
    target.write_text(
        target.read_text(encoding="utf-8") + "\n\nclass _Planted(ConfigModel):\n"
        '    mass: float = Field(0.7331, gt=0, description="kg")\n'
        "    drone_mass: float = Field(PV.DRONE_MASS)\n"
        '    fx: float = Field(886.8, description="px")\n'
        "    tilt_deg: float = Field(10.0)\n"
        "    gain: float = Field(1.0)\n"  # ROD_LENGTH's value, another quantity
        "    count: int = Field(4)\n",
        encoding="utf-8",
    )
    found = paper_values_restated(root)
    assert len(found) == 4, found
    for text in ("mass = 0.7331 (DRONE_MASS)", "fx = 886.8 (LOCAL_CAMERA_INTRINSICS[2])",
                 "tilt_deg = 10.0 (GLOBAL_CAMERA_TILT_DEG)", "count = 4 (TENDON_COUNT)"):  # fmt: skip
        assert any(text in f for f in found), (text, found)
