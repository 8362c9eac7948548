"""Two arms under one drone in the closed loop (tdacm.loop.arms, [[robot.arms]])."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.sim.assemble import build_loop, build_world
from tdacm.sim.batch import refuse
from tdacm.sim.scenario import ScenarioError, load_scenario

#: arm 1's strains from arm 0's under the mirror x -> -x of the body frame (the arms sit at
#: +-x): the curvature about the rod's local y (body y) changes sign, the one about local z
#: (body x) does not (a pseudovector reflected through the plane normal to local z)
MIRROR_STRAINS = np.array([-1.0, 1.0])
#: the drone coordinates the mirror x -> -x reverses: pitch theta, yaw psi, position x
REVERSED = [1, 2, 3]


def _mirrored(overrides=None):
    """dual-in-fov made exactly mirror-symmetric: no model error (its draws differ per
    coordinate), the analytic C_L (a detector on rendered pixels is not mirror-exact), and a
    mirrored start (roll, y, z free; pitch, yaw, x zero; arm 1 = mirror of arm 0)."""
    a = np.array([-0.25, -0.2])
    q0 = [0.03, 0.0, 0.0, 0.0, 0.25, 4.2, *a, *(MIRROR_STRAINS * a)]
    data = {
        "initial": {"q": q0},
        "model": {"perturbation": 0.0},
        "cameras": {"local_renderer": "analytic"},
    }
    return load_scenario("dual-in-fov").with_overrides({**data, **(overrides or {})})


def test_dual_scenario_builds_two_arms():
    w = build_world(load_scenario("dual-in-fov"))
    s = w.robot.system
    assert (s.n, s.n_u, len(s.arms), len(w.robot.arms)) == (10, 12, 2, 2)
    # each arm's marker lies below its attachment: at q* every C_L looks at its own marker
    for arm, scene in zip(w.robot.arms, w.scenes, strict=True):
        g = s.tip_pose(w.q_star, arm.rod) @ arm.tip_mount
        assert np.allclose(g[:2, 3], scene.box_xy, atol=1e-12)


def test_mirror_of_the_strains():
    """The strain map of MIRROR_STRAINS mirrors the tip positions (kinematics)."""
    w = build_world(load_scenario("dual-in-fov"))
    s = w.robot.system
    q = np.array([0.05, 0, 0, 0, 0.1, 3, 0.3, -0.2, 0, 0])
    q[8:] = MIRROR_STRAINS * q[6:8]
    p0, p1 = s.tip_pose(q, 0)[:3, 3], s.tip_pose(q, 1)[:3, 3]
    assert np.allclose(p1, [-p0[0], p0[1], p0[2]], atol=1e-14)


def _run_mirrored(duration):
    res = build_loop(_mirrored()).loop.run(duration)
    assert not res.terminated, res.reason
    q = res.arrays["q"]
    return q, res.arrays


def _check_mirror(q, a):
    # the drone coordinates the mirror reverses stay zero, and the arms stay mirror images
    assert np.abs(q[:, REVERSED]).max() < 1e-9
    assert np.abs(q[:, 8:10] - MIRROR_STRAINS * q[:, 6:8]).max() < 1e-9
    r = a["rmse_arms"]
    assert np.abs(r[:, 0] - r[:, 1]).max() < 1e-9
    # not a trivial run: the drone and the strains moved, and the views converged
    assert np.ptp(q[:, 5]) > 0.5 and np.ptp(q[:, 6]) > 0.1
    assert r[-1].max() < 0.2 * r[0].max()


def test_mirror_symmetry_short():
    """Two identical arms mounted symmetrically, mirrored targets and initial strains, no
    noise: mirror images over 2 s of closed loop (the 5 s version is slow-marked)."""
    _check_mirror(*_run_mirrored(2.0))


@pytest.mark.slow
def test_mirror_symmetry_5s():
    q, a = _run_mirrored(5.0)
    _check_mirror(q, a)
    assert a["rmse_arms"][-1].max() < 1e-3


def test_stacked_joint_rates_are_the_least_squares_solution():
    """ArmsServo.joint_rates: the pseudo-inverse of the two arms' stacked task Jacobians over
    the commanded coordinates (docs/control.md, "Two arms")."""
    a = build_loop(_mirrored())
    sv = a.loop.servo
    rng = np.random.default_rng(3)
    q = a.world.q0 + rng.normal(0, 0.05, 10)
    tw = [rng.normal(0, 0.3, 6), rng.normal(0, 0.3, 6)]
    got = sv.joint_rates(q, tw)
    c = sv.arms[0]._cmd
    assert list(c) == [2, 3, 4, 5, 6, 7, 8, 9]  # roll and pitch are not commanded
    qv = q.copy()
    qv[:2] = 0.0
    jac = np.vstack([a.world.robot.system.tip_jacobian(qv, k)[:, c] for k in (0, 1)])
    rhs = np.concatenate([arm._ad_mount @ v for arm, v in zip(sv.arms, tw, strict=True)])
    want = np.linalg.lstsq(jac, rhs, rcond=None)[0]
    assert np.allclose(got[c], want, rtol=1e-10, atol=1e-12)
    assert np.all(got[:2] == 0.0)
    # the shared drone columns couple the arms: arm 1's twist alone moves the drone
    only1 = sv.joint_rates(q, [np.zeros(6), tw[1]])
    assert np.abs(only1[2:6]).max() > 1e-3


@pytest.mark.parametrize(
    "data, match",
    [
        ({"robot": {"arms": [{"attachment": {"position": [0, 0]}, "marker": {"xy": [0, 0]}}]}},
         "robot.arms: give two or more arms"),
        ({"robot": {"rod": {"length": 0.5}}}, r"robot.rod: with \[\[robot.arms\]\]"),
        ({"robot": {"arms": [{"marker": {"xy": [0, 0]}}] * 2}},
         r"robot.arms\[0\].attachment is required"),
    ],
)  # fmt: skip
def test_refusals_name_the_key(data, match):
    with pytest.raises(ScenarioError, match=match):
        build_loop(load_scenario("dual-in-fov").with_overrides(data))


def test_two_arms_servo_on_the_ekfs_estimates():
    """``estimation.source = "estimated"`` with two arms: the EKF over all coordinates (its
    sensors: the drone's pose, the IMU, every tendon's encoder, arm 0's view of its marker)
    feeds the servo and the controller; 2 s of closed loop bring both arms' image errors down
    with the estimate close to the plant."""
    a = build_loop(load_scenario("dual-in-fov").with_overrides(
        {"estimation": {"source": "estimated"}}), 3)  # fmt: skip
    assert a.loop.estimator.filter.n == a.loop.plant.system.n == 10
    res = a.loop.run(2.0)
    arr = res.arrays
    q_true, q_hat = arr["q"], arr["q_hat"]
    assert np.all(np.isfinite(q_hat))
    strain = np.sqrt(np.mean((q_hat[-50:, 6:] - q_true[-50:, 6:]) ** 2))
    position = np.sqrt(np.mean((q_hat[-50:, 3:6] - q_true[-50:, 3:6]) ** 2))
    # measured 3.2e-4 /m and 1.0 mm (seed 3): the single-arm filter's figures
    assert strain < 0.002 and position < 0.005, (strain, position)  # 1/m, m
    assert a.loop.estimator.filter.views_fused > 50  # arm 0's C_L fused (2 s at 50 Hz)
    rmse = np.asarray(arr["rmse_true_arms"])  # (steps, 2): each arm's true image error
    assert np.all(rmse[-1] < 0.3 * rmse[0]), (rmse[0], rmse[-1])  # 0.29 -> 0.05 measured


def test_batched_engine_runs_several_arms_as_the_block_loop():
    """The engine's worlds of the mirrored two-arm robot equal the block loop of their seeds
    bit for bit (both call the servo of several arms' compiled step)."""
    from tdacm.sim.batch import build_batch

    engine_cameras = {"local_renderer": "analytic", "global_renderer": "planar"}
    sc = _mirrored({"ibvs": {"features": "measured"}, "duration": 0.6, "cameras": engine_cameras})
    refuse(build_loop(sc).loop)  # nothing refused
    res = build_batch(sc, [0, 2]).run(log_states=True)
    for w, seed in enumerate([0, 2]):
        r = build_loop(sc, seed).loop.run(0.6)
        np.testing.assert_array_equal(res.q[:, w], r.arrays["q"])
        np.testing.assert_array_equal(res.rmse[:, w], r.arrays["rmse"])


def test_outputs_know_the_arms(tmp_path):
    """A short run: the per-arm summary figures, CSV columns with units, the arms figure."""
    from tdacm.sim.outputs import columns
    from tdacm.sim.runner import arms_summary
    from tdacm.viz import plot_run

    a = build_loop(_mirrored())
    res = a.loop.run(0.3)
    s = arms_summary(res.arrays)
    assert len(s["late_rmse_1s_arms"]) == 2 and len(s["final_rmse_true_arms"]) == 2
    # the run's rmse is the larger of the arms'
    assert np.allclose(res.arrays["rmse"], res.arrays["rmse_arms"].max(axis=1))
    _, info = columns(res.arrays, True)
    arm_cols = {c["name"]: c["unit"] for c in info if c["series"] == "rmse_arms"}
    assert arm_cols == {"rmse_arm0": "-", "rmse_arm1": "-"}
    paths = plot_run(tmp_path, res.arrays, {}, a.loop.servo.desired_points, a.world.robot.system,
                     formats=("png",), kinds=("arms",))  # fmt: skip
    assert [p.name for p in paths] == ["arms.png"] and paths[0].stat().st_size > 0


def test_reseed_gives_the_run_of_a_fresh_build():
    """Every arm's C_L noise comes from the run's seed: a reseeded loop runs as one built with
    that seed (1 px noise, 10 % model error)."""
    from tdacm.sim.assemble import reseed

    sc = load_scenario("dual-in-fov").with_overrides(
        {"sensors": {"pixel_noise": 1.0}, "cameras": {"local_renderer": "analytic"}}
    )
    fresh = build_loop(sc, seed=5).loop.run(0.3).arrays
    a = build_loop(sc, seed=1)
    a.loop.run(0.3)
    again = reseed(a, 5).loop.run(0.3).arrays
    for key in ("q", "u", "rmse_arms"):
        assert np.array_equal(fresh[key], again[key]), key


def test_recovery_of_one_arm_from_its_global_snapshot():
    """dual-out-of-fov: arm 1 starts without its marker; the servo asks C_G, plans arm 1's
    rod from the snapshot of arm 1's marker, the drone's reference and arm 0's strains hold
    while arm 1's rod moves, and IBVS takes over once arm 1 sees its marker."""
    sc = load_scenario("dual-out-of-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic"}, "model": {"perturbation": 0.0}}
    )
    a = build_loop(sc)
    res = a.loop.run(1.0)
    assert not res.terminated, res.reason
    r = res.arrays
    mode, det, q_d = r["mode"], r["detected_arms"], r["q_d"]
    assert mode[0] == 1 and not det[0, 1] and det[0, 0]  # recovery: arm 1 blind, arm 0 sees
    rec = np.flatnonzero(mode == 1)
    assert rec[-1] < len(mode) - 1 and mode[-1] == 0 and det[-1].all()  # IBVS after
    held = q_d[rec]
    assert np.ptp(held[:, 2:8], axis=0).max() == 0.0  # drone (yaw, x, y, z), arm 0: held
    assert np.ptp(held[:, 8:10], axis=0).max() > 0.05  # arm 1's rod follows its plan
    # IBVS engaged (the safety monitor re-armed) when arm 1 saw its marker again
    assert res.switch_time == pytest.approx(r["t"][rec[-1] + 1])
