"""The closed loop's blocks built from the scenario's records, one factory per block family.

Each factory takes the records of the sections its block reads (attributes of
:class:`~tdacm.sim.config.ScenarioConfig`'s sections, never the file's dict) and the built
world; :func:`tdacm.sim.assemble.build_loop` wires them. ``source`` (the scenario's name for
messages) prefixes the one-line :class:`~tdacm.sim.scenario.ScenarioError` of a combination
the records accept alone but the loop cannot run. Randomness: the controller's model is
perturbed from the run's seed, C_L's imperfections (and the controller's intrinsics error) come
from ``[seed, 1]``, the disturbances from ``seed``, the turbulence from ``[seed, 21]``, the
proprioceptive sensors from ``[seed, 11..13]``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .._linalg import solve as _solve
from ..aero.config import AerodynamicsConfig
from ..control import EstimatedModel
from ..control.allocation import box_least_squares
from ..control.config import ModelConfig
from ..estimation import (
    EstimatorConfig,
    ExtendedKalmanFilter,
    FilterBlock,
    SensorSuite,
    SensorSuiteConfig,
)
from ..estimation.camera import TargetCamera
from ..estimation.config import EstimationConfig
from ..lie.se3 import rotation_angle
from ..loop.ablation import TruthAblation, parse_controller_truth
from ..loop.closed_loop import ClosedLoop
from ..loop.config import (
    CamerasConfig,
    ControllerConfig,
    IbvsConfig,
    RecoveryConfig,
    SensorModel,
    ServoConfig,
    TouchConfig,
)
from ..loop.lowlevel import make_low_level
from ..loop.perception import Perception
from ..loop.plant import Disturbances, Plant
from ..loop.policy import PolicyError, PolicyServo, load_policy, observation_size
from ..loop.precompile import wait
from ..loop.protocols import ControllerContext
from ..loop.sensors import (
    AnalyticFrontEnd,
    CameraSensor,
    RenderedFrontEnd,
    Sensors,
    perturbed_camera,
)
from ..loop.servo import RobustServo, VisualServo
from ..loop.touch import TipForceBlock, TouchServo
from ..system.aero import aero_array
from ..system.contact import probe_offset
from ..system.kernels import rk4_run
from ..vision import PlanarRenderer, SceneConfig
from ..vision.features import estimate_depths
from ..vision.target_filter import reference_from_pose
from ..vision.virtual import virtual_camera_points, virtual_camera_transform, virtual_pose
from .config import ScenarioConfig, SceneSection
from .robot import TipConfig
from .scenario import ScenarioError

#: The paper profile's command shaping: no rate limits, no ramp, no filter (docs/control.md,
#: "Profiles"); the rest of its choices are values of the records
#: (:data:`tdacm.sim.assemble.PAPER_PROFILE`).
PLAIN_SHAPING = dict(
    max_joint_rate=np.inf,
    max_drone_speed=np.inf,
    max_vertical_speed=np.inf,
    soft_start=0.0,
    rate_filter=0.0,
)


# ----------------------------------------------------------------------------- cameras
def front_end(kind: str, camera, scene: SceneConfig, target, backend: str = "auto"):
    """The image source of a camera sensor: ``"analytic"`` (projected corners), ``"pybullet"``,
    ``"planar-local"`` (grey planar images, what C_L's detector uses) or ``"planar"``."""
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


def camera_sensors(
    cameras: CamerasConfig, imperfections: SensorModel, world, seed: int, video: bool, suite=None
):
    """``(sensors, controller_camera)``: the sensors block (C_L with the imperfections of
    ``[sensors]``, C_G as ``[cameras]`` says, and the proprioceptive ``suite`` if any) and the
    controller's model of C_L (its intrinsics error drawn after C_L's generator is made, from
    the same ``[seed, 1]`` stream)."""
    robot, s = world.robot, world.robot.system
    rng = np.random.default_rng([seed, 1])
    kind = "planar-local" if cameras.local_renderer == "planar" else "analytic"
    local = CameraSensor(
        s,
        "tip",
        robot.tip_mount,
        front_end(kind, robot.local_camera, world.scene, world.target),
        imperfections,
        rng,
        keep_images=video,
    )
    g_kind = cameras.global_renderer
    if g_kind == "planar" and cameras.local_renderer == "analytic":
        g_kind = "analytic"
    glob = CameraSensor(
        s,
        "base",
        robot.drone_mount,
        front_end(g_kind, robot.global_camera, world.scene, world.target, cameras.global_backend),
        keep_images=video,
    )
    sensors = Sensors(
        local,
        glob,
        cameras.global_every,
        always_global=video,
        other=suite.named if suite is not None else None,
        global_output_every=cameras.global_output_every,
    )
    return sensors, perturbed_camera(robot.local_camera, imperfections.intrinsics_error, rng)


def arms_camera_sensors(cameras: CamerasConfig, imperfections: SensorModel, world, seed: int,
                        video: bool, suite=None):  # fmt: skip
    """:func:`camera_sensors` for ``[[robot.arms]]``: ``(sensors, controller_cameras)`` with
    one C_L per arm (:class:`~tdacm.loop.arms.ArmsSensors`), each seeing its own marker, and
    C_G detecting each arm's marker (the recovery per arm), and the proprioceptive ``suite``
    if any; arm 0's imperfections (and its controller camera's intrinsics error) from
    ``[seed, 1]`` as for one arm, arm k's from ``[seed, 1, k]``."""
    from ..loop.arms import ArmsSensors

    one, cam0 = camera_sensors(cameras, imperfections, world, seed, video, suite)
    robot, s = world.robot, world.robot.system
    kind = "planar-local" if cameras.local_renderer == "planar" else "analytic"
    locals_, cams, globals_ = [one.local], [cam0], []
    g_kind = cameras.global_renderer
    if g_kind == "planar" and cameras.local_renderer == "analytic":
        g_kind = "analytic"
    for k, arm in enumerate(robot.arms[1:], start=1):
        globals_.append(CameraSensor(
            s, "base", robot.drone_mount,
            front_end(g_kind, robot.global_camera, world.scenes[k], world.target,
                      cameras.global_backend),
            keep_images=video,
        ))  # fmt: skip
        rng = np.random.default_rng([seed, 1, k])
        scene = world.scenes[k]
        locals_.append(CameraSensor(
            s, "tip", arm.tip_mount, front_end(kind, arm.local_camera, scene, world.target),
            imperfections, rng, keep_images=video, rod=arm.rod,
        ))  # fmt: skip
        cams.append(perturbed_camera(arm.local_camera, imperfections.intrinsics_error, rng))
    sensors = ArmsSensors(
        locals_,
        one.global_,
        one.global_every,
        always_global=one.always_global,
        other=one.other,
        global_output_every=one.global_output_every,
        globals_=globals_,
    )
    return sensors, cams


def camera_imperfections(sensors) -> SensorModel:
    """C_L's imperfections: the camera keys of a ``[sensors]`` record."""
    return SensorModel(**{k: getattr(sensors, k) for k in SensorModel.model_fields})


def reference_views(local: CameraSensor, robot, target, scene, q_star, controller_camera):
    """The paper's reference snapshot, C_L's view at the desired configuration ``q_star``
    (detected; the analytic projection if the detector misses it or its corners admit no pose
    in front of the camera), in both cameras: ``((points, depths) in C_L, (points, depths) in
    the servo camera)``, the servo camera's being C_V for a floating base (eq. (18) at
    ``q_star``'s roll and pitch) and C_L itself for a fixed one. The C_L view is the touch
    servo's reference while its probe presses (docs/contact.md, "The hold judged on the
    task"); with a level ``q_star`` (zero roll and pitch) both views are the same."""
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
    in_local = (pts, z)
    if s.floating:
        gv = virtual_camera_transform(s.base_pose(q_star), g_c)
        pts, z = virtual_camera_points(pts, gv, z, "exact", return_depths=True)
    return in_local, (pts, z)


def reference_snapshot(local: CameraSensor, robot, target, scene, q_star, controller_camera):
    """The paper's reference snapshot in the servo camera (C_V for a floating base):
    :func:`reference_views`' second view."""
    return reference_views(local, robot, target, scene, q_star, controller_camera)[1]


def perception_block(controller_camera, world) -> Perception:
    """The perception block: the controller's models of C_L and C_G and the target."""
    return Perception(controller_camera, world.robot.global_camera, world.target)


# ----------------------------------------------------------------------------- servo
def servo_block(
    ibvs: IbvsConfig,
    recovery: RecoveryConfig,
    touch: TouchConfig,
    paper: bool,
    world,
    camera,
    desired,
    source: str,
    arm=None,
    local_reference=None,
) -> VisualServo:
    """The servo of ``[ibvs]`` and ``[recovery]``: the touch servo with ``touch.enabled``, the
    robust servo on predicted features, or the servo on the measured points; the paper
    profile's (``paper``) without command shaping. ``camera``: the controller's model of C_L;
    ``desired``: the reference snapshot ``(points, depths)``; ``arm``: the
    :class:`~tdacm.sim.robot.ArmRobot` whose C_L servoes (``[[robot.arms]]``; ``None``: the
    single arm); ``local_reference``: the reference snapshot in C_L ``(points, depths)``
    (:func:`reference_views`), the touch servo's while pressing."""
    robot = world.robot
    config = ibvs.model_copy(update=PLAIN_SHAPING) if paper else ibvs
    args = (
        robot.system,
        camera,
        robot.global_camera,
        world.target,
        robot.tip_mount if arm is None else arm.tip_mount,
        robot.drone_mount,
        *desired,
    )
    rod = {} if arm is None else {"rod": arm.rod}
    if touch.enabled:
        if ibvs.features != "predicted" or paper:
            raise ScenarioError(
                f"{source}: touch.enabled needs the robust servo "
                "(ibvs.features = 'predicted', controller.profile = 'default')"
            )
        return TouchServo(*args, config=config, recovery=recovery, touch=touch,
                          local_reference=local_reference, **rod)  # fmt: skip
    if ibvs.features == "predicted":
        return RobustServo(*args, config=config, recovery=recovery, **rod)
    return VisualServo(*args, config=config, recovery=recovery, **rod)


def force_block(touch: TouchConfig, servo, model, robot) -> TipForceBlock | None:
    """The estimated contact force of ``[touch]`` (``None`` unless the touch servo runs)."""
    if not (touch.enabled and isinstance(servo, TouchServo)):
        return None
    offset = probe_offset(robot.tip_mount, robot.probe_length)
    return TipForceBlock(
        model, robot.tip_mount, offset, touch.input_sigma, touch.force_estimator,
        touch.observer_gain,
    )  # fmt: skip


# ----------------------------------------------------------------------------- controller
def known_rotor_drag(model: ModelConfig, aero: AerodynamicsConfig, system):
    """The drone's rotor drag coefficients the controller's model knows (``[model] rotor_drag``
    with the drone drag of ``[aerodynamics]`` on a floating base), or ``None``."""
    if not (model.rotor_drag and aero.enabled and aero.drone_drag and system.floating):
        return None
    return tuple(aero.drone_linear)


def controller_model(model: ModelConfig, aero: AerodynamicsConfig, system, seed: int):
    """The controller's model of the robot (``[model]``: perturbed from ``seed``)."""
    drag = known_rotor_drag(model, aero, system)
    return EstimatedModel(system, model.perturbation, seed, model.gravity_feedforward, drag)


def controller_block(ctl: ControllerConfig, model, world, dt: float, source: str, folders=()):
    """The low-level controller of ``[controller]``: the adaptive law (its keys, the record
    whole) or the user class ``controller.class`` (looked for in ``folders`` after
    ``sys.path``), built from a :class:`~tdacm.loop.protocols.ControllerContext`."""
    options = {**ctl.model_dump(exclude={"class_", "options"}), **ctl.options}
    ctx = ControllerContext(world.robot.system, model, world.q_star, dt, options, law=ctl)
    try:
        return make_low_level(ctl.class_, ctx, search=folders)
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None


def truth_ablation(controller, truth: str, plant, source: str):
    """``estimation.controller_truth``: the controller reads these coordinates from the plant
    (unchanged when empty)."""
    if not truth:
        return controller
    try:
        q_idx, qd_idx = parse_controller_truth(truth, plant.system.n)
    except ValueError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    return TruthAblation(controller, plant, q_idx, qd_idx)


def search_folders(folder: str | None) -> tuple[str, ...]:
    """Where a user controller's module is looked for after ``sys.path``: the current folder
    (as ``python -m`` would), then the scenario file's folder."""
    return (os.getcwd(),) + ((folder,) if folder else ())


def robot_signature(cfg: ScenarioConfig, n: int, name: str | None = None) -> dict:
    """What a saved policy records of the robot it was trained for (:mod:`tdacm.loop.policy`)
    and :func:`policy_block` compares: ``signature``, a hash of the ``[robot]`` record and
    the base (``[system]``); ``n``, the robot's coordinates; ``floating``; ``scenario``:
    ``name``."""
    sysc = cfg.system
    robot = {"robot": cfg.robot.model_dump(mode="json"), "base": sysc.base}
    if sysc.base == "fixed":
        robot["held_base_q"] = list(sysc.held_base_q)
    text = json.dumps(robot, sort_keys=True)
    return {
        "signature": hashlib.sha256(text.encode()).hexdigest()[:16],
        "n": int(n),
        "floating": sysc.base == "floating",
        "scenario": name,
    }


def policy_block(cfg: ScenarioConfig, servo, world, camera, source: str, folder: str | None):
    """``servo`` itself without ``servo.policy``; else the :class:`~tdacm.loop.policy.PolicyServo`
    of the saved policy (the file relative to ``folder``, the scenario file's, then to the
    current folder), refused (one line naming the key) when it cannot be read or was trained
    for another observation size or robot (:func:`robot_signature`)."""
    servo_cfg: ServoConfig = cfg.servo
    if servo_cfg.policy is None:
        return servo
    if cfg.touch.enabled:
        raise ScenarioError(f"{source}: servo.policy: not with touch.enabled (IBVS only)")
    path = Path(servo_cfg.policy).expanduser()
    if not path.is_absolute() and folder is not None and (Path(folder) / path).exists():
        path = Path(folder) / path
    try:
        policy = load_policy(path)
    except PolicyError as exc:
        raise ScenarioError(f"{source}: servo.policy: {exc}") from None
    s = world.robot.system
    m = observation_size(s.n)
    if policy.observation_size != m:
        raise ScenarioError(
            f"{source}: servo.policy: {str(path)!r} takes observations of "
            f"{policy.observation_size} entries; this scenario's robot ({s.n} coordinates) "
            f"gives {m}"
        )
    mine = robot_signature(cfg, s.n)["signature"]
    theirs = policy.meta.get("robot", {})
    if theirs.get("signature") != mine:
        raise ScenarioError(
            f"{source}: servo.policy: {str(path)!r} was trained for another robot "
            f"(signature {theirs.get('signature')}, scenario {theirs.get('scenario')!r}); "
            f"this scenario's robot is {mine}"
        )
    cam = camera
    return PolicyServo(servo, policy, world.q_star, (cam.cx / cam.fx, cam.cy / cam.fy))


# ----------------------------------------------------------------------------- plant
def air_of(cfg: ScenarioConfig, world, seed: int, source: str = "scenario"):
    """``(aero, wind)`` of the plant: the packed aerodynamics of ``[aerodynamics]`` with the
    rotors of ``[robot.drone]`` (:func:`tdacm.system.aero.aero_array`) and the
    :class:`~tdacm.aero.Wind` of ``[wind]`` (turbulence from its own stream of ``seed``, sampled
    every control period, its scales at the drone's initial height); ``(None, None)`` when
    ``aerodynamics.enabled`` is false (the aerodynamically empty plant)."""
    aero = cfg.aerodynamics
    if not aero.enabled:
        return None, None
    s = world.robot.system
    drone = cfg.robot.drone
    try:
        record = aero.record(drone.rotor_radius, drone.layout, drone.arm_length)
        height = float(s.base_pose(world.q0)[2, 3])
        wind = cfg.wind.build(cfg.dt, seed, height)
    except ValueError as exc:
        raise ScenarioError(f"{source}: [aerodynamics]/[wind]: {exc}") from None
    return aero_array(s, record), wind


def contact_plant_options(
    scene: SceneSection, system, tip_mount=None, probe_length: float = TipConfig().probe_length
) -> dict:
    """The :class:`~tdacm.loop.plant.Plant` keywords of ``[scene]``'s obstacles and
    ``[scene.contact]`` (none without obstacles: the contact-free plant); the tip sphere on
    a probe of ``probe_length`` along the optical axis of C_L mounted at ``tip_mount``."""
    from ..contact.config import box_obstacle
    from ..system.contact import contact_array

    cc = scene.contact
    obstacles = [o.obstacle() for o in scene.obstacles]
    if cc.target_box:
        obstacles.append(box_obstacle(scene.box_size, scene.box_xy))
    if not obstacles:
        return {}
    return {
        "contact": contact_array(
            system,
            cc.model(obstacles),
            probe_offset(tip_mount, probe_length) if probe_length else (0.0, 0.0, 0.0),
        ),
        "contact_substeps": cc.contact_substeps,
        "contact_margin": cc.contact_margin,
        "force_limit": cc.force_limit,
    }


def plant_block(cfg: ScenarioConfig, world, seed: int, accelerations: bool, source: str) -> Plant:
    """The plant: the robot from the initial state, ``substeps`` RK4 steps a period, the
    ``[disturbances]`` (drawn from ``seed``), the aerodynamics and wind (:func:`air_of`) and the
    obstacles of ``[scene]``; ``accelerations``: keep ``qdd`` (the accelerometer senses it)."""
    robot = world.robot
    aero, wind = air_of(cfg, world, seed, source)
    return Plant(
        robot.system,
        world.q0,
        world.qd0,
        cfg.substeps,
        Disturbances.from_config(cfg.disturbances),
        np.random.default_rng(seed),
        accelerations=accelerations,
        aero=aero,
        wind=wind,
        **contact_plant_options(cfg.scene, robot.system, robot.tip_mount, robot.probe_length),
    )


def contact_logger(system, contact):
    """``(q, qd) -> (tip force, rod force)`` of the obstacles (inertial, N), for the log."""
    from ..system.contact import contact_state

    def forces(q, qd):
        st = contact_state(system, q, qd, contact)
        return st.tip, st.rod

    return forces


def truth_of(world, local: CameraSensor, virtual: bool = True):
    """``q -> (true points of the target in the servo camera, true target pose)`` for the
    logger (C_V for a floating base, C_L for a fixed one; ``virtual = False``: C_L always,
    the touch servo's task camera)."""
    system = world.robot.system
    g_t = world.scene.target_pose
    obj = world.target.feature_points
    to_virtual = virtual and system.floating

    def truth(q):
        g = local.pose(q)
        if to_virtual:
            g = virtual_pose(system.base_pose(q), g)
        r = _solve(g, g_t)
        pc = obj @ r[:3, :3].T + r[:3, 3]
        return pc[:, :2] / pc[:, 2:3], g_t

    return truth


# ----------------------------------------------------------------------------- estimation
#: the start-up reading's random streams: an independent copy of the sensors
#: (:func:`startup_sensors`)
STARTUP_STREAM_OFFSET = 100


def startup_sensors(config, system, seed: int) -> SensorSuite:
    """The start-up reading's sensors (``estimation.initial_guess = "measured"``): a copy of
    the suite of ``config`` (a :class:`~tdacm.estimation.SensorSuiteConfig`) with the pose and
    the encoders enabled, no latency and no dropout (read before the run starts), on their own
    streams."""
    start = config.model_copy(
        update=dict(
            pose=config.pose.model_copy(update=dict(latency=0.0, dropout=0.0, enabled=True)),
            encoders=config.encoders.model_copy(
                update=dict(latency=0.0, dropout=0.0, enabled=True)
            ),
        )
    )
    return SensorSuite(system, start, seed, stream_offset=STARTUP_STREAM_OFFSET)


def proprioceptive_sensors(sensors, system, seed: int) -> SensorSuite:
    """The drone pose, IMU and tendon-encoder sensors of a ``[sensors]`` record (a
    :class:`~tdacm.estimation.SensorSuite` seeded by ``[seed, 11..13]``): the sensors block
    reads them every period for the EKF."""
    return SensorSuite(system, SensorSuiteConfig.from_config(sensors), seed)


def estimation_block(
    est: EstimationConfig,
    level_normal,
    system,
    seed: int,
    plant: Plant,
    suite,
    q_nominal,
    model,
    tip_mount,
    target,
    camera,
):
    """``estimation.source = "estimated"``: the EKF (``[estimation]``) on the controller's
    perturbed ``model``, fusing the proprioceptive sensors ``suite``
    (:func:`proprioceptive_sensors`, read by the sensors block). The initial guess
    (``initial_guess = "measured"``) comes from one start-up reading of an independent copy of
    the sensors (no latency, no dropout: taken before the run starts). With
    ``estimation.fuse_local_camera`` the filter also fuses C_L's detections of the static
    target (:mod:`tdacm.estimation.camera`, its prior level direction ``level_normal``, the
    servo's ``ibvs.target_level_normal``): ``tip_mount``, ``target`` and ``camera`` are C_L's
    mount, the target and the controller's model of C_L."""
    cfg = suite.config
    init = None
    if est.initial_guess == "measured":
        first = startup_sensors(cfg, system, seed)

        def init(t):
            first.reset(t)
            st = plant.state  # a sensor reading (sensors read the plant; nothing else does)
            return first.sample(st.t, st.q, st.qd, None)

    view = None
    if est.fuse_local_camera:
        sigma = est.camera_pixel_sigma
        view = TargetCamera(
            tip_mount,
            target.feature_points,
            np.array([sigma / camera.fx, sigma / camera.fy]),
            np.asarray(level_normal, float),
            est.target_initial_position_std,
            est.target_initial_attitude_std,
        )
    filt = ExtendedKalmanFilter(model, cfg, EstimatorConfig.from_config(est), camera=view)
    filt.warm_up()
    return FilterBlock(
        filt, init, q_nominal, est.initial_strain_error, est.initial_position_error,
        camera.normalize if view is not None else None,
    )  # fmt: skip


# ----------------------------------------------------------------------------- helpers
def warm_up(system, q) -> None:
    """Call the numba kernels of one period once, so that their first-use compilation (or
    loading from the on-disk cache) happens before the run, not inside its first step."""
    q = np.asarray(q, float)
    qd = np.zeros(system.n)
    system.terms(q, qd)
    system.tip_kinematics(q, qd)
    box_least_squares(np.eye(3), np.ones(3), 0.0, 1.0)
    wait((rk4_run,))  # rk4_run may be compiling in a second process (cold cache only)
    rk4_run(q, qd, np.zeros(system.n_u), 1e-4, 1, 1, system.model_arrays, system.loads.packed())


def camera_pose_error(loop: ClosedLoop, q, q_ref) -> tuple[float, float]:
    """Position (m) and rotation (deg) error of C_L at ``q`` against its pose at ``q_ref``."""
    a = loop.sensors.local.pose(q)
    b = loop.sensors.local.pose(q_ref)
    dp = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    r = a[:3, :3].T @ b[:3, :3]
    ang = float(np.degrees(rotation_angle(r)))
    return dp, ang
