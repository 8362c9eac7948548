"""Scenario files (validation) and closed-loop runs (one short run in the default suite)."""

import json

import numpy as np
import pytest

from tdacm.cli import main as cli_main
from tdacm.sim import (
    SafetyMonitor,
    ScenarioError,
    Simulation,
    build_world,
    list_scenarios,
    load_scenario,
    parse_scenario,
)
from tdacm.vision import camera_pose, world_to_camera
from tdacm.viz import plot_run_dir

NAMES = [
    "custom-robot-example",
    "dual-in-fov",
    "dual-out-of-fov",
    "dual-squeeze",
    "flight-test-c",
    "ground-test-a",
    "ground-test-b",
    "paper-in-fov",
    "paper-out-of-fov",
    "touch-target",
]


def test_shipped_scenarios_load():
    assert set(NAMES) <= set(list_scenarios())
    for name in NAMES:
        sc = load_scenario(name)
        assert sc.name == name


@pytest.mark.parametrize("name", NAMES)
def test_scenario_geometry_matches_expectations(name):
    """The documented visibility conditions hold at the initial configuration."""
    sc = load_scenario(name)
    w = build_world(sc)
    r, s = w.robot, w.robot.system
    pts = w.scene.target_points_world()
    exp = sc["expect"]
    if exp["initial_in_local_fov"] is not None:
        pc = world_to_camera(pts, camera_pose(s.tip_pose(w.q0), r.tip_mount))
        assert r.local_camera.all_in_fov(pc) == exp["initial_in_local_fov"]
    if exp["initial_in_global_fov"] is not None:
        pg = world_to_camera(pts, camera_pose(s.base_pose(w.q0), r.drone_mount))
        assert r.global_camera.all_in_fov(pg) == exp["initial_in_global_fov"]
    # the desired view always sees the target
    pd = world_to_camera(pts, camera_pose(s.tip_pose(w.q_star), r.tip_mount))
    assert r.local_camera.all_in_fov(pd, 20)


def test_paper_in_fov_values():
    d = load_scenario("paper-in-fov").data
    q = np.array(d["initial"]["q"])
    assert np.allclose(q[3:6], [-0.5, 0.5, 5.0]) and np.isclose(q[2], np.pi / 18)
    assert np.allclose(d["desired"]["q"], [0, 0, 0, 0, 0, 3, 0, 0])
    assert d["dt"] == 0.02 and d["model"]["perturbation"] == 0.1


@pytest.mark.parametrize(
    "text, match",
    [
        ('description = "x"', "'name' is required"),
        ('name = "a"\n[initial]\nq = [0, 0]\n[desired]\nq = [0, 0]', "8 entries"),
        ('name = "a"\nfoo = 1', "unknown key 'foo'"),
        ('name = "a"\n[bogus]\nx = 1', r"unknown section \[bogus\]"),
        ('name = "a"\n[ibvs]\ngian = 1.0', "unknown key ibvs.gian"),
        ('name = "a"\n[ibvs]\ngain = "fast"', "ibvs.gain must be a finite number"),
        (
            'name = "a"\nduration = -1\n[initial]\nq = [0,0,0,0,0,3,0,0]\n[desired]\n'
            "q = [0,0,0,0,0,3,0,0]",
            "duration must be > 0",
        ),
        ('name = "a"\n[scene]\nbox_xy = [1, 2, 3]', "box_xy must have 2 entries"),
        ("name = ", "invalid TOML"),
    ],
)
def test_invalid_scenarios_rejected(text, match):
    with pytest.raises(ScenarioError, match=match):
        parse_scenario(text, "test.toml")


def test_config_override(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("duration = 1.5\n[ibvs]\ngain = 0.7\n")
    sc = load_scenario("paper-in-fov", cfg)
    assert sc["duration"] == 1.5 and sc["ibvs"]["gain"] == 0.7
    assert sc["ibvs"]["mode"] == "mean"  # from the scenario file, not overridden
    cfg.write_text("[ibvs]\nspeed = 1\n")
    with pytest.raises(ScenarioError, match="unknown key ibvs.speed"):
        load_scenario("paper-in-fov", cfg)


def test_safety_monitor_rule():
    m = SafetyMonitor(True, 0.05, 0.0, grace=0.0)
    assert m.check(0.0, 0.2) and m.check(0.02, 0.2)
    assert not m.check(0.04, 0.22)
    assert "grew" in m.reason
    m = SafetyMonitor(True, 0.05, 0.005, grace=0.0)
    assert m.check(0.0, 0.01) and m.check(0.02, 0.012)  # noise-level increase ignored


def test_short_closed_loop_end_to_end(tmp_path):
    """Fixed-base rod (ground test A), cameras rendered and detected every step, 10 %
    perturbed model: the image error drops; all outputs are written."""
    sc = load_scenario("ground-test-a").with_overrides({"cameras": {"global_renderer": "planar"}})
    arrays, summary = Simulation(sc, duration=1.5).run(tmp_path)
    plot_run_dir(tmp_path)  # the figures, drawn from the folder's data
    assert not summary["terminated"], summary["termination_reason"]
    assert summary["final_rmse"] < 0.5 * summary["initial_rmse"]
    assert np.all(arrays["u"] >= 0.0)
    assert arrays["detected_local"].all()
    for f in (
        "timeseries.csv",
        "timeseries.npz",
        "summary.json",
        "state_errors.png",
        "actuation.png",
        "features.png",
    ):
        assert (tmp_path / f).is_file(), f
    s = json.loads((tmp_path / "summary.json").read_text())
    for key in (
        "scenario",
        "seed",
        "initial_rmse",
        "final_rmse",
        "time_to_0.01",
        "mode_switch_time",
        "terminated",
        "termination_reason",
        "wall_time_s",
        "max_tension",
        "max_thrust",
    ):
        assert key in s


def test_cli_scenarios(capsys):
    assert cli_main(["scenarios"]) == 0
    out = capsys.readouterr().out
    for name in NAMES:
        assert name in out


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_scenario_converges(name, tmp_path):
    sc = load_scenario(name).with_overrides({"cameras": {"global_every": 0}})
    _, summary = Simulation(sc).run(tmp_path)
    assert not summary["terminated"], summary["termination_reason"]
    assert summary["time_to_0.01"] is not None
    if name == "paper-in-fov":
        assert summary["time_to_0.01"] <= 5.0
    if name in ("paper-out-of-fov", "ground-test-b"):
        assert summary["mode_switch_time"] is not None
