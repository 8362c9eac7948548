"""Each block of the closed loop on its own (inputs -> outputs), then the assembled loop."""

import numpy as np
import pytest

from tdacm.control.allocation import box_least_squares
from tdacm.loop import (
    AnalyticFrontEnd,
    CameraMeasurement,
    CameraSensor,
    ClosedLoop,
    ControllerContext,
    Disturbances,
    LocalView,
    LowLevelController,
    Perception,
    Plant,
    PlantState,
    Sensors,
    ServoCommand,
    StateEstimate,
    load_class,
)
from tdacm.loop.data import ActuatorCommand
from tdacm.loop.lowlevel import make_low_level
from tdacm.loop.sensors import SensorModel
from tdacm.sim import (
    ScenarioError,
    Simulation,
    build_loop,
    build_world,
    load_scenario,
    parse_scenario,
)
from tdacm.sim.robot import build_robot
from tdacm.system.kernels import rk4_run
from tdacm.vision.features import estimate_depths

ANALYTIC = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}


@pytest.fixture(scope="module")
def world():
    return build_world(load_scenario("paper-in-fov"))


# ---------------------------------------------------------------------- plant
def test_plant_matches_the_integrator_and_applies_named_disturbances(world):
    s = world.robot.system
    u = np.r_[np.full(4, s.total_mass * 9.81 / 4), [1.0, 0.0, 0.0, 0.0]]
    plant = Plant(s, world.q0, world.qd0, substeps=4)
    st = plant.advance(u, 0.02)
    qs, _, ok = rk4_run(world.q0, world.qd0, u, 0.005, 4, 4, s.model_arrays, s.loads.packed())
    assert ok and np.array_equal(st.q, qs[-1]) and st.t == pytest.approx(0.02)
    # a base wrench by name changes the motion; the system's own loads stay untouched
    dist = Disturbances(base_wrench_amplitude=np.array([0, 0, 0, 1.0, 0, 0]),
                        base_wrench_frequency=12.5)  # fmt: skip
    p2 = Plant(s, world.q0, world.qd0, 4, dist)
    p2.advance(u, 0.02)  # sin(0) = 0 at t = 0: same as without
    assert np.allclose(p2.state.q, st.q)
    a = p2.advance(u, 0.02)  # t = 0.02: sin(pi/2) = 1 N along body x
    b = plant.advance(u, 0.02)
    assert a.q[3] > b.q[3]  # pushed along +x (level drone, yaw 10 deg)
    assert not np.any(s.loads.base_wrench)
    assert dist.loads_at(0.02, np.random.default_rng(0), True)["base_wrench"][3] == 1.0


# ---------------------------------------------------------------------- sensors
def test_analytic_camera_sees_what_the_renderer_detects(world):
    """Along a motion, the analytic corners agree with the rendered-and-detected ones to the
    planar renderer's corner error (measured: <= 1.2 px at 3-5 m for the 20 cm marker)."""
    r = world.robot
    an = CameraSensor(r.system, "tip", r.tip_mount,
                      AnalyticFrontEnd(r.local_camera, world.target, world.scene.target_pose))  # fmt: skip
    loop = build_loop(load_scenario("paper-in-fov"), 0).loop
    try:
        rendered = loop.sensors.local
        for lam in np.linspace(0.0, 1.0, 6):
            q = (1 - lam) * world.q0 + lam * world.q_star
            da, _ = an.ideal(q)
            dr, _ = rendered.ideal(q)
            assert da.found and dr.found
            assert np.max(np.abs(da.points - dr.points)) < 1.5
    finally:
        loop.close()


def test_camera_imperfections_noise_dropout_latency(world):
    r = world.robot
    fe = AnalyticFrontEnd(r.local_camera, world.target, world.scene.target_pose)
    q = world.q0
    ideal = fe.detect_at(r.system.tip_pose(q) @ r.tip_mount).points
    noisy = CameraSensor(r.system, "tip", r.tip_mount, fe, SensorModel(pixel_noise=1.0),
                         np.random.default_rng(1))  # fmt: skip
    errs = np.array([noisy.measure(PlantState(0.0, q, q * 0)).detection.points - ideal
                     for _ in range(400)])  # fmt: skip
    assert np.std(errs) == pytest.approx(1.0, rel=0.05) and abs(np.mean(errs)) < 0.05
    drop = CameraSensor(r.system, "tip", r.tip_mount, fe, SensorModel(dropout=0.3),
                        np.random.default_rng(2))  # fmt: skip
    found = [drop.measure(PlantState(0.0, q, q * 0)).found for _ in range(1000)]
    assert np.mean(found) == pytest.approx(0.7, abs=0.05)
    late = CameraSensor(r.system, "tip", r.tip_mount, fe, SensorModel(latency_steps=2))
    stamps = [late.measure(PlantState(0.02 * k, q, q * 0)).t_capture for k in range(5)]
    assert stamps == pytest.approx([0.0, 0.0, 0.0, 0.02, 0.04])


def test_sensors_read_global_camera_when_due_or_requested(world):
    r = world.robot
    fe = AnalyticFrontEnd(r.local_camera, world.target, world.scene.target_pose)
    fg = AnalyticFrontEnd(r.global_camera, world.target, world.scene.target_pose)
    local = CameraSensor(r.system, "tip", r.tip_mount, fe)
    glob = CameraSensor(r.system, "base", r.drone_mount, fg)
    sensors = Sensors(local, glob, global_every=0)
    st = PlantState(0.0, world.q0, world.qd0)
    assert sensors.read(st).global_ is None
    g = sensors.read(st, request_global=True).global_
    assert g is not None and g.found  # paper-in-fov: the target is in C_G's view at the start
    every = Sensors(local, glob, global_every=3)
    got = [every.read(st).global_ is not None for _ in range(6)]
    assert got == [True, False, False, True, False, False]


def test_global_camera_renders_only_when_read_or_due_for_outputs(world):
    """C_G offered every period is measured only when read (the servo's snapshot), and then
    gives the frame an eager read gives; ``global_output_every`` renders it for the outputs."""
    r = world.robot
    fe = AnalyticFrontEnd(r.local_camera, world.target, world.scene.target_pose)
    fg = AnalyticFrontEnd(r.global_camera, world.target, world.scene.target_pose)
    calls = []
    detect = fg.detect_at
    fg.detect_at = lambda pose: calls.append(1) or detect(pose)
    local = CameraSensor(r.system, "tip", r.tip_mount, fe)
    glob = CameraSensor(r.system, "base", r.drone_mount, fg)
    st = PlantState(0.0, world.q0, world.qd0)
    lazy = Sensors(local, glob, global_every=1)
    readings = [lazy.read(st) for _ in range(4)]
    assert calls == [] and all(rd.global_ is not None for rd in readings)
    assert all(rd.global_rendered is None for rd in readings)
    eager = glob.measure(st)
    calls.clear()
    view = Perception(r.local_camera, r.global_camera, world.target).global_(readings[2].global_)
    assert calls == []  # the view defers too
    assert view.found and np.array_equal(view.detection.points, eager.detection.points)
    assert len(calls) == 1 and readings[2].global_rendered is not None
    calls.clear()
    out = Sensors(local, glob, global_every=0, global_output_every=2)
    got = [out.read(st) for _ in range(4)]
    assert len(calls) == 2 and [g.global_ for g in got] == [None] * 4
    assert [g.global_output is not None for g in got] == [True, False, True, False]


# ---------------------------------------------------------------------- perception
def test_perception_normalizes_with_the_controllers_camera_and_estimates_depths(world):
    r = world.robot
    fe = AnalyticFrontEnd(r.local_camera, world.target, world.scene.target_pose)
    pose = r.system.tip_pose(world.q0) @ r.tip_mount
    det = fe.detect_at(pose)
    view = Perception(r.local_camera, r.global_camera, world.target).local(
        CameraMeasurement(0.0, det)
    )
    assert view.found and view.t_capture == 0.0
    assert np.allclose(view.points, r.local_camera.normalize(det.points))
    pc = (world.target.feature_points @ world.scene.target_pose[:3, :3].T
          + world.scene.target_pose[:3, 3] - pose[:3, 3]) @ pose[:3, :3]  # fmt: skip
    assert np.allclose(view.depths, pc[:, 2], rtol=1e-6)
    assert np.allclose(view.depths, estimate_depths(view.points, world.target.feature_points))
    assert (
        not Perception(r.local_camera, r.global_camera, world.target)
        .local(CameraMeasurement(0.1))
        .found
    )

    # the perception block is the boundary that checks the detection (the servo and its
    # target filter then take the view's arrays unchecked)
    bad = det.points.copy()
    bad[2, 0] = np.nan
    from tdacm.vision.detect import Detection

    with pytest.raises(ValueError, match="detection.points must be finite"):
        Perception(r.local_camera, r.global_camera, world.target).local(
            CameraMeasurement(0.0, Detection(True, bad, det.ids, det.corners))
        )


# ---------------------------------------------------------------------- servo
def test_servo_ibvs_command_reduces_the_feature_error(world):
    loop = build_loop(load_scenario("paper-in-fov").with_overrides(ANALYTIC), 0).loop
    servo = loop.servo
    sensed = loop.sense()  # not reset: reset() also does this
    loop.reset()
    sensed = loop.sense()
    cmd = servo.step(0.0, 0.02, sensed.view, sensed.global_view, sensed.estimate)
    assert cmd.mode == "ibvs" and cmd.failure is None
    assert np.all(np.isfinite(cmd.twist)) and np.any(cmd.twist)
    # the twist decreases the error to first order: e_dot = -lambda J J^+ e
    points, depths, _, error, _ = servo.observe(sensed.view, sensed.estimate.q)
    assert error @ (servo.ibvs.interaction(points, depths) @ cmd.twist) < 0
    assert cmd.qd_d[:2].tolist() == [0.0, 0.0]  # roll and pitch are not commanded
    loop.close()


def test_servo_recovery_requests_the_global_camera_then_plans(world):
    loop = build_loop(load_scenario("paper-out-of-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_renderer": "planar",
                     "global_every": 0}}), 0).loop  # fmt: skip
    try:
        loop.reset()
        servo = loop.servo
        assert servo.mode == "recovery"
        est = StateEstimate(0.0, loop.plant.state.q, loop.plant.state.qd)
        no_view = LocalView(0.0)
        cmd = servo.step(0.0, 0.02, no_view, None, est)  # no C_G frame: hold and ask for one
        assert cmd.request_global and cmd.failure is None
        assert np.all(cmd.qd_d == 0)
        sensed = loop.sense()  # the loop honours the request: C_G is read this period
        assert loop._request_global and sensed.global_view is not None
        cmd = servo.step(0.02, 0.02, no_view, sensed.global_view, est)
        assert cmd.event == "recovery planned" and cmd.plan is not None
    finally:
        loop.close()


# ---------------------------------------------------------------------- low level
class NotAController:
    def __init__(self, context):
        self.context = context


def test_low_level_controller_protocol_and_loading(world):
    s = world.robot.system
    from tdacm.control import EstimatedModel

    ctx = ControllerContext(s, EstimatedModel(s, 0.1, 0), world.q_star, 0.02, {})
    for path in ("", "tdacm.loop.lowlevel:PDGravityController"):
        ctl = make_low_level(path, ctx)
        assert isinstance(ctl, LowLevelController)
        est = StateEstimate(0.0, world.q_star, np.zeros(s.n))
        ctl.reset(est)
        cmd = ServoCommand("ibvs", world.q_star, np.zeros(s.n), np.zeros(s.n), np.zeros(6))
        act = ctl.step(est, cmd, 0.02)
        assert isinstance(act, ActuatorCommand) and act.u.shape == (s.n_u,)
        assert np.all(act.u >= 0)
        # at the desired hover the thrust carries the weight (within the 10 % model error)
        assert act.u[:4].sum() == pytest.approx(s.total_mass * 9.81, rel=0.15)
    with pytest.raises(ValueError, match="package.module:ClassName"):
        load_class("nocolon")
    with pytest.raises(ValueError, match="cannot import"):
        load_class("no_such_module_xyz:Thing")
    with pytest.raises(ValueError, match="has no 'Nope'"):
        load_class("tdacm.control.pd:Nope")
    with pytest.raises(ValueError, match="does not implement"):
        make_low_level("tests.loop.test_blocks:NotAController", ctx)
    with pytest.raises(ValueError, match="building it from a ControllerContext failed"):
        make_low_level("tdacm.control.model:EstimatedTerms", ctx)


def test_allocation_box_least_squares_is_exact():
    from scipy.optimize import lsq_linear

    rng = np.random.default_rng(0)
    for _ in range(200):
        na = int(rng.integers(3, 9))
        ns = int(rng.integers(1, na))
        b = rng.normal(size=(ns, na)) * 0.01
        tau = rng.normal(size=ns) * rng.choice([0.01, 0.1, 1.0])
        w = 1e-3 * np.linalg.norm(b, axis=0).max()
        a = np.vstack((b, w * np.eye(na)))
        rhs = np.concatenate((tau, np.full(na, w * 0.5)))
        x = box_least_squares(a, rhs, 0.0, 20.0)
        ref = lsq_linear(a, rhs, bounds=(0, 20), method="bvls", tol=1e-14).x
        assert np.all((x >= 0) & (x <= 20))
        cost_x, cost_ref = (np.sum((a @ v - rhs) ** 2) for v in (x, ref))
        assert cost_x <= cost_ref * (1 + 1e-8) + 1e-300


# ---------------------------------------------------------------------- robot section
def test_robot_section_builds_any_robot_and_names_bad_keys():
    sc = load_scenario("custom-robot-example")
    w = build_world(sc)
    s = w.robot.system
    assert s.rod.length == 0.8 and s.base.mass == 1.0 and s.tendons.n == 3
    offs = s.tendons.offsets[:, 1:]
    ang = np.degrees(np.arctan2(offs[:, 1], offs[:, 0])) % 360
    assert np.allclose(sorted(ang), [0, 120, 240])
    # omitted keys: the paper's robot exactly
    paper = build_world(load_scenario("paper-in-fov")).robot.system
    from tdacm import paper_system

    ref = paper_system()
    q = np.array([0, 0, 0.1, 0, 0, 3, 0.2, -0.1])
    assert np.allclose(paper.terms(q, q).M, ref.terms(q, q).M, rtol=0, atol=0)
    base = 'name = "x"\n[initial]\nq = [0,0,0,0,0,3,0,0]\n[desired]\nq = [0,0,0,0,0,3,0,0]\n'
    with pytest.raises(ScenarioError, match="robot.rod.lenght"):
        parse_scenario(base + "[robot.rod]\nlenght = 1\n")
    with pytest.raises(ScenarioError, match="robot.rod.length must be a finite number"):
        parse_scenario(base + '[robot.rod]\nlength = "long"\n')
    with pytest.raises(
        ScenarioError, match="robot.rod.length must be > 0"
    ):  # when the scenario loads
        load_scenario("paper-in-fov").with_overrides({"robot": {"rod": {"length": -1.0}}})
    two = load_scenario("paper-in-fov").with_overrides(
        {"robot": {"tendons": {"offsets": [[0.01, 0.0], [-0.01, 0.0]]}}}
    )
    with pytest.raises(ScenarioError, match="at least 3"):
        build_world(two)
    with pytest.raises(ScenarioError, match=r"initial.q must have 10 entries"):
        parse_scenario(base + '[robot.rod]\nbasis = "bending:1"\n')
    r = build_robot(load_scenario("paper-in-fov").config.robot)
    assert r.system.n == 8


def test_scenario_changing_only_rod_length_and_drone_mass_runs(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text(
        'name = "mine"\nduration = 0.6\n[initial]\nq = [0, 0, 0.1, -0.2, 0.2, 4.0, -0.2, -0.3]\n'
        "[desired]\nq = [0, 0, 0, 0, 0, 3, 0, 0]\n[robot.rod]\nlength = 0.9\n"
        '[robot.drone]\nmass = 0.9\n[cameras]\nlocal_renderer = "analytic"\n'
        'global_renderer = "planar"\n'
    )
    _, summary = Simulation(load_scenario(str(f))).run()
    assert not summary["terminated"], summary["termination_reason"]
    assert summary["final_rmse"] < summary["initial_rmse"]


# ---------------------------------------------------------------------- assembled loop
def test_assembled_loop_with_a_user_controller_object():
    """ClosedLoop(..., controller=...) takes any object with the protocol's two methods."""

    class Recorder:
        def __init__(self, inner):
            self.inner, self.calls = inner, 0

        def reset(self, estimate):
            self.inner.reset(estimate)

        def step(self, estimate, command, dt):
            self.calls += 1
            return self.inner.step(estimate, command, dt)

    sc = load_scenario("paper-in-fov").with_overrides(ANALYTIC)
    ref = build_loop(sc, 0).loop
    rec = Recorder(ref.controller)
    loop = build_loop(sc, 0, controller=rec).loop
    assert isinstance(loop, ClosedLoop)
    res = loop.run(0.4)
    assert rec.calls == 21 and len(res.arrays["t"]) == 21 and not res.terminated
    res_ref = ref.run(0.4)
    assert np.array_equal(res.arrays["q"], res_ref.arrays["q"])


def test_analytic_loop_follows_the_rendered_loop_when_noise_is_off():
    """Same scenario, analytic vs rendered C_L, no noise: the trajectories agree to the effect
    of the renderer's corner error (measured 1e-4-1e-3 in q over the first second; the
    loop's sensitivity to corner errors makes them drift apart later)."""
    base = load_scenario("paper-in-fov").with_overrides({"cameras": {"global_every": 0}})
    a, _ = Simulation(base.with_overrides({"cameras": {"local_renderer": "analytic"}}),
                      duration=1.0).run()  # fmt: skip
    b, _ = Simulation(base, duration=1.0).run()
    assert np.max(np.abs(a["q"] - b["q"])) < 2e-3
    assert np.nanmax(np.abs(a["rmse"] - b["rmse"])) < 2e-3


def test_summary_window_metrics_match_the_logged_rmse():
    """late_rmse_1s and within_0.01_last_2s are computed from the logged servo RMSE."""
    sc = load_scenario("paper-in-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_every": 0}}
    )
    a, s = Simulation(sc, duration=2.5, seed=0).run()
    t, r = a["t"], a["rmse"]
    last1 = r[(t >= t[-1] - 1.0 - 1e-9) & np.isfinite(r)]
    last2 = r[(t >= t[-1] - 2.0 - 1e-9) & np.isfinite(r)]
    assert last1.size == 51 and last2.size == 101  # 50 Hz, both ends included
    assert s["late_rmse_1s"] == pytest.approx(np.sqrt(np.mean(last1**2)), rel=1e-12)
    assert s["within_0.01_last_2s"] == pytest.approx(np.mean(last2 <= 0.01))
    assert 0.0 <= s["within_0.01_last_2s"] <= 1.0
    assert min(last1) <= s["late_rmse_1s"] <= max(last1)


def test_logger_comparison_columns_match_their_definitions():
    """rmse_raw and rmse_true of the log are the normalized RMSE of the raw C_L points and of
    the true points of the state (the logger's truth), and arrays() is repeatable."""
    from tdacm.loop.servo import normalized_rmse

    sc = (
        load_scenario("paper-in-fov")
        .with_overrides(ANALYTIC)
        .with_overrides({"cameras": {"global_every": 0}, "sensors": {"pixel_noise": 1.0}})
    )
    loop = build_loop(sc, seed=3).loop
    res = loop.run(0.4)
    a = res.arrays
    log = loop.log
    n = len(a["t"])
    assert n == 21 and all(len(a[k]) == n for k in ("rmse_raw", "rmse_true", "target_error_deg"))
    for k in range(n):
        pts, g_t = log.truth(a["q"][k])
        assert a["rmse_true"][k] == normalized_rmse(pts, log.desired_points)
        raw = a["points_local"][k]
        want = normalized_rmse(raw, log.desired_points) if np.all(np.isfinite(raw)) else np.nan
        assert a["rmse_raw"][k] == want or (np.isnan(want) and np.isnan(a["rmse_raw"][k]))
    assert np.isfinite(a["target_error_deg"][-1]) and a["target_error_deg"][-1] < 5.0
    # repeatable: a second call returns the same arrays
    again = log.arrays()
    assert all(np.array_equal(again[k], a[k], equal_nan=True) for k in a if a[k].dtype != object)


def test_a_point_behind_the_virtual_camera_ends_the_run_as_an_outcome():
    """Eq. (18) has no image for a point behind C_V (the drone tilted beyond what C_V can
    see): the loop ends the run with Termination.BEHIND_CAMERA instead of raising."""
    from tdacm.loop.data import Termination
    from tdacm.vision.virtual import BehindVirtualCamera, virtual_points

    with pytest.raises(BehindVirtualCamera):  # still a ValueError for direct callers
        g = np.eye(4)
        g[2, 3] = -10.0
        virtual_points(np.zeros((4, 2)), g, np.ones(4))
    sc = load_scenario("paper-in-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}
    )
    loop = build_loop(sc, 0).loop
    step = loop.servo.step
    calls = []

    def tumbling(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise BehindVirtualCamera("a point lies behind the virtual camera")
        return step(*args, **kwargs)

    loop.servo.step = tumbling
    res = loop.run(1.0)
    assert res.terminated and res.termination == Termination.BEHIND_CAMERA
    assert "behind the virtual camera" in res.reason and len(res.arrays["t"]) == 4


def test_rendering_global_camera_for_outputs_leaves_the_run_unchanged():
    """paper-out-of-fov starts in recovery: the servo reads C_G's snapshot. Rendering C_G
    every period for the outputs (the former default) changes nothing but the logged
    detected_global, which then holds every period's detection."""
    sc = load_scenario("paper-out-of-fov").with_overrides(
        {"cameras": {"global_renderer": "planar"}}
    )
    lazy = build_loop(sc, 0).loop.run(0.6).arrays
    eager_sc = sc.with_overrides({"cameras": {"global_output_every": 1}})
    eager = build_loop(eager_sc, 0).loop.run(0.6).arrays
    for k in lazy:
        if k != "detected_global":
            assert np.array_equal(lazy[k], eager[k], equal_nan=True), k
    assert lazy["detected_global"].sum() == 1  # the snapshot, read once
    assert eager["detected_global"].sum() > 0.9 * len(eager["t"])
