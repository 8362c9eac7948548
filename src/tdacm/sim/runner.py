"""Closed-loop simulation of a scenario (paper, "Simulation Results").

Per control period ``dt`` (paper: 0.02 s, 50 Hz):

1. render C_L at the current configuration (:class:`~tdacm.vision.PlanarRenderer`, the tip
   camera looks away from the arm) and C_G (:class:`~tdacm.vision.PyBulletRenderer` with the
   arm drawn, every ``cameras.global_every`` steps; always for the recovery snapshot and the
   video), detect the target in both;
2. local servo: normalized points -> depths (planar PnP) -> virtual camera C_V (floating
   base) -> advanced features -> IBVS twist -> ``qdot_d`` (pseudo-inverse of ``J_L^L`` over
   the commanded coordinates, roll/pitch excluded) -> ``q_d`` integrated;
3. mode switch (:class:`~tdacm.control.ModeSwitch`): in recovery the rod follows the cubic
   trajectory to the planned ``q_s^d`` (one C_G snapshot) while the drone holds its pose;
4. low-level :class:`~tdacm.control.TDACMController` (estimated model) -> thrusts/tensions;
5. the plant (true model, disturbances as loads) advanced by ``substeps`` RK4 steps in numba
   (:func:`tdacm.system.kernels.rk4_run`) with the input held;
6. safety monitor (paper): terminate if the normalized RMSE grows by more than
   ``growth_limit`` (5 %) from one step to the next, checked while IBVS is active. Two
   additions of ours (documented deviations): increases below ``min_increase`` (absolute,
   default 0.005, ~4 px on C_L) are ignored - the 5 % rule alone fires on detection noise and
   on the small oscillations of the flying base near convergence - and the first ``grace``
   seconds (default 0.5) after IBVS engages after a recovery are not checked (the paper
   itself reports "an initial overshoot caused by the transition between phases").

Normalized RMSE: ``sqrt(mean_k |p_k - p_k^d|^2)`` over the four points in normalized image
coordinates (C_V for a floating base, C_L for a fixed one).
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import paper_system
from ..control import (
    CubicTrajectory,
    EstimatedModel,
    ModeSwitch,
    TDACMController,
    default_gains,
    estimate_target_pose,
    plan_rod_configuration,
)
from ..system.kernels import rk4_run
from ..vision import (
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PAPER_MARKER,
    PAPER_PATTERN,
    LocalCameraServo,
    PlanarRenderer,
    PredictiveServo,
    SceneConfig,
    TargetDetector,
    camera_joint_rates,
    camera_pose,
    drone_camera_mount,
    tip_camera_mount,
    virtual_camera_transform,
)
from ..vision.features import estimate_depths
from ..vision.virtual import virtual_camera_points, virtual_camera_pose
from .outputs import LOG_KEYS
from .scenario import Scenario, load_scenario, vec
from .sensors import Delay, NoisyDetector, SensorModel, perturbed_camera

MODE_CODES = {"ibvs": 0, "recovery": 1}

#: What ``controller.profile = "paper"`` sets (the paper's literal choices, docs/control.md):
#: gravity lumped into Delta_hat, the approximate compensation p_V = R p_L on the measured
#: points, the plain law v = -lambda J_img^-1 e (no floor, no command shaping), the bare 5 %
#: safety rule.
PAPER_PROFILE = {
    "model": {"gravity_feedforward": False},
    "ibvs": {"compensation": "approx", "features": "measured", "floor": 0.0},
    "safety": {"min_increase": 0.0, "grace": 0.0},
}


def apply_profile(scenario: Scenario) -> Scenario:
    """The scenario with its ``controller.profile`` applied (unchanged for "default")."""
    if scenario.data["controller"]["profile"] != "paper":
        return scenario
    d = copy.deepcopy(scenario.data)
    for sec, kv in PAPER_PROFILE.items():
        d[sec].update(kv)
    return Scenario(d, scenario.source + " (profile paper)")


def _rotation_angle_deg(r) -> float:
    c = np.clip(0.5 * (np.trace(r) - 1.0), -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def normalized_rmse(points, desired) -> float:
    if points is None:
        return float("nan")
    d = np.asarray(points) - np.asarray(desired)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


class SafetyMonitor:
    """The paper's error-growth limit (see module docstring)."""

    def __init__(self, enabled=True, growth_limit=0.05, min_increase=0.005, grace=0.5):
        self.enabled = bool(enabled)
        self.grace = float(grace)
        self.armed_at = 0.0
        self.growth_limit = float(growth_limit)
        self.min_increase = float(min_increase)
        self.prev = None
        self.reason = None

    def arm(self, t: float) -> None:
        """IBVS (re)engaged at ``t``: the transition overshoot is not checked for ``grace`` s."""
        self.armed_at = float(t)
        self.prev = None

    def check(self, t: float, rmse: float) -> bool:
        """False (and ``reason`` set) when the limit is exceeded."""
        if not self.enabled or not np.isfinite(rmse):
            return True
        prev, self.prev = self.prev, rmse
        if prev is None or t - self.armed_at < self.grace:
            return True
        if rmse > prev * (1 + self.growth_limit) and rmse - prev > self.min_increase:
            self.reason = (
                f"safety monitor: normalized RMSE grew from {prev:.5f} to {rmse:.5f} "
                f"(+{100 * (rmse / prev - 1):.1f} % > {100 * self.growth_limit:.0f} %)"
                f" at t = {t:.2f} s"
            )
            return False
        return True


@dataclass
class Setup:
    """Everything built from a scenario (system, scene, cameras, controller...)."""

    scenario: Scenario
    system: object
    scene: SceneConfig
    target: object
    tip_mount: np.ndarray
    drone_mount: np.ndarray
    q0: np.ndarray
    qd0: np.ndarray
    q_star: np.ndarray
    local_renderer: object
    global_renderer: object = None
    extras: dict = field(default_factory=dict)

    def local_pose(self, q):
        return camera_pose(self.system.tip_pose(q), self.tip_mount)

    def global_pose(self, q):
        return camera_pose(self.system.base_pose(q), self.drone_mount)

    def render_local(self, q):
        return self.local_renderer.render(LOCAL_CAMERA, self.local_pose(q))

    def render_global(self, q):
        r = self.global_renderer
        if getattr(r, "draws_arm", False):
            r.set_arm(self.system.base_pose(q), self.system.backbone(q, 21))
        return r.render(GLOBAL_CAMERA, self.global_pose(q))

    def close(self):
        for r in (self.local_renderer, self.global_renderer):
            if r is not None:
                r.close()


def build(scenario: Scenario, need_global: bool = True) -> Setup:
    d = scenario.data
    sysd = d["system"]
    if scenario.floating:
        system = paper_system()
    else:
        held = np.zeros(8)
        held[:6] = sysd["held_base_q"]
        pose = paper_system().base_pose(held)
        system = paper_system(fixed_base_pose=pose)
    sc = d["scene"]
    target = PAPER_MARKER if sc["target"] == "aruco" else PAPER_PATTERN
    scene = SceneConfig(
        target=target,
        box_size=sc["box_size"],
        box_xy=tuple(sc["box_xy"]),
        target_yaw_deg=sc["target_yaw_deg"],
    )
    cams = d["cameras"]
    tip_mount = tip_camera_mount(system.attachment, cams["tip_offset"])
    drone_mount = drone_camera_mount(
        tuple(cams["drone_camera_position"]), cams["drone_camera_tilt_deg"]
    )
    q0 = vec(d["initial"]["q"])
    qd0 = np.zeros(system.n) if d["initial"]["qd"] is None else vec(d["initial"]["qd"])
    q_star = vec(d["desired"]["q"])
    local = PlanarRenderer(scene)
    glob = None
    if need_global:
        if cams["global_renderer"] == "pybullet":
            from ..vision import PyBulletRenderer

            glob = PyBulletRenderer(scene, backend=cams["global_backend"])
        else:
            glob = PlanarRenderer(scene)
    return Setup(
        scenario, system, scene, target, tip_mount, drone_mount, q0, qd0, q_star, local, glob
    )


def make_controller(setup: Setup, seed: int) -> TDACMController:
    """The scenario's low-level controller: adaptive law on the estimated model (perturbation
    seeded by ``seed``), gains for the desired configuration, drone loop and allocation."""
    d = setup.scenario.data
    s = setup.system
    model = EstimatedModel(s, d["model"]["perturbation"], seed, d["model"]["gravity_feedforward"])
    c = d["controller"]
    return TDACMController(
        s,
        model,
        default_gains(s, setup.q_star),
        pretension=c["pretension"],
        max_tilt=c["max_tilt"],
        attitude_filter=c["attitude_filter"],
        max_tilt_rate=c["max_tilt_rate"],
    )


class Simulation:
    """One closed-loop run; :meth:`run` returns the log dict and the summary."""

    def __init__(
        self, scenario: Scenario | str, duration=None, seed=None, video=False, progress=False
    ):
        sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
        self.scenario = apply_profile(sc)
        d = self.scenario.data
        self.duration = float(d["duration"] if duration is None else duration)
        self.seed = int(d["seed"] if seed is None else seed)
        self.video = bool(video)
        self.progress = bool(progress)

    # ------------------------------------------------------------------ helpers
    def _desired_view(self, setup: Setup):
        """Reference snapshot at the desired configuration (rendered and detected; the
        analytic projection if detection fails)."""
        det = TargetDetector(setup.target).detect(setup.render_local(setup.q_star))
        g_c = setup.local_pose(setup.q_star)
        ref, z = LocalCameraServo.reference_from_pose(
            LOCAL_CAMERA, setup.target, setup.scene.target_pose, g_c
        )
        if det.found:
            pts = LOCAL_CAMERA.normalize(det.points)
            z = estimate_depths(pts, setup.target.feature_points)
        else:
            pts = ref
        if setup.system.floating:
            gv = virtual_camera_transform(setup.system.base_pose(setup.q_star), g_c)
            pts, z = virtual_camera_points(pts, gv, z, "exact", return_depths=True)
        return pts, z

    def _plan(self, setup: Setup, q, t, det_g):
        """Recovery plan from one C_G snapshot (detection ``det_g``)."""
        s = setup.system
        g_t_cg = estimate_target_pose(det_g, GLOBAL_CAMERA, setup.target)
        p_body = setup.drone_mount @ g_t_cg[:, 3]
        q_s_now = q[s.n - s.n_s :]
        plan = plan_rod_configuration(
            s, p_body[:3], setup.tip_mount, q_s_now, z_min=LOCAL_CAMERA.near
        )
        rec = self.scenario.data["recovery"]
        traj = CubicTrajectory.with_speed(q_s_now, plan.q_s, t, rec["max_speed"])
        return plan, traj, g_t_cg

    # ------------------------------------------------------------------ main loop
    def run(self, out_dir=None):
        d = self.scenario.data
        dt, sub = d["dt"], d["substeps"]
        nsteps = int(round(self.duration / dt))
        need_global = True
        setup = build(self.scenario, need_global)
        s = setup.system
        n = s.n
        rng = np.random.default_rng(self.seed)
        try:
            if out_dir is not None:
                write_scene_picture(Path(out_dir) / "scene.png", setup)
            desired_pts, desired_z = self._desired_view(setup)
            ib = d["ibvs"]
            paper = d["controller"]["profile"] == "paper"
            predicted = ib["features"] == "predicted"
            servo = LocalCameraServo(
                LOCAL_CAMERA,
                setup.target,
                desired_pts,
                desired_z,
                gain=ib["gain"],
                mode=ib["mode"],
                compensation=ib["compensation"],
            )
            servo.controller.floor = ib["floor"]
            servo.controller.solver = ib["solver"]
            pservo = None
            if predicted:
                pservo = PredictiveServo(
                    LOCAL_CAMERA,
                    setup.target,
                    desired_pts,
                    desired_z,
                    gain=ib["gain"],
                    mode=ib["mode"],
                    floor=ib["floor"],
                    solver=ib["solver"],
                    pixel_sigma=ib["filter_pixel_sigma"],
                    window=ib["filter_window"],
                    smoothing=ib["filter_smoothing"],
                )
                pservo.detector = servo.detector
            # sensor imperfections (campaigns): their own random stream, seeded by the run seed
            sensors = SensorModel(**d["sensors"])
            sensor_rng = np.random.default_rng([self.seed, 1])
            if sensors.pixel_noise > 0 or sensors.dropout > 0:
                servo.detector = NoisyDetector(servo.detector, sensors, sensor_rng)
            if sensors.intrinsics_error > 0:
                servo.camera = perturbed_camera(LOCAL_CAMERA, sensors.intrinsics_error, sensor_rng)
            if pservo is not None:
                pservo.detector = servo.detector
                pservo.camera = servo.camera
                pservo.filter.camera = servo.camera
            delay = Delay(sensors.latency_steps) if sensors.latency_steps > 0 else None
            ctl = make_controller(setup, self.seed)
            rc = d["recovery"]
            # initial mode from the first local image
            # (up to 3 captures of the first image: one dropped frame must not start a
            # recovery)
            img0 = setup.render_local(setup.q0)
            for _ in range(3):
                det0 = servo.detector.detect(img0)
                if det0.found:
                    break
            switch = ModeSwitch(LOCAL_CAMERA, rc["margin_px"], rc["confirm"], rc["lose"])
            ibvs_start = 0.0
            if det0.found and switch.inside(det0.points):
                switch.mode = ModeSwitch.IBVS
            servo.detector.reset()
            safety = SafetyMonitor(**d["safety"])
            dist = d["disturbances"]
            loads0 = s.loads.packed().copy()
            g_target = setup.scene.target_pose
            g_cl_star = setup.local_pose(setup.q_star)

            q, qd = setup.q0.copy(), setup.qd0.copy()
            q_d = q.copy()
            if s.floating:
                q_d[:2] = 0.0
            qd_d = np.zeros(n)
            cmd = np.array([i for i in range(n) if not (s.floating and i < 2)])
            traj = None
            plan_info = None
            switch_time = None
            terminated, reason = False, None
            log = {k: [] for k in LOG_KEYS}
            frames = []
            pose_hist = {}  # capture step -> C_L pose (latency compensation)
            last_fused = -1
            last_seen = None  # time of the last fused detection
            cg_missed = None  # since when recovery waits for a C_G snapshot
            wall0 = time.perf_counter()
            steps = range(nsteps + 1)
            if self.progress:
                from tqdm import tqdm

                steps = tqdm(steps, desc=self.scenario.name, unit="step")
            glob_every = d["cameras"]["global_every"]
            for k in steps:
                t = k * dt
                # ---------------------------------------------------------- cameras
                img_l = setup.render_local(q)
                g_cl = setup.local_pose(q)
                g_b = s.base_pose(q)
                gv = virtual_camera_transform(g_b, g_cl) if s.floating else None
                g_servo = virtual_camera_pose(g_b, g_cl) if s.floating else g_cl
                if predicted:
                    # detection of this frame, delivered `latency_steps` later with its
                    # capture step; fused with the C_L pose at capture time
                    pose_hist[k] = g_cl
                    det_now = servo.detector.detect(img_l)
                    k_cap, det = delay((k, det_now)) if delay is not None else (k, det_now)
                    for old in [j for j in pose_hist if j < k_cap]:
                        del pose_hist[old]
                    if det.found and k_cap > last_fused:
                        last_fused = k_cap
                        if pservo.measure(det, pose_hist[k_cap]):
                            last_seen = k_cap * dt
                    pservo.predict(dt)
                    ps = pservo.step(g_servo, g_cl)
                    pix = det.points if det.found else None
                    # measured points in the servo camera (for the log only)
                    st = None
                    meas_pts = None
                    if det.found:
                        try:
                            xy = servo.camera.normalize(det.points)
                            z = estimate_depths(xy, setup.target.feature_points)
                            meas_pts = (
                                virtual_camera_points(xy, gv, z, "exact") if gv is not None else xy
                            )
                        except ValueError:
                            meas_pts = None
                    found = ps.valid
                else:
                    st = servo.step(img_l, gv)
                    if delay is not None:  # the controller acts on an older image
                        st = delay(st)
                    pix = st.detection.points if st.found else None
                    meas_pts = st.points if st.found else None
                    found = st.found and st.twist is not None
                want_global = (
                    self.video
                    or (glob_every > 0 and k % glob_every == 0)
                    or (switch.mode == ModeSwitch.RECOVERY and traj is None)
                )
                img_g, det_g = None, None
                if want_global:
                    img_g = setup.render_global(q)
                    det_g = TargetDetector(setup.target).detect(img_g)
                if self.video:
                    frames.append(_side_by_side(img_l, img_g, pix))
                # ---------------------------------------------------------- mode + reference
                prev_mode = switch.mode
                if predicted and switch.mode == ModeSwitch.IBVS:
                    # lost only if nothing was fused for `lost_timeout` s or the predicted
                    # points leave C_L's image (for `lose` frames)
                    ok = (
                        ps.valid
                        and last_seen is not None
                        and t - last_seen <= rc["lost_timeout"]
                        and ps.pixels_local is not None
                        and bool(np.all(LOCAL_CAMERA.pixels_in_image(ps.pixels_local, 0.0)))
                    )
                    mode = switch.update(ps.pixels_local if ok else None)
                else:
                    mode = switch.update(pix)
                if prev_mode == ModeSwitch.RECOVERY and mode == ModeSwitch.IBVS:
                    if switch_time is None:
                        switch_time = t
                    ibvs_start = t
                    safety.arm(t)
                    traj = None
                    # q_d continues from the recovery reference (continuous error)
                twist = np.zeros(6)
                qdd_d = np.zeros(n)
                if mode == ModeSwitch.IBVS and found:
                    twist = ps.twist if predicted else st.twist
                    rates = camera_joint_rates(
                        s,
                        q,
                        twist,
                        setup.tip_mount,
                        jacobian_at="virtual" if s.floating else "actual",
                    )
                    new_qd = np.zeros(n)
                    if paper:  # the plain law: no limits, no ramp, no filter
                        new_qd[cmd] = rates[cmd]
                        qd_d = new_qd
                    else:
                        lim = np.full(n, ib["max_joint_rate"])
                        if s.floating:
                            lim[3:5] = ib["max_drone_speed"]
                            lim[5] = ib["max_vertical_speed"]
                        t_ib = t - ibvs_start
                        ramp = (
                            1.0 - np.exp(-t_ib / ib["soft_start"]) if ib["soft_start"] > 0 else 1.0
                        )
                        scale = max(1.0, float(np.max(np.abs(rates[cmd]) / lim[cmd])))
                        new_qd[cmd] = rates[cmd] / scale
                        # soft start; the first-order smoothing below starts from the
                        # recovery's last joint rates (smooth hand-over) and keeps the IBVS
                        # from exciting the coupled roll/strain mode (~2 Hz)
                        target_qd = ramp * new_qd
                        a_f = min(1.0, dt / ib["rate_filter"]) if ib["rate_filter"] > 0 else 1.0
                        qd_prev = qd_d
                        qd_d = qd_d + a_f * (target_qd - qd_d)
                        if ib["accel_feedforward"]:
                            # the filtered rate's derivative: the low-level loop follows the
                            # deceleration instead of lagging into an overshoot
                            qdd_d = (qd_d - qd_prev) / dt
                    # paper: qdd_d = 0 (IBVS gives rates only, qdd_r = -beta edot)
                    q_d = q_d + qd_d * dt
                    if not paper and ib["reference_leak"] > 0:
                        # q_d is only an integrated rate; the vision loop closes on the
                        # actual pose, so pull q_d toward q (no wind-up while the plant lags)
                        q_d[cmd] += ib["reference_leak"] * dt * (q[cmd] - q_d[cmd])
                elif mode == ModeSwitch.RECOVERY:
                    if traj is None:
                        if det_g is None:  # recovery needs a snapshot: render C_G now
                            img_g = setup.render_global(q)
                            det_g = TargetDetector(setup.target).detect(img_g)
                        if not det_g.corners:
                            # hold and retry (C_L may see it again, C_G on the next frame)
                            # until the loss is confirmed for `lost_timeout` s
                            cg_missed = t if cg_missed is None else cg_missed
                            if paper or t - cg_missed >= rc["lost_timeout"]:
                                terminated, reason = True, "recovery: target not seen by C_G"
                                break
                            qd_d = np.zeros(n)
                        else:
                            cg_missed = None
                            try:
                                plan, traj, g_t = self._plan(setup, q, t, det_g)
                            except ValueError as exc:
                                terminated, reason = True, f"recovery planning failed: {exc}"
                                break
                            plan_info = {
                                "t": t,
                                "q_s_d": plan.q_s.tolist(),
                                "point_local": plan.point_local.tolist(),
                                "cost": plan.cost,
                                "success": plan.success,
                                "duration": traj.duration,
                            }
                            q_d = q.copy()
                            if s.floating:
                                q_d[:2] = 0.0
                    if traj is not None:
                        qs_d, qsd_d, qsdd_d = traj(t)
                        q_d[n - s.n_s :] = qs_d
                        qd_d = np.zeros(n)
                        qd_d[n - s.n_s :] = qsd_d
                        qdd_d = np.zeros(n)
                        qdd_d[n - s.n_s :] = qsdd_d
                else:  # IBVS mode, measured features, target missed this frame: hold
                    qd_d = np.zeros(n)
                # ---------------------------------------------------------- low level
                cs = ctl.step(q, qd, q_d, qd_d, qdd_d, dt)
                # ---------------------------------------------------------- logging
                if predicted:
                    pts_v = ps.points if ps.valid else None
                    feats = ps.features if ps.valid else np.full(6, np.nan)
                    ferr = ps.error if ps.valid else np.full(6, np.nan)
                else:
                    pts_v = meas_pts
                    feats = st.features if st.found else np.full(6, np.nan)
                    ferr = st.error if st.found else np.full(6, np.nan)
                raw = LOCAL_CAMERA.normalize(pix) if pix is not None else None
                rmse = normalized_rmse(pts_v, desired_pts)
                rmse_raw = normalized_rmse(raw, desired_pts)
                true_pts, _ = LocalCameraServo.reference_from_pose(
                    LOCAL_CAMERA, setup.target, g_target, g_servo
                )
                nanp = np.full((4, 2), np.nan)
                log["t"].append(t)
                log["q"].append(q.copy())
                log["qd"].append(qd.copy())
                log["q_d"].append(q_d.copy())
                log["qd_d"].append(qd_d.copy())
                log["u"].append(cs.u)
                log["tau"].append(cs.tau)
                log["q_ref"].append(cs.q_ref)
                log["features"].append(feats)
                log["feature_error"].append(ferr)
                log["points_local"].append(raw if raw is not None else nanp)
                log["points_virtual"].append(pts_v if pts_v is not None else nanp)
                log["rmse"].append(rmse)
                log["rmse_raw"].append(rmse_raw)
                log["rmse_measured"].append(normalized_rmse(meas_pts, desired_pts))
                log["rmse_true"].append(normalized_rmse(true_pts, desired_pts))
                te = np.nan
                if pservo is not None and pservo.filter.initialized:
                    te = _rotation_angle_deg(np.linalg.solve(g_target, pservo.filter.pose)[:3, :3])
                log["target_error_deg"].append(te)
                log["mode"].append(MODE_CODES[mode])
                log["V"].append(cs.V)
                log["detected_local"].append(bool(pix is not None))
                log["detected_global"].append(bool(det_g.found) if det_g is not None else False)
                log["thrust_saturated"].append(cs.thrust_saturated)
                log["tension_saturated"].append(cs.tension_saturated)
                log["twist"].append(twist)
                log["delta_hat"].append(cs.delta_hat)
                if mode == ModeSwitch.IBVS and not safety.check(t, rmse):
                    terminated, reason = True, safety.reason
                    break
                if k == nsteps:
                    break
                # ---------------------------------------------------------- plant
                loads = loads0.copy()
                amp = vec(dist["base_wrench_amplitude"])
                if np.any(amp) and dist["base_wrench_frequency"] > 0 and s.floating:
                    loads[3:9] = amp * np.sin(2 * np.pi * dist["base_wrench_frequency"] * t)
                down = vec(dist["downwash"])
                if np.any(down) or dist["downwash_noise"] > 0:
                    loads[15:18] = down + dist["downwash_noise"] * rng.standard_normal(3)
                qs_, qds_, ok = rk4_run(q, qd, cs.u, dt / sub, sub, sub, s.model_arrays, loads)
                q, qd = qs_[-1].copy(), qds_[-1].copy()
                if not ok or not np.all(np.isfinite(q)):
                    terminated, reason = True, "plant integration failed (singular mass matrix)"
                    break
            # figures of merit against the reference (desired) configuration
            g_cl_end = setup.local_pose(q)
            dg = np.linalg.solve(g_cl_star, g_cl_end)
            self._merit = {
                "final_camera_position_error_m": float(
                    np.linalg.norm(g_cl_end[:3, 3] - g_cl_star[:3, 3])
                ),
                "final_camera_rotation_error_deg": _rotation_angle_deg(dg[:3, :3]),
                "final_drone_position_error_m": (
                    float(np.linalg.norm(q[3:6] - setup.q_star[3:6])) if s.floating else None
                ),
            }
            if pservo is not None and pservo.filter.initialized:
                e = np.linalg.solve(g_target, pservo.filter.pose)
                self._merit["final_target_estimate_error_m"] = float(np.linalg.norm(e[:3, 3]))
                self._merit["final_target_estimate_error_deg"] = _rotation_angle_deg(e[:3, :3])
                # the filter's own 1-sigma of the worst rotation direction (its covariance)
                self._merit["final_target_estimate_sigma_deg"] = float(
                    np.degrees(np.sqrt(np.linalg.eigvalsh(pservo.filter.P[:3, :3]).max()))
                )
            wall = time.perf_counter() - wall0
        finally:
            setup.close()
        arrays = {k: np.asarray(v) for k, v in log.items()}
        summary = self._summary(
            arrays, terminated, reason, wall, switch_time, plan_info, s, desired_pts
        )
        if out_dir is not None:
            write_outputs(out_dir, arrays, summary, desired_pts, frames, s)
        return arrays, summary

    def _summary(self, a, terminated, reason, wall, switch_time, plan_info, s, desired_pts):
        rmse = a["rmse"]
        t = a["t"]
        finite = np.isfinite(rmse)
        initial = float(rmse[finite][0]) if finite.any() else None
        final = float(rmse[finite][-1]) if finite.any() else None

        def reach(level):
            idx = np.flatnonzero(finite & (rmse <= level))
            return float(t[idx[0]]) if idx.size else None

        u = a["u"]
        na = s.n_a
        return {
            "scenario": self.scenario.name,
            "seed": self.seed,
            "duration": float(t[-1]) if t.size else 0.0,
            "requested_duration": self.duration,
            "dt": self.scenario.data["dt"],
            "perturbation": self.scenario.data["model"]["perturbation"],
            "initial_rmse": initial,
            "final_rmse": final,
            "min_rmse": float(np.nanmin(rmse)) if finite.any() else None,
            "time_to_0.01": reach(0.01),
            "time_to_0.001": reach(0.001),
            "mode_switch_time": switch_time,
            "initial_mode": "recovery" if a["mode"].size and a["mode"][0] == 1 else "ibvs",
            "recovery_plan": plan_info,
            "terminated": bool(terminated),
            "termination_reason": reason,
            "wall_time_s": wall,
            "wall_per_sim_second": wall / max(float(t[-1]) if t.size else 0.0, 1e-9),
            "max_tension": float(u[:, -na:].max()) if u.size else 0.0,
            "min_tension": float(u[:, -na:].min()) if u.size else 0.0,
            "max_thrust": float(u[:, :4].max()) if (u.size and s.floating) else None,
            "tension_saturated_steps": int(np.sum(a["tension_saturated"])),
            "thrust_saturated_steps": int(np.sum(a["thrust_saturated"])),
            "final_q": a["q"][-1].tolist() if a["q"].size else None,
            "local_detection_rate": float(np.mean(a["detected_local"])) if t.size else 0.0,
            "final_rmse_true": _last_finite(a["rmse_true"]),
            "final_rmse_measured": _last_finite(a["rmse_measured"]),
            "profile": self.scenario.data["controller"]["profile"],
            **getattr(self, "_merit", {}),
        }


def _last_finite(x):
    x = np.asarray(x, float)
    f = np.isfinite(x)
    return float(x[f][-1]) if f.any() else None


def _side_by_side(img_l, img_g, pix):
    import cv2

    left = cv2.resize(img_l, (500, 500), interpolation=cv2.INTER_AREA)
    if pix is not None:
        for p in np.asarray(pix) * 500 / img_l.shape[1]:
            cv2.circle(left, (int(p[0]), int(p[1])), 4, (255, 0, 0), -1)
    right = img_g if img_g is not None else np.zeros((500, 500, 3), np.uint8)
    if right.shape[:2] != (500, 500):
        right = cv2.resize(right, (500, 500))
    return np.concatenate((left, right[:, :, :3]), axis=1)


def write_scene_picture(path: Path, setup: Setup) -> None:
    """The scenario's geometry as the cameras see it: C_L at the start, C_L at the desired
    configuration (the reference snapshot), C_G at the start (arm drawn)."""
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    tiles = []
    for label, img in (
        ("C_L initial", setup.render_local(setup.q0)),
        ("C_L desired (reference)", setup.render_local(setup.q_star)),
        ("C_G initial", setup.render_global(setup.q0)),
    ):
        t = cv2.resize(
            np.ascontiguousarray(img[:, :, :3]), (500, 500), interpolation=cv2.INTER_AREA
        )
        cv2.putText(t, label, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 0), 2)
        tiles.append(t)
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(tiles, axis=1), cv2.COLOR_RGB2BGR))


def write_outputs(out_dir, a, summary, desired_pts, frames, system):
    from .outputs import write_all

    write_all(Path(out_dir), a, summary, desired_pts, frames, system)


def run_scenario(
    name, out=None, config=None, duration=None, seed=None, video=False, progress=False
):
    """Load and run a scenario; returns ``(arrays, summary)`` and writes ``out`` if given."""
    sc = load_scenario(name, config)
    sim = Simulation(sc, duration=duration, seed=seed, video=video, progress=progress)
    return sim.run(out)
