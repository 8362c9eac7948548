"""A scenario's batched engine: N worlds of its closed loop in lockstep
(:mod:`tdacm.batch`), assembled from the same blocks as the block loop.

:func:`build_batch` assembles the scenario's loop once (:func:`~tdacm.sim.assemble.build_loop`)
and packs its blocks; what depends on a world's seed is drawn per world as ``build_loop``
draws it for that seed: the controller's model error (``[model] perturbation``) and, with an
intrinsics error, the controller's camera model and the reference snapshot taken with it.
Per-world parameters (:class:`~tdacm.batch.params.WorldParams`: the robot's stiffness,
damping, masses and tendon moment arms, C_L's imperfections, the target's pose) give each
world the rows the block loop built on that world's scenario has (tested equal).
:func:`run_batch` runs the worlds to the end and returns their arrays.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from .._compiling import compiling
from .._records import put, replicate, stack, take
from ..batch import Batch, BatchResult, empty_data
from ..batch.engine import BatchModel
from ..batch.params import MAX_LATENCY, ROBOT_FACTORS, SENSOR_FIELDS, TARGET_FIELDS, WorldParams
from ..control.hierarchical import TDACMController, controller_params, default_gains
from ..estimation import ekf_step as EK
from ..estimation.block import Estimation, EstimationData, FilterBlock
from ..estimation.config import EstimatorConfig, SensorSuiteConfig
from ..estimation.contact_force import ForceOut, ForceState
from ..estimation.ekf import ExtendedKalmanFilter, ekf_params
from ..estimation.proprioception import SensorSuite
from ..loop.arms import ArmsServo
from ..loop.config import TouchConfig
from ..loop.estimation import TrueState
from ..loop.lowlevel import AdaptiveLowLevel, PDGravityController
from ..loop.sensors import AnalyticFrontEnd, perturbed_camera
from ..loop.servo import RobustServo, VisualServo
from ..loop.touch import (
    TipForceBlock,
    TouchData,
    TouchLaw,
    TouchOut,
    TouchRecords,
    TouchServo,
    TouchState,
    touch_views,
)
from ..loop.touch_arms import (
    ArmsForceBlock,
    ArmsTouchServo,
    SqueezeLaw,
    SqueezeOut,
    SqueezeState,
)
from ..system.kernels import coupled_terms
from ..system.worlds import robot_rows
from ..vision.features import advanced_features, feature_interaction_matrix
from . import compile_engine
from .assemble import build_loop, reference_views
from .blocks import startup_sensors
from .scenario import Scenario, ScenarioError, load_scenario

log = logging.getLogger(__name__)

#: the model arrays a world's robot replaces (:class:`~tdacm.system.worlds.RobotRows`)
_ROBOT_FIELDS = ("stiffness", "damping", "step_mass", "mb6", "tendon_d", "tendon_dd")
_GAINS = ("beta", "A_d", "A_p", "A_a")


class Unsupported(ValueError):
    """A scenario the engine does not run; the message names the key."""


#: the scenario keys a world can have its own value of, and the
#: :class:`~tdacm.batch.params.WorldParams` field each gives: a value, or (for the robot) the
#: ratio of the world's value to the scenario's
SCENARIO_KEYS = {
    "sensors.pixel_noise": "pixel_noise",
    "sensors.dropout": "dropout",
    "sensors.latency_steps": "latency",
    "scene.target_tilt_deg": "target_tilt_deg",
    "scene.target_yaw_deg": "target_yaw_deg",
    "scene.box_xy": "target_xy",
    "robot.rod.youngs_modulus": "stiffness",
    "robot.rod.damping": "damping",
    "robot.drone.mass": "drone_mass",
    "robot.rod.density": "rod_mass",
    "robot.tendons.radius": "moment_arm",
}


def _value(cfg, key: str):
    node = cfg
    for part in key.split("."):
        node = getattr(node, part)
    return node


def world_params(scenario: Scenario, configs, keys) -> WorldParams | None:
    """The :class:`~tdacm.batch.params.WorldParams` of worlds whose scenario records
    ``configs`` (one :class:`~tdacm.sim.config.ScenarioConfig` per world) differ from
    ``scenario``'s in the keys ``keys`` (of :data:`SCENARIO_KEYS`); ``None`` for no key.
    ``ValueError`` (naming the key) when a ratio is undefined (the scenario's value is 0) or
    the tendons are given by ``offsets`` (their ``radius`` is then unused)."""
    keys = [k for k in keys if k in SCENARIO_KEYS]
    if not keys:
        return None
    base = scenario.config
    out = {}
    for key in keys:
        field = SCENARIO_KEYS[key]
        vals = np.array([_value(c, key) for c in configs], float)
        if field in ROBOT_FACTORS:
            if key == "robot.tendons.radius" and base.robot.tendons.offsets is not None:
                raise ValueError(f"{key}: the tendons are given by robot.tendons.offsets")
            ref = float(_value(base, key))
            if ref == 0.0:
                if np.any(vals != 0.0):
                    raise ValueError(f"{key}: the scenario's value is 0; worlds scale it")
                continue
            vals = vals / ref
        out[field] = vals
    return WorldParams(**out) if out else None


def arm_scene(world, params: WorldParams | None, w: int, k: int):
    """World ``w``'s scene of arm ``k`` of a robot with several arms: the arm's marker
    (its own place and yaw) with the world's board tilt from ``params`` plus the arm's
    ``marker.extra_tilt_deg``, as :func:`~tdacm.sim.assemble.build_world` builds it for that
    world's scenario (the scenario's ``box_xy`` and ``target_yaw_deg`` place no arm's
    marker)."""
    base = world.scenes[k]
    if params is None or params.target_tilt_deg is None:
        return base
    tilt = np.add(params.target_tilt_deg[w], world.robot.arms[k].marker_tilt_deg)
    return replace(base, target_tilt_deg=tuple(float(x) for x in tilt))


def world_scene(world, params: WorldParams | None, w: int):
    """World ``w``'s scene (of a :class:`~tdacm.sim.assemble.World`): the scenario's with
    its target pose from ``params``."""
    if params is None or not params.given(TARGET_FIELDS):
        return world.scene
    kw = {}
    if params.target_tilt_deg is not None:
        kw["target_tilt_deg"] = tuple(float(x) for x in params.target_tilt_deg[w])
    if params.target_yaw_deg is not None:
        kw["target_yaw_deg"] = float(params.target_yaw_deg[w])
    if params.target_xy is not None:
        kw["box_xy"] = tuple(float(x) for x in params.target_xy[w])
    return replace(world.scene, **kw)


class _Robot:
    """A world's robot as :func:`~tdacm.control.hierarchical.default_gains` reads a system:
    its size and its mass matrix (of the world's model arrays ``m``)."""

    def __init__(self, system, m):
        self.n, self.floating, self.n_s = system.n, system.floating, system.n_s
        self._m, self._loads = m, system.loads.packed()

    def terms(self, q, qd):
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        return SimpleNamespace(M=coupled_terms(q, qd, self._m, self._loads, True)[0])


def arm_blocks(loop) -> tuple[list, list, list, list]:
    """The per-arm blocks of an assembled loop: ``(tip cameras, C_G sensors, perceptions,
    servos)``, one of each per arm (arm 0 first; C_G detecting each arm's marker)."""
    sensors = loop.sensors
    locals_ = list(getattr(sensors, "locals_", None) or [sensors.local])
    globals_ = [sensors.global_, *getattr(sensors, "globals_", [])]
    perceptions = list(getattr(loop.perception, "arms", None) or [loop.perception])
    servos = list(loop.servo.arms) if isinstance(loop.servo, ArmsServo) else [loop.servo]
    return locals_, globals_, perceptions, servos


def refuse(loop) -> None:
    """Refuse (:class:`Unsupported`, naming the scenario key) the blocks the engine does not
    run: rendered cameras, a user's controller class, and what is not batched yet."""
    locals_, globals_, _, servos = arm_blocks(loop)
    if not all(isinstance(s.front_end, AnalyticFrontEnd) for s in locals_):
        raise Unsupported(
            "the engine's tip camera is analytic: set cameras.local_renderer = 'analytic'"
        )
    if isinstance(loop.servo, ArmsServo) and type(loop.servo) not in (ArmsServo, ArmsTouchServo):
        raise Unsupported(f"the servo {type(loop.servo).__name__} is not batched")
    if any(type(s) not in (VisualServo, RobustServo, TouchServo) for s in servos):
        raise Unsupported(f"the servo {type(loop.servo).__name__} is not batched")
    if not isinstance(loop.estimator, TrueState | FilterBlock):
        raise Unsupported(
            f"estimation: the engine runs the true state or the shipped EKF, got "
            f"{type(loop.estimator).__name__}"
        )
    if loop.force is not None and type(loop.force) not in (TipForceBlock, ArmsForceBlock):
        raise Unsupported(f"the force block {type(loop.force).__name__} is not batched")
    if any(g is None for g in globals_):
        raise Unsupported("the engine needs the global camera C_G")
    if not all(isinstance(g.front_end, AnalyticFrontEnd) for g in globals_):
        raise Unsupported(
            "the engine's global camera is analytic: set cameras.global_renderer = 'planar' "
            "(with the analytic C_L)"
        )
    low = loop.controller
    if type(low) not in (AdaptiveLowLevel, PDGravityController):
        raise Unsupported(
            f"controller.class: the engine runs the shipped controllers, got "
            f"{type(low).__module__}.{type(low).__qualname__}"
        )
    if type(low.controller) is not TDACMController:
        raise Unsupported("controller.class: the engine runs the shipped controllers")
    if max(s.model.latency_steps for s in locals_) > MAX_LATENCY:
        raise Unsupported(f"sensors.latency_steps: the engine buffers {MAX_LATENCY} frames")


def _reference(points, depths):
    """The servo's reference records of a snapshot: points (4, 2), depths (4,), features (6,)
    and interaction matrix (6, 6)."""
    pts = np.ascontiguousarray(points, float)
    z = np.ascontiguousarray(np.broadcast_to(np.asarray(depths, float), (4,)))
    return pts, z, advanced_features(pts), feature_interaction_matrix(pts, z)


def world_records(a, seed: int, params: WorldParams | None, w: int) -> dict:
    """World ``w``'s block records (seed ``seed``, parameters row ``w`` of ``params``), each as
    the block loop built on that world's scenario has it: the controller's (its model error
    drawn from the seed, its gains and masses for the world's robot), and per arm (lists,
    arm 0 first) the tip camera's (the world's target and imperfections), C_G's, the
    perception's and the servo's (the seed's camera model and the reference snapshot taken
    with it), and the robot's factors."""
    loop = a.loop
    low = loop.controller.controller
    a.model.reseed(int(seed))
    s = loop.plant.system
    f = np.ones(len(ROBOT_FACTORS))
    if params is not None:
        f = params.robot_factors(params.n_worlds)[w]
    gains = low.gains
    if np.any(f != 1.0):
        gains = _gains_of(a, f) or gains
    ctl = controller_params(s, a.model, gains, low.config, low.exact_attitude, low.params.law)
    if np.any(f != 1.0):
        sd = a.model.damping_scale
        d = a.model.system.model_arrays.damping * f[ROBOT_FACTORS.index("damping")]
        mb = s.base.mass * f[ROBOT_FACTORS.index("drone_mass")] if s.floating else 0.0
        rod = s.arms[0].rod
        total = mb + (rod.mass * f[ROBOT_FACTORS.index("rod_mass")] + rod.tip_mass)
        ctl = ctl._replace(
            model=ctl.model._replace(damping=np.ascontiguousarray(sd[:, None] * d * sd[None, :])),
            min_lift_force=low.config.min_lift * float(total * np.linalg.norm(s.loads.gravity)),
        )
    world = a.world
    locals_, globals_, perceptions, servos = arm_blocks(loop)
    several = len(locals_) > 1
    out = {"controller": ctl, "factors": f, "sensor": [], "global_sensor": [], "servo": [],
           "perception": [], "ekf": _ekf_params(a)}  # fmt: skip
    servo0 = arm_blocks(loop)[3][0]
    if isinstance(loop.force, TipForceBlock) and isinstance(servo0, TouchServo):
        # the force estimate's model is the controller's (the seed's model error, the world's
        # damping)
        out["force"] = loop.force.record(a.model)._replace(model=ctl.model)
        out["touch_refs"] = [servo.refs for servo in servos]  # every arm's
    for k, (local, glob, perception, servo) in enumerate(
        zip(locals_, globals_, perceptions, servos, strict=True)
    ):
        sensor, g_rec = local.params, glob.params
        base_scene = world.scenes[k] if several else world.scene
        scene = arm_scene(world, params, w, k) if several else world_scene(world, params, w)
        if scene is not base_scene:  # the world's own target pose
            fe = AnalyticFrontEnd(local.front_end.camera, world.target, scene.target_pose)
            sensor = sensor._replace(corners=fe.corners_world, features=fe.features_world)
            g_rec = g_rec._replace(corners=fe.corners_world, features=fe.features_world)
        if params is not None and params.given(SENSOR_FIELDS):
            m = local.model
            row = params.sensor_rows([m.pixel_noise, m.dropout, m.latency_steps])[w]
            sensor = sensor._replace(pixel_noise=float(row[0]), dropout=float(row[1]),
                                     latency=int(row[2]))  # fmt: skip
        s_rec, p_rec = servo.params, perception.params
        err = local.model.intrinsics_error
        if err > 0 or scene is not base_scene:  # the seed's camera model, its snapshot
            cam = perception.local_camera
            if err > 0:
                nominal = world.robot.arms[k].local_camera if several else world.robot.local_camera
                rng = np.random.default_rng([seed, 1, k] if k else [seed, 1])
                cam = perturbed_camera(nominal, err, rng)
            snap = local if scene is base_scene else local.seeing(world.target, scene.target_pose)
            views = reference_views(snap, world.robot, world.target, scene, world.q_star, cam)
            pts, z, feats, inter = _reference(*views[1])
            if isinstance(servo, TouchServo):  # the touch law's views from the same snapshot
                out["touch_refs"][k] = touch_views(servo.ibvs, views[1], views[0],
                                                   servo.touch.standoff)[2]  # fmt: skip
            cp = cam.params()
            s_rec = s_rec._replace(
                camera=cp, desired_points=pts, desired_depths=z, desired_features=feats,
                desired_interaction=inter, filter=s_rec.filter._replace(record=s_rec.filter.record.with_camera(cam)),
            )  # fmt: skip
            p_rec = p_rec._replace(camera=cp)
        out["sensor"].append(sensor)
        out["global_sensor"].append(g_rec)
        out["servo"].append(s_rec)
        out["perception"].append(p_rec)
    return out


def touch_records(a, rows) -> tuple[TouchRecords, TouchData]:
    """The engine's touch records of the worlds of ``rows`` (:func:`world_records`): the
    loop's touch law, each world's views and force estimate when it servoes into contact
    (one arm), else records of the default law that the engine does not read (``on``
    false); and one world's state records."""
    loop = a.loop
    s = loop.plant.system
    n = len(rows)
    servos = arm_blocks(loop)[3]
    servo = servos[0]
    arms = len(servos)
    touching = isinstance(servo, TouchServo) and isinstance(loop.force, TipForceBlock)
    squeeze_on = touching and isinstance(loop.servo, ArmsTouchServo)
    on = touching and not squeeze_on
    tc = loop.servo.touch if touching else TouchConfig()
    if touching:
        law = loop.servo.law
        force = stack([r["force"] for r in rows])
        refs = stack([r["touch_refs"][0] for r in rows])
        arm_refs = stack([stack(r["touch_refs"]) for r in rows])
    else:
        law = TouchLaw.from_config(tc)
        reference = (servo.desired_points, servo.desired_depths)
        refs = replicate(touch_views(servo.ibvs, reference, reference, tc.standoff)[2], n)
        arm_refs = replicate(stack([take(refs, 0)] * arms), n)
        unused = TipForceBlock(a.model, servo.tip_mount, None, tc.input_sigma, "momentum",
                               tc.observer_gain)  # fmt: skip
        force = replicate(unused.params, n)
    touch = TouchRecords(on=on, law=replicate(law, n), refs=refs, force=force,
                         squeeze_on=squeeze_on, squeeze=replicate(SqueezeLaw.from_config(tc), n),
                         arm_refs=arm_refs)  # fmt: skip
    k = take(force, 0).rods.shape[0]
    data = TouchData(TouchState.initial(), TouchOut.empty(), ForceState.initial(s.n, s.n_u),
                     ForceOut.empty(k), SqueezeState.initial(arms),
                     SqueezeOut.empty(arms))  # fmt: skip
    return touch, data


def _ekf_params(a):
    """The filter's record for the assembly's model as now seeded: the loop's EKF, or for a
    loop on the true state a filter of the default sensors (unused: the engine's records
    have one type for either)."""
    est = a.loop.estimator
    if isinstance(est, FilterBlock):
        f = est.filter
        return ekf_params(a.model, f.sensors, f.config, f.q_ref, f.camera)
    s = a.model.system
    return ekf_params(a.model, SensorSuiteConfig(), EstimatorConfig(), np.zeros(s.n_s), None)


def estimation_records(a, seeds, rows, dt: float) -> tuple[Estimation, EstimationData]:
    """The engine's estimation records of the worlds ``seeds`` (their filters' ``rows``): the
    loop's EKF and sensors when it runs on estimates, else records of the default sensors that
    the engine does not read (``on`` false)."""
    loop = a.loop
    est = loop.estimator
    s = loop.plant.system
    n = len(seeds)
    on = isinstance(est, FilterBlock)
    if on:
        other = loop.sensors.other
        suite_cfg = est.filter.sensors
        filt = est.filter
    else:
        other, suite_cfg, filt = {}, SensorSuiteConfig(), None
    # the sensors' records; a robot without a drone has no pose sensor and no IMU: disabled
    off = suite_cfg.model_copy(update=dict(
        pose=suite_cfg.pose.model_copy(update=dict(enabled=False)),
        imu=suite_cfg.imu.model_copy(update=dict(enabled=False)),
    ))  # fmt: skip
    drone = SensorSuite(_Floating(s), off, 0)
    pose = other.get("pose", drone.pose)
    imu = other.get("imu", drone.imu)
    encoders = other.get("encoders") or SensorSuite(s, suite_cfg, 0).encoders
    start = startup_sensors(suite_cfg, s, 0)
    start_pose = start.pose if start.pose is not None else drone.pose
    ekf = stack([r["ekf"] for r in rows])
    p0 = take(ekf, 0)
    nominal = est.nominal_q if on else np.zeros(s.n)
    q_ref = filt.q_ref if on else np.zeros(s.n_s)
    model = Estimation(
        on=on,
        ekf=ekf,
        pose=replicate(pose.params, n),
        imu=replicate(imu.params, n),
        encoders=replicate(encoders.params, n),
        start_pose=replicate(start_pose.params, n),
        start_encoders=replicate(start.encoders.params, n),
        measured=bool(on and est.initial_measurements is not None),
        nominal=replicate(np.asarray(nominal, float), n),
        q_ref=replicate(np.asarray(q_ref, float), n),
        strain_error=float(est.strain_error) if on else 0.0,
        position_error=float(est.position_error) if on else 0.0,
        fuse_view=bool(on and est.normalize is not None),
    )
    window = EK.window_ticks(filt.config.max_delay, dt) if on else 2
    slots = 2 * ExtendedKalmanFilter.SLOTS
    data = EstimationData(
        ekf=EK.EkfState.empty(p0, window, slots),
        meas=EK.EkfMeasurements.empty(p0, slots),
        pose=pose.state,
        imu=imu.state,
        encoders=encoders.state,
        start_pose=start_pose.state,
        start_encoders=start.encoders.state,
        q_hat=np.zeros(s.n),
        qd_hat=np.zeros(s.n),
        p_qq=np.zeros((s.n, s.n)),
        status=np.zeros(1, np.int64),
        qdd=np.zeros(s.n),
        has_qdd=np.zeros(1, np.bool_),
        out=np.zeros(max(12, s.n_a)),
    )
    return model, data


class _Floating:
    """A system as a sensor suite reads it, with a drone (for disabled drone sensors)."""

    def __init__(self, system):
        self.floating = True
        self.loads = system.loads
        self.model_arrays = system.model_arrays
        self.n_s, self.n_a = system.n_s, system.n_a


def _gains_of(a, f):
    """``AdaptiveGains`` of the robot of factors ``f`` (5,) when the scenario's controller has
    the default gains (shaped by the robot's inertia at the desired configuration); ``None``:
    the scenario's (other gains, or the scenario's masses)."""
    mass = [ROBOT_FACTORS.index("drone_mass"), ROBOT_FACTORS.index("rod_mass")]
    if np.all(f[mass] == 1.0):
        return None
    c = a.loop.controller.controller
    s = a.loop.plant.system
    q_star = a.world.q_star
    nominal = default_gains(s, q_star, c.config)
    if any(not np.array_equal(getattr(nominal, k), getattr(c.gains, k)) for k in _GAINS):
        return None  # gains given by the user: not shaped by the inertia
    rows = robot_rows(s.model_arrays, f[None, :])
    m = s.model_arrays._replace(mb6=rows.mb6[0], step_mass=rows.step_mass[0])
    return default_gains(_Robot(s, m), q_star, c.config)


@compiling("engine")
def build_batch(
    scenario, seeds, duration=None, q0=None, threads=None, assembly=None, params=None
) -> Batch:
    """A :class:`~tdacm.batch.Batch` of ``scenario`` (a name, path or
    :class:`~tdacm.sim.scenario.Scenario`) with one world per seed of ``seeds``, for
    ``duration`` seconds (default the scenario's), from ``q0`` ((N, n) or (n,); default the
    scenario's initial state), stepped by ``threads`` threads (default: the machine's cores;
    the results do not depend on it), each world with its parameters of ``params`` (a
    :class:`~tdacm.batch.params.WorldParams`; default: the scenario's for all). A scenario the
    engine does not run raises :class:`~tdacm.sim.scenario.ScenarioError` naming the key.
    ``assembly``: the scenario's loop already assembled
    (:func:`~tdacm.sim.assemble.build_loop`), reused instead of a new one
    (:func:`reseed_world` needs it)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    seeds = np.asarray(seeds, np.int64).ravel()
    if sc.config.servo.policy is not None:
        raise ScenarioError(
            f"{sc.source}: the batched engine: servo.policy runs in the block loop "
            "(tdacm run, a campaign with batched = false or 'auto')"
        )
    if seeds.size == 0:
        raise ScenarioError("seeds: at least one world")
    if params is not None:
        if not isinstance(params, WorldParams):
            raise ScenarioError(f"params: a WorldParams, got {type(params).__name__}")
        if params.n_worlds not in (None, seeds.size):
            raise ScenarioError(f"params: {params.n_worlds} worlds for {seeds.size} seeds")
        if params.n_worlds is None:
            params = None
        elif params.latency is not None and np.any(params.latency > MAX_LATENCY):
            raise ScenarioError(f"params.latency: the engine buffers {MAX_LATENCY} frames")
    a = build_loop(sc, int(seeds[0])) if assembly is None else assembly
    loop = a.loop
    try:
        refuse(loop)  # the blocks first: a refusal names the scenario's key
        pm = loop.plant.system.model_arrays
        cm = a.model.system.model_arrays
        if any(not np.array_equal(getattr(pm, k), getattr(cm, k)) for k in _ROBOT_FIELDS):
            raise Unsupported("the controller's model describes another robot than the plant")
        rows = [world_records(a, int(s), params, w) for w, s in enumerate(seeds)]
        a.model.reseed(int(seeds[0]))
        estimation, estimation_data = estimation_records(a, seeds, rows, float(loop.dt))
        touch, touch_data = touch_records(a, rows)
    except (Unsupported, ValueError) as exc:
        raise ScenarioError(f"{sc.source}: the batched engine: {exc}") from None
    dur = float(sc.data["duration"] if duration is None else duration)
    n = seeds.size
    arms = lambda key: stack([stack(r[key]) for r in rows])  # noqa: E731 - (worlds, arms)
    model = BatchModel(
        sensor=arms("sensor"),
        global_sensor=arms("global_sensor"),
        perception=arms("perception"),
        servo=arms("servo"),
        controller=stack([r["controller"] for r in rows]),
        safety=replicate(loop.safety.params, n),
        plant=replicate(loop.plant.params, n),
        robot=robot_rows(pm, np.array([r["factors"] for r in rows])),
        plant_model=pm,
        control_model=cm,
        dt=float(loop.dt),
        steps=int(round(dur / loop.dt)),
        global_every=int(loop.sensors.global_every),
        n_arms=len(loop.plant.system.arms),
        estimation=estimation,
        touch=touch,
    )
    q0 = a.world.q0 if q0 is None else q0
    n_u = loop.plant.system.n_u
    # on a cold cache the engine compiles in two processes (tdacm.sim.compile_engine): its
    # types are those of one world's data
    like = empty_data(model, 1, loop.plant.system.n, n_u, estimation_data, touch_data)
    ahead = compile_engine.start(model, like)
    try:
        if ahead:
            compile_engine.first(model, like)
        batch = Batch(model, seeds, q0, a.world.qd0, n_u, threads, estimation_data, touch_data)
        if ahead:
            compile_engine.finish(model, like)
    finally:
        compile_engine.stop()  # nothing left for it to do (or the batch failed)
    batch.params = params
    return batch


def run_batch(
    scenario, seeds, duration=None, q0=None, log_states=False, params=None
) -> BatchResult:
    """Run ``scenario``'s worlds of ``seeds`` (:func:`build_batch`) to the end."""
    return build_batch(scenario, seeds, duration, q0, params=params).run(log_states=log_states)


def reseed_world(batch: Batch, assembly, w: int, seed: int, params=None) -> None:
    """Give world ``w`` of ``batch`` (built by :func:`build_batch` with ``assembly``) the seed
    ``seed`` and the parameters ``params`` (a :class:`~tdacm.batch.params.WorldParams` of one
    world; ``None``: the batch's own for ``w``): its records in place, drawn as
    :func:`build_batch` draws them, and ``batch.seeds[w]``, from which
    :meth:`~tdacm.batch.Batch.reset` starts its random streams. A latency beyond the one the
    batch was built with is refused (its buffers are sized then). Call ``batch.reset`` for the
    world afterwards."""
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    model = batch.model
    row, rw = params, 0
    if row is None and getattr(batch, "params", None) is not None:
        row, rw = batch.params, w
    r = world_records(assembly, seed, row, rw)
    cap = batch.data.sensor.found.shape[2] - 1
    latency = max(s.latency for s in r["sensor"])
    if latency > cap:
        raise ValueError(f"latency {latency}: the batch buffers {cap} frames")
    for key in ("sensor", "global_sensor", "perception", "servo"):
        put(getattr(model, key), w, stack(r[key]))
    put(model.controller, w, r["controller"])
    put(model.estimation.ekf, w, r["ekf"])
    if model.touch.on or model.touch.squeeze_on:
        put(model.touch.refs, w, r["touch_refs"][0])
        put(model.touch.arm_refs, w, stack(r["touch_refs"]))
        put(model.touch.force, w, r["force"])
    put(model.robot, w, take(robot_rows(model.plant_model, r["factors"][None, :]), 0))
    batch.seeds[w] = seed
