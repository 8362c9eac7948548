"""The scenario configuration: typed records with one default per value, errors of one line,
a real TOML writer, ``extends``, ``[controller.options]``, campaign ranges and the generated
reference."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import tdacm
from tdacm import paper_values as PV
from tdacm.base import Quadrotor
from tdacm.campaign.spec import CampaignSpecError, parse_spec, sample_overrides
from tdacm.estimation import EstimatorConfig, SensorSuiteConfig
from tdacm.loop.config import IbvsConfig, RecoveryConfig
from tdacm.rod import Rod, Tendons
from tdacm.sim import build_loop
from tdacm.sim import config as C
from tdacm.sim.robot import build_robot
from tdacm.sim.runner import Simulation
from tdacm.sim.scenario import (
    ScenarioError,
    list_scenarios,
    load_scenario,
    scenario_to_toml,
)

ROOT = Path(__file__).resolve().parents[2]
ANALYTIC = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}


# ------------------------------------------------------------------ one default per value
def test_servo_takes_the_scenario_records_whole():
    ib, rc = IbvsConfig(), RecoveryConfig()
    sc = load_scenario("ground-test-a").with_overrides(ANALYTIC)
    servo = build_loop(sc).loop.servo
    assert servo.config == sc.config.ibvs and servo.recovery == sc.config.recovery
    assert servo.config.target_level_prior_deg == 0.5 == ib.target_level_prior_deg
    assert servo.target_filter.level_prior == pytest.approx(np.radians(0.5))
    assert servo.target_filter.window == ib.filter_window
    assert servo.shaping.max_joint_rate == 0.4 and servo.recovery.lose == rc.lose == 5


def test_filter_and_sensor_defaults_are_the_scenario_defaults():
    sc = load_scenario("ground-test-a")
    assert EstimatorConfig.from_section(sc["estimation"]) == EstimatorConfig()
    assert SensorSuiteConfig.from_section(sc["sensors"]) == SensorSuiteConfig()


def test_paper_values_reach_every_constructor():
    rod, quad, tendons = Rod(), Quadrotor(), Tendons.parallel()
    assert (rod.length, rod.diameter, rod.density) == (
        PV.ROD_LENGTH,
        PV.ROD_DIAMETER,
        PV.ROD_DENSITY,
    )
    assert quad.mass == PV.DRONE_MASS and tuple(quad.inertia) == PV.DRONE_INERTIA
    assert tendons.n == PV.TENDON_COUNT and tendons.max_tension == PV.TENDON_MAX_TENSION
    # a scenario without [robot] builds the paper's system
    robot = build_robot(load_scenario("paper-in-fov").config.robot)
    ref = tdacm.paper_system()
    assert robot.system.n == ref.n == 8
    q = np.r_[0, 0, 0, 0, 0, 3, 0.3, -0.2]
    mine, paper = robot.system.terms(q, np.zeros(8)), ref.terms(q, np.zeros(8))
    for name in ("M", "K", "tau_ext", "B"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(paper, name))


# ------------------------------------------------------------------ errors of one line
@pytest.mark.parametrize(
    "text, needles",
    [
        ('[ibvs]\nmode = "fast"', ["ibvs.mode", "'current', 'desired' or 'mean'", "'fast'"]),
        ("[sensors]\ndropout = 1.0", ["sensors.dropout", "in [0, 1)"]),
        ("[sensors]\npixel_noise = -1.0", ["sensors.pixel_noise", ">= 0"]),
        ("[controller]\nmax_tilt = 2.0", ["controller.max_tilt", "in (0, 1.5708)"]),
        ("[controller]\nki = 1.0", ["unknown key controller.ki", "profile, class, options"]),
        ("[recovery]\nconfirm = 1.5", ["recovery.confirm", "integer"]),
        ("[robot.drone]\ninertia = [1, 2]", ["robot.drone.inertia", "3 entries"]),
        ("[model]\ngravity_feedforward = 1", ["model.gravity_feedforward", "true or false"]),
        ("[ibvs]\ntarget_level_normal = [0, 0, 0]", ["ibvs.target_level_normal"]),
        ("[scene]\ntarget_tilt_deg = [0, 40]", ["scene.target_tilt_deg", "30"]),
        ("ibvs = 3", ["ibvs must be a section"]),
    ],
)
def test_errors_are_one_line_naming_file_key_and_range(tmp_path, text, needles):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text + "\n")
    with pytest.raises(ScenarioError) as exc:
        load_scenario("paper-in-fov", cfg)
    msg = str(exc.value)
    assert "\n" not in msg and str(cfg) in msg, msg
    for n in needles:
        assert n in msg, (n, msg)


def test_cross_field_checks_kept():
    base = load_scenario("paper-in-fov")
    with pytest.raises(ScenarioError, match="initial.q must have 8 entries"):
        base.with_overrides({"initial": {"q": [0.0, 0.0]}})
    with pytest.raises(ScenarioError, match="controller_truth needs estimation.source"):
        base.with_overrides({"estimation": {"controller_truth": "qd[3:5]"}})


# ------------------------------------------------------------------ the TOML writer
@pytest.mark.parametrize("name", list_scenarios())
def test_written_scenario_reloads_to_the_same_configuration(name, tmp_path):
    sc = load_scenario(name)
    text = scenario_to_toml(sc)
    assert text.startswith(f"# resolved from scenario {name}\n")
    path = tmp_path / "scenario.toml"
    path.write_text(text)
    again = load_scenario(str(path))
    assert again.data == sc.data
    assert json.dumps(again.data, sort_keys=True) == json.dumps(sc.data, sort_keys=True)


# ------------------------------------------------------------------ extends
def _three_line(tmp_path) -> Path:
    p = tmp_path / "variant.toml"
    p.write_text('extends = "paper-in-fov"\n[cameras]\nlocal_renderer = "analytic"\n')
    return p


def test_extends_inherits_everything_not_set(tmp_path):
    sc = load_scenario(str(_three_line(tmp_path)))
    ref = load_scenario("paper-in-fov")
    assert sc["cameras"]["local_renderer"] == "analytic"
    d, r = json.loads(json.dumps(sc.data)), json.loads(json.dumps(ref.data))
    d["cameras"].pop("local_renderer")
    r["cameras"].pop("local_renderer")
    assert d == r
    assert sc["ibvs"]["gain"] == 2.0 and sc["ibvs"]["mode"] == "mean"  # not the defaults


def test_extends_variant_converges(tmp_path):
    sc = load_scenario(str(_three_line(tmp_path)))
    _, summary = Simulation(sc).run()
    assert sc["duration"] == 5.0
    assert not summary["terminated"], summary["termination_reason"]
    assert summary["final_rmse"] <= 0.01, summary["final_rmse"]


def test_extends_chains_paths_and_cycles(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.toml").write_text('extends = "ground-test-a"\nduration = 1.5\n')
    (tmp_path / "c.toml").write_text('extends = "sub/b.toml"\n[ibvs]\ngain = 0.7\n')
    sc = load_scenario(str(tmp_path / "c.toml"))
    assert sc["duration"] == 1.5 and sc["ibvs"]["gain"] == 0.7 and sc.name == "ground-test-a"
    # a --config file overrides the scenario named with it: an extends there is refused
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('extends = "sub/b.toml"\nseed = 3\n')
    with pytest.raises(ScenarioError, match="extends is not allowed in a --config file") as exc:
        load_scenario("paper-in-fov", cfg)
    assert str(cfg) in str(exc.value) and "'paper-in-fov'" in str(exc.value)
    (tmp_path / "x.toml").write_text('extends = "y.toml"\n')
    (tmp_path / "y.toml").write_text('extends = "x.toml"\n')
    with pytest.raises(ScenarioError, match="extends cycle") as exc:
        load_scenario(str(tmp_path / "x.toml"))
    assert "x.toml -> " in str(exc.value) and "\n" not in str(exc.value)
    (tmp_path / "z.toml").write_text('extends = "no-such-scenario"\n')
    with pytest.raises(ScenarioError, match="unknown scenario 'no-such-scenario'"):
        load_scenario(str(tmp_path / "z.toml"))


# ------------------------------------------------------------------ [controller.options]
PID = """
from tdacm.loop.lowlevel import AdaptiveLowLevel


class PID(AdaptiveLowLevel):
    def __init__(self, context):
        super().__init__(context)
        self.ki = context.options["ki"]
        self.options = dict(context.options)
"""


def test_user_controller_found_from_the_current_folder_gets_its_options(tmp_path, monkeypatch):
    pkg = tmp_path / "mylab"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "pid.py").write_text(PID)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delitem(sys.modules, "mylab", raising=False)
    monkeypatch.delitem(sys.modules, "mylab.pid", raising=False)
    path_before = list(sys.path)
    sc = load_scenario("paper-in-fov").with_overrides(
        {**ANALYTIC, "controller": {"class": "mylab.pid:PID", "options": {"ki": 1.0}}}
    )
    loop = build_loop(sc).loop
    assert type(loop.controller).__name__ == "PID"
    assert loop.controller.ki == 1.0
    assert loop.controller.options["max_tilt"] == 0.35  # the law's keys are there too
    assert sys.path == path_before  # the search does not leave the folder on sys.path
    sys.modules.pop("mylab.pid", None)
    sys.modules.pop("mylab", None)


def test_user_controller_found_from_the_scenario_folder(tmp_path, monkeypatch):
    lab = tmp_path / "lab"
    (lab / "mylab2").mkdir(parents=True)
    (lab / "mylab2" / "__init__.py").write_text("")
    (lab / "mylab2" / "pid.py").write_text(PID)
    (lab / "sc.toml").write_text(
        'extends = "paper-in-fov"\n[cameras]\nlocal_renderer = "analytic"\n'
        'global_renderer = "planar"\n'
        '[controller]\nclass = "mylab2.pid:PID"\n[controller.options]\nki = 2.5\n'
    )
    monkeypatch.chdir(tmp_path)  # not the scenario's folder
    loop = build_loop(load_scenario(str(lab / "sc.toml"))).loop
    assert loop.controller.ki == 2.5
    sys.modules.pop("mylab2.pid", None)
    sys.modules.pop("mylab2", None)


# ------------------------------------------------------------------ build from the records
def test_loop_blocks_take_the_scenario_values():
    sc = load_scenario("paper-in-fov").with_overrides(
        {**ANALYTIC, "ibvs": {"filter_window": 17, "target_level_prior_deg": 0.25},
         "recovery": {"lost_timeout": 0.7, "margin_px": 11.0}}
    )  # fmt: skip
    servo = build_loop(sc).loop.servo
    assert servo.target_filter.window == 17 and servo.config.target_level_prior_deg == 0.25
    assert servo.recovery.lost_timeout == 0.7 and servo.recovery.margin_px == 11.0
    assert servo.shaping.soft_start == sc["ibvs"]["soft_start"] == 0.4


# ------------------------------------------------------------------ campaign distributions
def _spec(dists: str) -> str:
    return f'scenario = "paper-in-fov"\nruns = 4\nseed = 1\n[distributions]\n{dists}\n'


def test_choice_of_strings_and_booleans():
    data = load_scenario("paper-in-fov").data
    spec = parse_spec(
        _spec(
            '"ibvs.mode" = { kind = "choice", values = ["mean", "current"] }\n'
            '"ibvs.accel_feedforward" = { kind = "choice", values = [true, false] }'
        ),
        "s.toml",
        data,
    )
    seen = {(o["ibvs"]["mode"], o["ibvs"]["accel_feedforward"])
            for o in (sample_overrides(spec, data, s) for s in range(40))}  # fmt: skip
    assert seen == {("mean", True), ("mean", False), ("current", True), ("current", False)}
    with pytest.raises(CampaignSpecError, match="ibvs.mode must be one of"):
        parse_spec(_spec('"ibvs.mode" = { kind = "choice", values = ["mean", "fast"] }'),
                   "s.toml", data)  # fmt: skip


@pytest.mark.parametrize(
    "dist",
    [
        '"sensors.pixel_noise" = { kind = "normal", std = 1.0 }',
        '"sensors.dropout" = { kind = "uniform", low = 0.0, high = 1.2 }',
        '"sensors.pixel_noise" = { kind = "choice", values = [1.0, -1.0] }',
        '"controller.max_tilt" = { kind = "fixed", value = 2.0 }',
        '"sensors.pixel_noise" = { kind = "truncnormal", mean = -3, std = 1, high = -1 }',
    ],
)
def test_distributions_leaving_the_valid_range_rejected_on_load(dist):
    data = load_scenario("paper-in-fov").data
    key = dist.split('"')[1]
    with pytest.raises(CampaignSpecError, match=key.replace(".", r"\.")):
        parse_spec(_spec(dist), "s.toml", data)


def test_truncnormal_stays_in_range_and_is_seeded():
    data = load_scenario("paper-in-fov").data
    spec = parse_spec(
        _spec('"sensors.pixel_noise" = { kind = "truncnormal", mean = 0.5, std = 1.0 }\n'
              '"sensors.dropout" = { kind = "truncnormal", mean = 0.9, std = 0.3, low = 0.1 }'),
        "s.toml", data,
    )  # fmt: skip
    draws = [sample_overrides(spec, data, s)["sensors"] for s in range(300)]
    noise = np.array([d["pixel_noise"] for d in draws])
    drop = np.array([d["dropout"] for d in draws])
    assert noise.min() >= 0.0 and (noise > 1.5).any()  # bell-shaped, clipped at 0
    assert drop.min() >= 0.1 and drop.max() < 1.0
    assert draws[7] == sample_overrides(spec, data, 7)["sensors"]
    # every sampled run is a valid scenario
    load_scenario("paper-in-fov").with_overrides({"sensors": draws[0]})


def test_shipped_specs_still_load():
    from tdacm.campaign.spec import load_spec

    for f in sorted((ROOT / "examples" / "campaigns").glob("*.toml")):
        assert load_spec(f).runs >= 1


# ------------------------------------------------------------------ schema and reference
def test_json_schema_and_cli(capsys):
    from tdacm.cli import main

    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert "extends" in schema["properties"] and "ibvs" in schema["properties"]
    ibvs = schema["$defs"]["IbvsConfig"]["properties"]
    assert ibvs["mode"]["enum"] == ["current", "desired", "mean"]
    assert ibvs["gain"]["exclusiveMinimum"] == 0 and ibvs["gain"]["description"]
    assert schema["$defs"]["ControllerConfig"]["properties"]["class"]["type"] == "string"


def test_committed_reference_is_the_generated_one():
    committed = (ROOT / "docs" / "scenario-reference.md").read_text(encoding="utf-8")
    assert committed == C.reference_markdown(), (
        "regenerate: tdacm schema --markdown docs/scenario-reference.md"
    )


def test_every_field_is_described():
    def walk(model, prefix):
        for key, f in C._by_key(model).items():
            sub = C._model_of(f.annotation)
            if sub is not None:
                yield from walk(sub, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}", f

    missing = [k for k, f in walk(C.ScenarioConfig, "") if not f.description]
    assert not missing
    assert C.range_text("sensors.dropout") == "in [0, 1)"
    assert C.bounds("controller.max_tilt") == (0.0, False, math.pi / 2, False)
