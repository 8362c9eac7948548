"""The robust servo in the closed loop: 1 px of corner noise, missed and late frames, the
recovery's C_G snapshot on demand, and the paper profile (docs/control.md, "Robust servo")."""

import numpy as np
import pytest

from tdacm.loop import GlobalView, LocalView, StateEstimate
from tdacm.loop.servo import RobustServo, VisualServo
from tdacm.sim import Simulation, build_loop, load_scenario
from tdacm.sim.assemble import apply_profile

ANALYTIC = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}


def _run(overrides, duration, scenario="paper-in-fov", seed=0):
    sc = load_scenario(scenario).with_overrides(ANALYTIC).with_overrides(overrides)
    return Simulation(sc, duration=duration, seed=seed).run()


def _twist_roughness(a):
    """Largest step-to-step change of the weak-direction twist components (w_x, w_y, v_x,
    v_y) while servoing."""
    tw = a["twist"][a["mode"] == 0][:, [0, 1, 3, 4]]
    return float(np.max(np.abs(np.diff(tw, axis=0))))


def test_noisy_closed_loop_converges_with_a_clean_twist():
    """1 px corner noise, 10 % model error: with the measured features and the plain
    J_img^-1 the twist jumps by more than 0.3 (rad/s, m/s) from one period to the next along
    the weak directions; the robust servo's twist is smooth and the error keeps falling."""
    a, s = _run({"sensors": {"pixel_noise": 1.0}}, 1.6)
    assert not s["terminated"], s["termination_reason"]
    assert s["final_rmse_true"] < 0.7 * s["initial_rmse"]
    assert _twist_roughness(a) < 0.1
    b, sb = _run(
        {"sensors": {"pixel_noise": 1.0}, "ibvs": {"features": "measured", "floor": 0.0}}, 1.6
    )
    assert _twist_roughness(b) > 0.3


def test_missed_frames_do_not_zero_the_commanded_rates():
    """30 % dropped frames: in IBVS the command keeps its value through the misses
    (predicted features), it is never reset to zero."""
    a, s = _run({"sensors": {"pixel_noise": 1.0, "dropout": 0.3}}, 1.0)
    assert not s["terminated"], s["termination_reason"]
    missed = ~a["detected_local"].astype(bool) & (a["mode"] == 0)
    missed[:5] = False  # the soft start
    assert missed.sum() > 5
    assert np.all(np.linalg.norm(a["qd_d"][missed], axis=1) > 1e-3)
    assert np.max(np.abs(np.diff(a["qd_d"][5:], axis=0))) < 0.05


def test_latency_is_compensated_in_the_loop():
    """2 periods of latency: frames are fused with the camera pose at their capture time, so
    the trajectory stays that of the latency-free loop (noise off: same to 1 mm)."""
    a, s = _run({"sensors": {"latency_steps": 2}}, 1.0)
    b, _ = _run({}, 1.0)
    assert not s["terminated"]
    assert np.max(np.abs(a["q"][:, 3:6] - b["q"][:, 3:6])) < 1e-3
    assert np.nanmax(np.abs(a["rmse_true"] - b["rmse_true"])) < 2e-3


def test_recovery_holds_when_the_global_camera_misses_then_gives_up():
    loop = build_loop(load_scenario("paper-out-of-fov").with_overrides(ANALYTIC), 0).loop
    try:
        loop.reset()
        servo = loop.servo
        assert isinstance(servo, RobustServo) and servo.mode == "recovery"
        est = StateEstimate(0.0, loop.plant.state.q, loop.plant.state.qd)
        missed = GlobalView(0.0)  # C_G read, target not found
        for k in range(50):
            cmd = servo.step(0.02 * k, 0.02, LocalView(0.02 * k), missed, est)
            assert cmd.request_global and np.all(cmd.qd_d == 0)
            assert cmd.failure is None
        cmd = servo.step(1.0, 0.02, LocalView(1.0), missed, est)  # lost_timeout = 1 s
        assert cmd.failure == "recovery: target not seen by C_G"
    finally:
        loop.close()


def test_paper_profile_selects_the_literal_choices():
    sc = load_scenario("paper-in-fov").with_overrides({"controller": {"profile": "paper"}})
    d = apply_profile(sc).data
    assert d["model"]["gravity_feedforward"] is False
    assert d["ibvs"]["compensation"] == "approx" and d["ibvs"]["floor"] == 0.0
    assert d["safety"]["min_increase"] == 0.0 and d["safety"]["grace"] == 0.0
    loop = build_loop(sc.with_overrides(ANALYTIC), 0).loop
    try:
        assert type(loop.servo) is VisualServo
        assert np.isinf(loop.servo.shaping.max_drone_speed)
        assert loop.servo.shaping.rate_filter == 0.0 and loop.servo.shaping.soft_start == 0.0
    finally:
        loop.close()
    assert apply_profile(load_scenario("paper-in-fov")) is not None


@pytest.mark.slow
def test_noise_free_paper_in_fov_meets_the_convergence_targets():
    """The normalized RMSE reaches 0.01 within 3 s and 0.001 within 5 s (rendered camera,
    noise-free)."""
    sc = load_scenario("paper-in-fov").with_overrides({"cameras": {"global_every": 0}})
    _, s = Simulation(sc).run()
    assert s["time_to_0.01"] <= 3.0 and s["time_to_0.001"] <= 5.0
    assert s["final_camera_position_error_m"] < 0.03


def test_camera_pose_covariance_maps_the_state_covariance_through_the_kinematics():
    """``J_C P_qq J_C^T`` against a Monte-Carlo of states around the estimate, each mapped to
    the C_L pose (``log(g_hat^-1 g)``, camera frame); ``None`` for the true state."""
    from scipy.spatial.transform import Rotation

    def log_small(d):  # [w; v] of a small relative pose (first order, like the filter's eps)
        return np.concatenate((Rotation.from_matrix(d[:3, :3]).as_rotvec(), d[:3, 3]))

    loop = build_loop(load_scenario("paper-in-fov").with_overrides(ANALYTIC), 0).loop
    servo = loop.servo
    assert isinstance(servo, RobustServo)
    n = loop.plant.system.n
    q = np.array([0.05, -0.03, 0.2, 0.1, -0.1, 3.0, -0.2, 0.3])
    std = np.array([2e-3, 2e-3, 3e-3, 2e-3, 2e-3, 2e-3, 5e-3, 5e-3])
    p = np.zeros((2 * n, 2 * n))
    p[:n, :n] = np.diag(std**2)
    cov = servo.camera_pose_covariance(q, p)
    assert servo.camera_pose_covariance(q, None) is None
    rng = np.random.default_rng(0)
    g0 = servo.local_camera_pose(q)
    xs = np.array(
        [
            log_small(np.linalg.solve(g0, servo.local_camera_pose(q + rng.normal(0, std))))
            for _ in range(4000)
        ]
    )
    mc = np.cov(xs.T)
    np.testing.assert_allclose(cov, cov.T)
    # Monte-Carlo error of a covariance with 4000 samples: ~2.2 % of the diagonal
    np.testing.assert_allclose(np.diag(cov), np.diag(mc), rtol=0.08)
    scale = np.sqrt(np.outer(np.diag(mc), np.diag(mc)))
    assert np.max(np.abs(cov - mc) / scale) < 0.08
