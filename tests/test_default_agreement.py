"""One default per quantity: every field of the scenario's records (and the campaign spec's) that
also appears as a keyword default of a function or a class field anywhere in ``src/`` has the
same default there.

The keyword defaults are collected from the source with ``ast`` (literal values only: a default
written as the record's own value, ``IbvsConfig().gain``, cannot disagree). ``None`` means "not
given" and is skipped. A name that stands for different quantities in different places is listed
in :data:`OTHER_QUANTITIES` with what it means where; the test fails when such an entry no longer
names anything that differs (a stale entry) and for any other name with two defaults.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest
from pydantic import BaseModel

from tdacm.campaign.spec import CampaignSpecConfig
from tdacm.sim.config import ScenarioConfig

SRC = Path(__file__).resolve().parents[1] / "src" / "tdacm"

#: Names that mean different quantities in different places (the scenario keys keep their names:
#: the files use them).
OTHER_QUANTITIES = {
    "damping": "robot.rod.damping (Pa s, material) vs scene.contact.damping (s/m, Hunt-Crossley)",
    "density": "robot.rod.density (the rod's material) vs aero's Air density",
    "dt": "the scenario's control period vs the step of a study, a demo or a kinematic servo",
    "duration": "the scenario's simulated time vs the length of a study, a benchmark or a demo",
    "enabled": "each section's own switch ([safety], [aerodynamics], [touch])",
    "length": "robot.rod.length vs an obstacle's (a cylinder's) length",
    "offset": "robot.attachment.offset vs robot.cameras.local.offset vs identify's sample offset",
    "position": "a camera's mount position vs an obstacle's position",
    "radius": "robot.tendons.radius vs an obstacle's radius",
    "rod": "scene.contact.rod (the backbone touches) vs a rod section's index",
    "source": "estimation.source vs the name of a file in messages",
    "substeps": "the scenario's RK4 steps per control period vs identify's per measurement sample",
    "tip_mass": "robot.rod.tip_mass (the camera at the arm's tip) vs a bare rod section's point "
    "mass (none unless given: the inner joints of a SectionedRod, the analytic cantilevers)",
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


def _norm(v):
    if isinstance(v, dict):
        return tuple(sorted((k, _norm(x)) for k, x in v.items()))
    if isinstance(v, list | tuple):
        return tuple(_norm(x) for x in v)
    if isinstance(v, bool) or not isinstance(v, int | float):
        return v
    return float(v)


def record_defaults() -> dict[str, list[tuple[object, str]]]:
    """Field name -> ``[(default, "Record.field")]`` over every record."""
    out = defaultdict(list)
    for model in _records():
        for name, f in model.model_fields.items():
            if f.is_required():
                continue
            d = f.get_default()
            if d is None or isinstance(d, BaseModel):
                continue
            out[name].append((_norm(d), f"{model.__name__}.{name}"))
    return out


def keyword_defaults(root: Path = SRC) -> dict[str, list[tuple[object, str]]]:
    """Parameter or class-field name -> ``[(literal default, "file:line name")]`` in ``root``."""
    out = defaultdict(list)
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            pairs = []
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                a = node.args
                pos = a.posonlyargs + a.args
                pairs += zip(pos[len(pos) - len(a.defaults) :], a.defaults, strict=True)
                pairs += [
                    (x, d)
                    for x, d in zip(a.kwonlyargs, a.kw_defaults, strict=True)
                    if d is not None
                ]
                pairs = [(x.arg, d) for x, d in pairs]
            elif isinstance(node, ast.ClassDef):
                pairs = [
                    (st.target.id, st.value)
                    for st in node.body
                    if isinstance(st, ast.AnnAssign)
                    and st.value is not None
                    and isinstance(st.target, ast.Name)
                ]
            for name, default in pairs:
                try:
                    value = ast.literal_eval(default)
                except ValueError:
                    continue  # an expression (the record's own value, a constant): no literal
                if value is not None:
                    out[name].append((_norm(value), f"{rel}:{default.lineno} {node.name}"))
    return out


def disagreements() -> dict[str, list[tuple[object, str]]]:
    """Names with more than one default among the records and the keyword defaults."""
    rec, kw = record_defaults(), keyword_defaults()
    out = {}
    for name, where in rec.items():
        places = where + kw.get(name, [])
        if len({v for v, _ in places}) > 1:
            out[name] = places
    return out


def test_every_quantity_has_one_default():
    found = disagreements()
    bad = {k: v for k, v in found.items() if k not in OTHER_QUANTITIES}
    lines = [
        f"{name}: " + "; ".join(f"{v!r} at {w}" for v, w in places)
        for name, places in sorted(bad.items())
    ]
    assert not lines, "defaults disagree:\n" + "\n".join(lines)


def test_the_list_of_names_with_two_meanings_is_current():
    stale = sorted(set(OTHER_QUANTITIES) - set(disagreements()))
    assert not stale, f"no longer differ (remove from OTHER_QUANTITIES): {stale}"


def test_the_walk_sees_the_constructors():
    """The collection finds a keyword default of a block's constructor and a record field."""
    kw = keyword_defaults()
    assert any("loop/plant.py" in w for _, w in kw["contact_substeps"])
    assert "IbvsConfig.gain" in [w for _, w in record_defaults()["gain"]]


@pytest.mark.parametrize("name", ["gain", "floor", "input_sigma", "level_prior"])
def test_the_resolved_names_have_no_second_default(name):
    """The IBVS gain and floor, the force estimate's input sigma and the target filter's level
    prior have their default on the scenario's records only (the lower-level classes take them
    as required keywords)."""
    kw = keyword_defaults()
    assert not kw.get(name)
