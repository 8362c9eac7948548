"""System identification: the shooting kernel, synthetic recordings, the fit, observability,
the outputs and the command line (docs/identify.md). Small recordings: seconds each."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.identify import (
    DEFAULT_TRUTH,
    fisher_report,
    identify,
    load_recording,
    parse_params,
    robot_toml,
    synthesize,
    truth_errors,
)
from tdacm.identify import kernels as IK
from tdacm.identify.data import model_of_scenario
from tdacm.identify.params import FRICTION_V0
from tdacm.sim import build_world, parse_scenario
from tdacm.system import simulate

ROD = ["E", "damping", "radius"]


@pytest.fixture(scope="module")
def clamped():
    return model_of_scenario("ground-test-a")[0]


def test_shooting_is_the_system_rk4_and_its_poses(clamped):
    sysm = clamped.system
    u = np.array([3.0, 1.0, 0.0, 0.0])
    ref = simulate(sysm, [0.1, -0.2], duration=1.0, dt=0.01, u=u, method="rk4")
    t = len(ref.t)
    pred = clamped.simulate({}, ref.q[:1], ref.qd[:1], [0], [t], np.tile(u, (t, 1)), 0.01)
    np.testing.assert_array_equal(pred.q, ref.q)
    np.testing.assert_array_equal(pred.qd, ref.qd)
    np.testing.assert_allclose(pred.tip[-1], sysm.tip_pose(ref.q[-1]), atol=1e-14)
    # two segments: the second restarts from its own state
    pred2 = clamped.simulate({}, ref.q[[0, 50]], ref.qd[[0, 50]], [0, 50], [50, t],
                             np.tile(u, (t, 1)), 0.01)  # fmt: skip
    np.testing.assert_array_equal(pred2.q[50:], ref.q[50:])


def test_tendon_friction_is_the_documented_law_and_dissipates(clamped):
    sysm = clamped.system
    m = sysm.model_arrays
    q, qd = np.array([0.4, -0.1]), np.array([0.3, 0.2])
    u = np.array([2.0, 1.0, 0.5, 0.0])
    mu, cv = 0.05, 0.8
    ue = IK.effective_input(q, qd, u, m, 1.0, mu, cv, FRICTION_V0)
    ldot = -sysm.tendon_matrix(q).T @ qd
    want = np.maximum(u * (1 + mu * np.tanh(ldot / FRICTION_V0)) + cv * ldot, 0.0)
    np.testing.assert_allclose(ue, want, rtol=1e-14)
    # the friction's power on the rod, -ldot . (T_eff - T), is never positive
    assert -(ldot @ (ue - u)) <= 0.0
    # a swinging rod with friction loses more energy than without
    q0 = np.array([0.6, 0.0])
    ends = []
    for f in (0.0, 0.1):
        p = clamped.simulate({"friction": f}, q0[None], np.zeros((1, 2)), [0], [150],
                             np.tile([1.0, 1.0, 1.0, 1.0], (150, 1)), 0.01)  # fmt: skip
        e = sysm.energy(p.q[-1], p.qd[-1])["total"]
        ends.append(e)
    assert ends[1] < ends[0]


def test_synthetic_noise_is_as_documented():
    rec = synthesize("tendon-chirp", seed=5, duration=6.0)
    sysm = rec.model.build(rec.truth)
    _, tip = rec.model.poses(sysm, rec.q)
    e = (rec.tip[:, :3, 3] - tip[:, :3, 3]).ravel()
    assert abs(e.std() / 0.5e-3 - 1) < 0.05  # 1800 draws: 5 % is > 3 sigma of the estimate
    u_true = np.load  # noqa: F841 (the true tensions are the profile)
    exp_u = rec.u[:, :]
    from tdacm.identify.experiments import EXPERIMENTS

    true_u = EXPERIMENTS["tendon-chirp"].profile(rec.t, None)
    rel = (exp_u - true_u)[true_u > 0.5] / true_u[true_u > 0.5]
    assert abs(rel.std() / 0.02 - 1) < 0.05


def test_a_short_clamped_recording_identifies_the_rod_from_30_percent_off():
    # 8 s hold four steps only: scaling E, damping, tip mass and radius together is then
    # nearly invisible (only the rod's own, known, mass breaks the tie: the 20 s
    # experiments pin it down, see docs/identify.md), so the tip mass is given here
    rec = synthesize("tendon-steps", seed=3, duration=8.0, noise={"tension": 0.0})
    start = {k: 1.3 * DEFAULT_TRUTH[k] for k in ROD}
    res = identify(rec, ROD, start=start, max_nfev=30, fixed={"tip_mass": rec.truth["tip_mass"]})
    err = truth_errors(res, rec.truth)
    assert res.success
    for k in ROD:
        # mocap noise only: the estimate is within 4 sigma of its own standard deviation
        assert abs(err[k]) < max(4 * res.rel_std[k], 2e-3), (k, err[k], res.rel_std[k])
    assert res.residual_variance == pytest.approx(1.0, abs=0.15)
    assert abs(res.corr[0, 1]) <= 1.0


def test_observability_per_experiment():
    steps = synthesize("tendon-steps", seed=1, duration=8.0)
    rod = ["E", "damping", "tip_mass", "radius"]
    rep = fisher_report(steps, rod)
    assert rep["rank"] == 4
    # a known clip-on mass fixes the common scale of E, damping, tip mass and radius
    loaded = synthesize("tendon-steps-loaded", seed=1, duration=8.0)
    both_rod = fisher_report([steps, loaded], rod)
    assert both_rod["crlb"]["E"] < rep["crlb"]["E"] / 10
    hover = synthesize("hover", seed=1, duration=3.0)
    alone = fisher_report(hover, ["drone_mass"])
    both = fisher_report(hover, ["drone_mass", "thrust"])
    assert alone["crlb"]["drone_mass"] < 1e-3
    # thrust constant and drone mass enter mostly as k_T / m (only the rod's 4 % of the mass
    # tells them apart): together, the mass's bound is more than 10 times worse
    assert both["condition"] > 1e3
    assert both["crlb"]["drone_mass"] > 10 * alone["crlb"]["drone_mass"]


def test_params_parsing():
    assert parse_params("E, inertia,E") == ["E", "inertia_x", "inertia_y", "inertia_z"]
    with pytest.raises(ValueError, match="unknown parameter 'mass_of_rod'"):
        parse_params("mass_of_rod")


def test_the_robot_block_pastes_into_a_scenario(tmp_path):
    rec = synthesize("tendon-steps", seed=2, duration=4.0, out=tmp_path / "rec")
    res = identify(load_recording(tmp_path / "rec"), ["E", "radius"], max_nfev=3)
    block = robot_toml(res)
    data = tomllib.loads(block)
    assert data["robot"]["rod"]["youngs_modulus"] == pytest.approx(res.values["E"], rel=1e-5)
    assert data["robot"]["tendons"]["radius"] == pytest.approx(res.values["radius"], rel=1e-5)
    base = (tmp_path / "rec" / "scenario.toml").read_text().split("[robot.rod]")[0]
    world = build_world(parse_scenario(base + "\n" + block))
    assert world.robot.system.rod.youngs_modulus == pytest.approx(res.values["E"], rel=1e-5)
    assert rec.truth == DEFAULT_TRUTH or set(rec.truth) <= set(DEFAULT_TRUTH)


def test_cli_identify_writes_the_report_and_names_bad_flags(tmp_path, capsys):
    synthesize("tendon-chirp", seed=4, duration=4.0, out=tmp_path / "rec")
    out = tmp_path / "fit"
    code = main(["identify", str(tmp_path / "rec"), "--params", "E,tip_mass", "--out", str(out)])
    assert code == 0
    for name in ("identification.json", "robot.toml", "identification.png"):
        assert (out / name).is_file()
    cap = capsys.readouterr()
    assert "[robot.rod]" in cap.out
    # progress on stderr: what is fitted, then each iteration
    assert "identify: fitting E, tip_mass to 1 recording" in cap.err
    assert "identify: iteration 1, cost " in cap.err
    assert main(["-q", "identify", str(tmp_path / "rec"), "--params", "E", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    # -q: no progress (a misfit warning, here E alone at 3.5 x the noise, still shows)
    assert "identify: " not in err and "iteration" not in err
    assert main(["identify", str(tmp_path / "rec"), "--params", "E,bogus"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --params")
    assert main(["identify", str(tmp_path / "rec"), "--params", "drone_mass"]) == 2
    assert "--params: drone_mass needs a recording with a flying base" in capsys.readouterr().err
    assert main(["identify", str(tmp_path / "nothing"), "--params", "E"]) == 2
    assert "RECORDING" in capsys.readouterr().err


def test_an_mcap_with_a_labs_topic_names_gives_the_same_recording(tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap_ros2.writer import Writer

    from tdacm.identify.data import matrix_to_pose7
    from tdacm.live.msgdefs import schema_text

    folder = tmp_path / "rec"
    synthesize("tendon-chirp", seed=6, duration=1.0, out=folder)
    ref = load_recording(folder)
    lab = tmp_path / "lab.mcap"
    t0_ns = 1_764_633_600 * 10**9
    tip7 = matrix_to_pose7(ref.tip)
    with open(lab, "wb") as f, Writer(f) as w:
        pose = w.register_msgdef("geometry_msgs/msg/PoseStamped",
                                 schema_text("geometry_msgs/msg/PoseStamped"))  # fmt: skip
        joints = w.register_msgdef("sensor_msgs/msg/JointState",
                                   schema_text("sensor_msgs/msg/JointState"))  # fmt: skip
        for k, t in enumerate(ref.t):
            ns = t0_ns + round(t * 1e9)
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            x, y, z, qx, qy, qz, qw = tip7[k]
            w.write_message("/vicon/tip", pose, {
                "header": {"stamp": stamp, "frame_id": "vicon_world"},
                "pose": {"position": {"x": x, "y": y, "z": z},
                         "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}}, ns, ns)  # fmt: skip
            w.write_message("/loadcells", joints, {
                "header": {"stamp": stamp}, "name": ["a", "b", "c", "d"],
                "effort": ref.u[k].tolist()}, ns, ns)  # fmt: skip
    (tmp_path / "map.toml").write_text(
        '[topics]\n"/vicon/tip" = "tip_pose"\n"/loadcells" = { effort = "tensions" }\n'
    )
    from tdacm.recording import load_topic_map

    (tmp_path / "lab.experiment.toml").write_text("[added]\ntip_mass = 0.02\n")
    got = load_recording(lab, folder / "scenario.toml", load_topic_map(tmp_path / "map.toml"))
    assert got.added == {"tip_mass": 0.02}
    np.testing.assert_allclose(got.t, ref.t, atol=1e-9)
    np.testing.assert_array_equal(got.u, ref.u)
    np.testing.assert_allclose(got.tip, ref.tip, atol=1e-12)


def test_a_loaded_experiment_carries_its_known_mass_through_the_folder(tmp_path):
    rec = synthesize("tendon-steps-loaded", seed=2, duration=1.0, out=tmp_path / "rec")
    got = load_recording(tmp_path / "rec")
    assert got.added == rec.added == {"tip_mass": 0.02}
    v = got.values({"tip_mass": 0.01})
    assert v["tip_mass"] == pytest.approx(0.03)
    # the recorded motion is that of the loaded rod: the model with the known mass added
    # reproduces the true states exactly (same integrator, same inputs)
    truth_u = np.load(tmp_path / "rec" / "timeseries.npz")["u"]
    n = got.model.system.n
    pred = got.model.simulate(got.values(rec.truth), np.zeros((1, n)), np.zeros((1, n)), [0],
                              [len(got.t)], truth_u, got.dt, 4)  # fmt: skip
    np.testing.assert_array_equal(pred.q, got.q)


@pytest.mark.slow
def test_acceptance_five_parameters_from_the_shipped_experiments():
    """The acceptance of docs/identify.md on a seed the experiments were not tuned on: from
    30 % off, with the documented noise (about a minute and a half of CPU)."""
    from tdacm.identify import MAIN_PARAMETERS
    from tdacm.identify.fit import identify_staged
    from tdacm.identify.validate import held_out_rms

    seed = 606
    recs = [synthesize(e, seed=seed) for e in ("tendon-steps", "tendon-steps-loaded", "hover")]
    start = {k: 0.7 * DEFAULT_TRUTH[k] for k in MAIN_PARAMETERS}
    res = identify_staged(recs, list(MAIN_PARAMETERS), start=start, decimate=2)
    err = truth_errors(res, DEFAULT_TRUTH)
    limits = {"E": 0.02, "damping": 0.10, "tip_mass": 0.05, "radius": 0.03, "drone_mass": 0.01}
    for k, lim in limits.items():
        assert abs(err[k]) < lim, (k, err[k])
    assert held_out_rms(res.values, seed=seed) < 5e-3


def test_a_run_folder_without_measurements_fits_on_the_poses_of_q(tmp_path, clamped):
    """A `tdacm run`-style folder (timeseries.npz t, q, qd, u; scenario.toml): the poses are
    those of q; noise-free data give the scenario's own value back."""
    from pathlib import Path

    from tdacm import __file__ as pkg

    sysm = clamped.system
    u = np.array([2.0, 0.5, 0.0, 0.0])
    ref = simulate(sysm, [0.3, -0.1], duration=3.0, dt=0.01, u=u, method="rk4")
    folder = tmp_path / "run"
    folder.mkdir()
    text = (Path(pkg).parent / "scenarios" / "ground-test-a.toml").read_text()
    (folder / "scenario.toml").write_text(text)
    np.savez(folder / "timeseries.npz", t=ref.t, q=ref.q, qd=ref.qd, u=ref.u[:-1])
    rec = load_recording(folder)
    assert rec.u.shape == (len(ref.t), 4)
    np.testing.assert_allclose(rec.tip[100], sysm.tip_pose(ref.q[100]), atol=1e-14)
    res = identify(rec, ["E"], start={"E": 1.2 * sysm.rod.youngs_modulus}, max_nfev=20)
    assert res.values["E"] == pytest.approx(sysm.rod.youngs_modulus, rel=1e-6)


def test_tendon_friction_is_identified_from_the_steps():
    truth = {**DEFAULT_TRUTH, "friction": 0.04, "viscous": 0.5}
    rec = synthesize("tendon-steps", seed=8, duration=8.0, truth=truth, noise={"tension": 0.0})
    held = {"tip_mass": truth["tip_mass"], "damping": truth["damping"]}
    # the tensions are exact here: the fit is told so (no load-cell noise in its uncertainty)
    res = identify(rec, "E,radius,friction,viscous", start={"E": 5e10, "radius": 0.0115},
                   fixed=held, decimate=2, sigma={"tension": 0.0})  # fmt: skip
    for k in ("friction", "viscous"):
        assert abs(res.values[k] - truth[k]) < 4 * res.std[k], (k, res.values[k], res.std[k])
    assert res.std["friction"] < 0.002 and res.std["viscous"] < 0.2
    assert abs(res.values["E"] / truth["E"] - 1) < 2e-3
