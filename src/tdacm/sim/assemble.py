"""Assembling the closed loop from a scenario (``tdacm run``, campaigns and the env use it).

:func:`build_loop` turns a validated :class:`~tdacm.sim.scenario.Scenario` into an
:class:`Assembly`: the :class:`~tdacm.loop.ClosedLoop` with the :class:`World` it was built
from and its seed. The loop is made of the robot of its ``[robot]`` section, the scene, the cameras
and their imperfections (``[cameras]``, ``[sensors]``), the reference snapshot, the servo
(``[ibvs]``, ``[recovery]``), the controller (``[model]``, ``[controller]``, or a user class),
the disturbances, the aerodynamics and wind (``[aerodynamics]``, ``[wind]``) and the safety
monitor. Randomness: the model perturbation is drawn from the run's seed, the sensor
imperfections from ``[seed, 1]``, the disturbances from ``seed`` and the turbulence from
``[seed, 21]``, so a run is reproducible from its seed.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from .._linalg import solve as _solve
from ..aero.config import AerodynamicsConfig, WindConfig
from ..control import EstimatedModel
from ..control.allocation import box_least_squares
from ..estimation import (
    EstimatorConfig,
    ExtendedKalmanFilter,
    FilterBlock,
    SensorSuite,
    SensorSuiteConfig,
)
from ..estimation.camera import TargetCamera
from ..lie.se3 import rotation_angle
from ..loop.ablation import TruthAblation, parse_controller_truth
from ..loop.closed_loop import ClosedLoop
from ..loop.config import (
    ControllerConfig,
    IbvsConfig,
    RecoveryConfig,
    SafetyConfig,
    SensorModel,
    TouchConfig,
)
from ..loop.logger import RunLog
from ..loop.lowlevel import make_low_level
from ..loop.perception import Perception
from ..loop.plant import Disturbances, Plant
from ..loop.precompile import wait
from ..loop.protocols import ControllerContext
from ..loop.safety import SafetyMonitor
from ..loop.sensors import (
    AnalyticFrontEnd,
    CameraSensor,
    RenderedFrontEnd,
    Sensors,
    perturbed_camera,
)
from ..loop.servo import RecoveryParams, RobustParams, RobustServo, ShapingParams, VisualServo
from ..loop.touch import TipForceBlock, TouchServo
from ..system.aero import aero_array
from ..system.contact import probe_offset
from ..system.kernels import rk4_run
from ..vision import PAPER_MARKER, PAPER_PATTERN, PlanarRenderer, SceneConfig
from ..vision.features import estimate_depths
from ..vision.target_filter import reference_from_pose
from ..vision.virtual import virtual_camera_points, virtual_camera_transform, virtual_pose
from .robot import Robot, build_robot
from .scenario import Scenario, ScenarioError, check_with_world

#: What ``controller.profile = "paper"`` sets (the paper's literal choices, docs/control.md
#: "Profiles"): gravity lumped into Delta_hat, the approximate compensation p_V = R p_L on the
#: measured points, the plain law v = -lambda J_img^-1 e (no floor, no command shaping, rates
#: held at zero on a missed frame), the bare 5 % safety rule.
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
    return replace(scenario, data=d, source=scenario.source + " (profile paper)")


@dataclass(frozen=True)
class World:
    """The static world and the robot of a scenario: the robot, the scene (box and target),
    the target, the initial state ``(q0, qd0)`` and the desired configuration ``q_star``."""

    robot: Robot
    scene: SceneConfig
    target: object
    q0: np.ndarray
    qd0: np.ndarray
    q_star: np.ndarray


def build_world(scenario: Scenario) -> World:
    """The :class:`World` of a scenario, checked against the built robot
    (:func:`~tdacm.sim.scenario.check_with_world`: the plant's step limit, the target in front
    of C_L at the desired configuration)."""
    d = scenario.data
    held = d["system"]["held_base_q"] if not scenario.floating else None
    try:
        robot = build_robot(d["robot"], held)
    except ValueError as exc:
        raise ScenarioError(f"{scenario.source}: {exc}") from None
    sc = d["scene"]
    target = PAPER_MARKER if sc["target"] == "aruco" else PAPER_PATTERN
    scene = SceneConfig(
        target=target,
        box_size=sc["box_size"],
        box_xy=tuple(sc["box_xy"]),
        target_yaw_deg=sc["target_yaw_deg"],
        target_tilt_deg=tuple(sc["target_tilt_deg"]),
    )
    n = robot.system.n
    q0 = np.asarray(d["initial"]["q"], float)
    qd0 = np.zeros(n) if d["initial"]["qd"] is None else np.asarray(d["initial"]["qd"], float)
    world = World(robot, scene, target, q0, qd0, np.asarray(d["desired"]["q"], float))
    check_with_world(scenario, world)
    return world


def _front_end(kind: str, camera, scene: SceneConfig, target, backend: str = "auto"):
    if kind == "analytic":
        return AnalyticFrontEnd(camera, target, scene.target_pose)
    if kind == "pybullet":
        from ..vision import PyBulletRenderer

        return RenderedFrontEnd(
            camera, lambda: PyBulletRenderer(scene, backend=backend), target, False
        )
    if kind == "planar-local":  # C_L: grey images (what the detector uses; faster)
        return RenderedFrontEnd(camera, PlanarRenderer(scene, grayscale=True), target, True)
    return RenderedFrontEnd(camera, PlanarRenderer(scene), target, False)


def reference_snapshot(local: CameraSensor, robot: Robot, target, scene, q_star, controller_camera):
    """The paper's reference snapshot: C_L's view at the desired configuration (detected;
    the analytic projection if the detector misses it or its corners admit no pose in front
    of the camera), in C_V for a floating base."""
    s = robot.system
    g_c = local.pose(q_star)
    try:
        ref, z = reference_from_pose(target, scene.target_pose, g_c)
    except ValueError as exc:
        raise ScenarioError(f"desired.q: {exc}") from None
    det, _ = local.ideal(q_star)
    local.reset()
    pts = ref
    if det.found:
        detected = controller_camera.normalize(det.points)
        try:
            z = estimate_depths(detected, target.feature_points)
            pts = detected
        except ValueError:  # corners no pose explains (a grazing view): as a missed detection
            pass
    if s.floating:
        gv = virtual_camera_transform(s.base_pose(q_star), g_c)
        pts, z = virtual_camera_points(pts, gv, z, "exact", return_depths=True)
    return pts, z


@dataclass(frozen=True)
class Assembly:
    """What :func:`build_loop` assembled: the closed loop, the world it runs in, its seed."""

    loop: ClosedLoop
    world: World
    seed: int
    model: EstimatedModel | None = None  # the controller's model (perturbation drawn from seed)
    scenario: Scenario | None = None  # as assembled (profile applied)

    @property
    def reseedable(self) -> bool:
        """Whether :func:`reseed` can give this loop another seed's random streams in place:
        not with an intrinsics error (the controller's camera, hence the reference snapshot,
        depends on the seed), with the estimator (its sensors and filter are seeded when
        built) or with a user controller (it may copy the model when built); those need
        :func:`build_loop` again."""
        d = self.scenario.data if self.scenario is not None else None
        return (
            d is not None
            and self.model is not None
            and d["sensors"]["intrinsics_error"] == 0
            and d["estimation"]["source"] == "true"
            and not d["controller"]["class"]
        )


def reseed(assembly: Assembly, seed: int) -> Assembly:
    """The assembled loop with the random streams of ``seed``, without rebuilding it: the
    controller's model perturbation (drawn from ``seed``), C_L's imperfections (``[seed, 1]``),
    the disturbances (``seed``) and the turbulence (``[seed, 21]``), as :func:`build_loop` seeds
    them, so a reseeded loop runs as one built with ``seed`` (tested). Only when
    :attr:`Assembly.reseedable`."""
    from dataclasses import replace

    if not assembly.reseedable:
        raise ValueError("this loop cannot be reseeded in place (see Assembly.reseedable)")
    seed = int(seed)
    loop = assembly.loop
    assembly.model.reseed(seed)
    loop.sensors.local.rng = np.random.default_rng([seed, 1])
    loop.plant.rng = np.random.default_rng(seed)
    if loop.plant.wind is not None:  # the turbulence of [seed, WIND_STREAM]
        loop.plant.wind = air_of(assembly.scenario, assembly.world, seed)[1]
    return replace(assembly, seed=seed)


def build_loop(
    scenario: Scenario,
    seed: int | None = None,
    video: bool = False,
    controller=None,
    servo=None,
    estimator=None,
    frame_composer=None,
) -> Assembly:
    """The closed loop of ``scenario`` (module docstring). ``controller``, ``servo`` and
    ``estimator`` replace the scenario's blocks (objects implementing the protocols of
    :mod:`tdacm.loop.protocols`)."""
    scenario = apply_profile(scenario)
    d = scenario.data
    seed = int(d["seed"] if seed is None else seed)
    paper = d["controller"]["profile"] == "paper"
    world = build_world(scenario)
    robot, s = world.robot, world.robot.system
    cams = d["cameras"]
    sensor_model = SensorModel(**{k: d["sensors"][k] for k in SensorModel.model_fields})
    sensor_rng = np.random.default_rng([seed, 1])
    kind = "planar-local" if cams["local_renderer"] == "planar" else "analytic"
    local = CameraSensor(
        s,
        "tip",
        robot.tip_mount,
        _front_end(kind, robot.local_camera, world.scene, world.target),
        sensor_model,
        sensor_rng,
        keep_images=video,
    )
    glob = None
    g_kind = cams["global_renderer"]
    if g_kind == "planar" and cams["local_renderer"] == "analytic":
        g_kind = "analytic"
    glob = CameraSensor(
        s,
        "base",
        robot.drone_mount,
        _front_end(g_kind, robot.global_camera, world.scene, world.target, cams["global_backend"]),
        keep_images=video,
    )
    # the proprioceptive sensors of the EKF (estimation.source = "estimated"), read every period
    suite = None
    if estimator is None and d["estimation"]["source"] == "estimated":
        suite = proprioceptive_sensors(d, s, seed)
    sensors = Sensors(
        local,
        glob,
        cams["global_every"],
        always_global=video,
        other=suite.named if suite is not None else None,
        global_output_every=cams["global_output_every"],
    )
    # the controller's model of C_L (intrinsics error drawn after nothing else: reproducible)
    ctl_camera = perturbed_camera(robot.local_camera, sensor_model.intrinsics_error, sensor_rng)
    perception = Perception(ctl_camera, robot.global_camera, world.target)
    desired_pts, desired_z = reference_snapshot(
        local, robot, world.target, world.scene, world.q_star, ctl_camera
    )
    ib, rc = IbvsConfig(**d["ibvs"]), RecoveryConfig(**d["recovery"])
    touch = TouchConfig(**d["touch"])
    if touch.enabled and not (d["scene"]["obstacles"] or d["scene"]["contact"]["target_box"]):
        raise ScenarioError(
            f"{scenario.source}: touch.enabled needs something to touch: "
            "scene.contact.target_box = true or [[scene.obstacles]]"
        )
    if servo is None:
        if paper:  # the plain law: no limits, no ramp, no filter
            shaping = ShapingParams(
                max_joint_rate=np.inf,
                max_drone_speed=np.inf,
                max_vertical_speed=np.inf,
                soft_start=0.0,
                rate_filter=0.0,
            )
        else:
            shaping = ShapingParams.from_config(ib)
        args = (
            s,
            ctl_camera,
            robot.global_camera,
            world.target,
            robot.tip_mount,
            robot.drone_mount,
            desired_pts,
            desired_z,
        )
        kwargs = dict(
            gain=ib.gain,
            mode=ib.mode,
            compensation=ib.compensation,
            shaping=shaping,
            recovery=RecoveryParams.from_config(rc),
        )
        if touch.enabled:
            if ib.features != "predicted" or paper:
                raise ScenarioError(
                    f"{scenario.source}: touch.enabled needs the robust servo "
                    "(ibvs.features = 'predicted', controller.profile = 'default')"
                )
            servo = TouchServo(
                *args, robust=RobustParams.from_config(ib, rc), touch=touch, **kwargs
            )
        elif ib.features == "predicted":
            servo = RobustServo(*args, robust=RobustParams.from_config(ib, rc), **kwargs)
        else:
            servo = VisualServo(*args, floor=ib.floor, solver=ib.solver, **kwargs)
    m = d["model"]
    model = EstimatedModel(
        s, m["perturbation"], seed, m["gravity_feedforward"], known_rotor_drag(scenario, s)
    )
    if controller is None:
        ctl = ControllerConfig(**d["controller"])
        # the [controller] keys the adaptive law reads, and the user's [controller.options]
        options = {**ctl.model_dump(exclude={"class_", "options"}), **ctl.options}
        ctx = ControllerContext(s, model, world.q_star, d["dt"], options)
        try:
            controller = make_low_level(ctl.class_, ctx, search=_folders(scenario))
        except ValueError as exc:
            raise ScenarioError(f"{scenario.source}: {exc}") from None
    aero, wind = air_of(scenario, world, seed)
    plant = Plant(
        s,
        world.q0,
        world.qd0,
        d["substeps"],
        Disturbances.from_dict(d["disturbances"]),
        np.random.default_rng(seed),
        accelerations=suite is not None,  # the accelerometer senses qdd
        aero=aero,
        wind=wind,
        **contact_plant_options(d["scene"], s, robot.tip_mount, robot.probe_length),
    )
    force = None
    if touch.enabled and isinstance(servo, TouchServo):
        force = TipForceBlock(
            model, robot.tip_mount, probe_offset(robot.tip_mount, robot.probe_length),
            touch.input_sigma,
        )  # fmt: skip
    truth = d["estimation"]["controller_truth"]
    if truth:  # ablation: the controller reads these coordinates from the plant
        try:
            q_idx, qd_idx = parse_controller_truth(truth, s.n)
        except ValueError as exc:
            raise ScenarioError(f"{scenario.source}: {exc}") from None
        controller = TruthAblation(controller, plant, q_idx, qd_idx)
    if suite is not None:
        estimator = estimation_block(
            d, s, seed, plant, suite, world.q0, model, robot.tip_mount, world.target, ctl_camera
        )
    loop = ClosedLoop(
        plant,
        sensors,
        perception,
        servo,
        controller,
        d["dt"],
        estimator=estimator,
        safety=SafetyMonitor(**SafetyConfig(**d["safety"]).model_dump()),
        log=RunLog(servo.desired_points, frame_composer, _truth(s, local, world)),
        name=scenario.name,
        force=force,
    )
    if plant.contact is not None:
        loop.log.contact = contact_logger(s, plant.contact)
    warm_up(s, world.q0)
    return Assembly(loop, world, seed, model, scenario)


def contact_plant_options(scene: dict, system, tip_mount=None, probe_length=0.0) -> dict:
    """The :class:`~tdacm.loop.plant.Plant` keywords of ``[scene]``'s obstacles and
    ``[scene.contact]`` (none without obstacles: the contact-free plant); the tip sphere on
    a probe of ``probe_length`` along the optical axis of C_L mounted at ``tip_mount``."""
    from ..contact.config import ContactConfig, ObstacleConfig, box_obstacle
    from ..system.contact import contact_array, probe_offset

    cc = ContactConfig(**scene.get("contact", {}))
    obstacles = [ObstacleConfig(**o).obstacle() for o in scene.get("obstacles", [])]
    if cc.target_box:
        obstacles.append(box_obstacle(scene["box_size"], scene["box_xy"]))
    if not obstacles:
        return {}
    return {
        "contact": contact_array(
            system,
            cc.model(obstacles),
            probe_offset(tip_mount, probe_length) if probe_length else (0.0, 0.0, 0.0),
        ),
        "contact_substeps": cc.substeps,
        "contact_margin": cc.margin,
        "force_limit": cc.force_limit,
    }


def contact_logger(system, contact):
    """``(q, qd) -> (tip force, rod force)`` of the obstacles (inertial, N), for the log."""
    from ..system.contact import contact_state

    def forces(q, qd):
        st = contact_state(system, q, qd, contact)
        return st.tip, st.rod

    return forces


def known_rotor_drag(scenario: Scenario, system):
    """The drone's rotor drag coefficients the controller's model knows (``[model] rotor_drag``
    with the drone drag of ``[aerodynamics]`` on a floating base), or ``None``."""
    d = scenario.data
    cfg = AerodynamicsConfig(**d["aerodynamics"])
    if not (d["model"]["rotor_drag"] and cfg.enabled and cfg.drone_drag and system.floating):
        return None
    return tuple(cfg.drone_linear)


def air_of(scenario: Scenario, world: World, seed: int):
    """``(aero, wind)`` of the plant: the packed aerodynamics of ``[aerodynamics]`` with the
    rotors of ``[robot.drone]`` (:func:`tdacm.system.aero.aero_array`) and the
    :class:`~tdacm.aero.Wind` of ``[wind]`` (turbulence from its own stream of ``seed``, sampled
    every control period, its scales at the drone's initial height); ``(None, None)`` when
    ``aerodynamics.enabled`` is false (the aerodynamically empty plant)."""
    d = scenario.data
    cfg = AerodynamicsConfig(**d["aerodynamics"])
    if not cfg.enabled:
        return None, None
    s = world.robot.system
    drone = d["robot"]["drone"]
    try:
        record = cfg.record(drone["rotor_radius"], drone["layout"], drone["arm_length"])
        height = float(s.base_pose(world.q0)[2, 3])
        wind = WindConfig(**d["wind"]).build(d["dt"], seed, height)
    except ValueError as exc:
        raise ScenarioError(f"{scenario.source}: [aerodynamics]/[wind]: {exc}") from None
    return aero_array(s, record), wind


def _truth(system, local: CameraSensor, world: World):
    """``q -> (true points of the target in the servo camera, true target pose)`` for the
    logger (C_V for a floating base, C_L for a fixed one)."""
    g_t = world.scene.target_pose
    obj = world.target.feature_points

    def truth(q):
        g = local.pose(q)
        if system.floating:
            g = virtual_pose(system.base_pose(q), g)
        r = _solve(g, g_t)
        pc = obj @ r[:3, :3].T + r[:3, 3]
        return pc[:, :2] / pc[:, 2:3], g_t

    return truth


def proprioceptive_sensors(d: dict, system, seed: int):
    """The drone pose, IMU and tendon-encoder sensors of ``[sensors]`` (a
    :class:`~tdacm.estimation.SensorSuite` seeded by ``[seed, 11..13]``): the sensors block
    reads them every period for the EKF."""
    return SensorSuite(system, SensorSuiteConfig.from_section(d["sensors"]), seed)


def estimation_block(
    d: dict, system, seed: int, plant: Plant, suite, q_nominal, model, tip_mount, target, camera
):
    """``estimation.source = "estimated"``: the EKF (``[estimation]``) on the controller's
    perturbed ``model``, fusing the proprioceptive sensors ``suite``
    (:func:`proprioceptive_sensors`, read by the sensors block). The initial guess
    (``initial_guess = "measured"``) comes from one start-up reading of an independent copy of
    the sensors (no latency, no dropout: taken before the run starts). With
    ``estimation.fuse_local_camera`` the filter also fuses C_L's detections of the static
    target (:mod:`tdacm.estimation.camera`): ``tip_mount``, ``target`` and ``camera`` are
    C_L's mount, the target and the controller's model of C_L."""
    est = d["estimation"]
    cfg = suite.config
    init = None
    if est["initial_guess"] == "measured":
        start = cfg.model_copy(
            update=dict(
                pose=cfg.pose.model_copy(update=dict(latency=0.0, dropout=0.0, enabled=True)),
                encoders=cfg.encoders.model_copy(
                    update=dict(latency=0.0, dropout=0.0, enabled=True)
                ),
            )
        )
        first = SensorSuite(system, start, seed, stream_offset=100)

        def init(t):
            first.reset(t)
            st = plant.state  # a sensor reading (sensors read the plant; nothing else does)
            return first.sample(st.t, st.q, st.qd, None)

    view = None
    if est["fuse_local_camera"]:
        sigma = est["camera_pixel_sigma"]
        view = TargetCamera(
            tip_mount,
            target.feature_points,
            np.array([sigma / camera.fx, sigma / camera.fy]),
            np.asarray(d["ibvs"]["target_level_normal"], float),
            est["target_initial_position_std"],
            est["target_initial_attitude_std"],
        )
    filt = ExtendedKalmanFilter(model, cfg, EstimatorConfig.from_section(est), camera=view)
    filt.warm_up()
    return FilterBlock(
        filt, init, q_nominal, est["initial_strain_error"], est["initial_position_error"],
        camera.normalize if view is not None else None,
    )  # fmt: skip


def warm_up(system, q) -> None:
    """Call the numba kernels of one period once, so that their first-use compilation (or
    loading from the on-disk cache) happens before the run, not inside its first step."""
    q = np.asarray(q, float)
    qd = np.zeros(system.n)
    system.terms(q, qd)
    system.tip_kinematics(q, qd)
    box_least_squares(np.eye(3), np.ones(3), 0.0, 1.0)
    wait()  # rk4_run may be compiling in a second process (cold cache only)
    rk4_run(q, qd, np.zeros(system.n_u), 1e-4, 1, 1, system.model_arrays, system.loads.packed())


def _folders(scenario: Scenario) -> tuple[str, ...]:
    """Where a user controller's module is looked for after ``sys.path``: the current folder
    (as ``python -m`` would), then the scenario file's folder."""
    import os

    folder = getattr(scenario, "folder", None)
    return (os.getcwd(),) + ((folder,) if folder else ())


def camera_pose_error(loop: ClosedLoop, q, q_ref) -> tuple[float, float]:
    """Position (m) and rotation (deg) error of C_L at ``q`` against its pose at ``q_ref``."""
    a = loop.sensors.local.pose(q)
    b = loop.sensors.local.pose(q_ref)
    dp = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    r = a[:3, :3].T @ b[:3, :3]
    ang = float(np.degrees(rotation_angle(r)))
    return dp, ang
