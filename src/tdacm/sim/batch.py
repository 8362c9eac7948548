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

import copy
from collections import deque
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from ..batch import Batch, BatchResult
from ..batch.control import P_MIN_LIFT_FORCE, controller_arrays
from ..batch.engine import BatchModel
from ..batch.pack import Unsupported, check_loop, servo_model, target_points
from ..batch.params import ROBOT_FACTORS, SENSOR_FIELDS, TARGET_FIELDS, WorldParams, robot_rows
from ..batch.plant import plant_arrays
from ..control.hierarchical import default_gains
from ..loop.sensors import AnalyticFrontEnd, perturbed_camera
from ..system.kernels import coupled_terms
from .assemble import build_loop, reference_snapshot
from .scenario import Scenario, ScenarioError, load_scenario

#: the model arrays a world's robot replaces (:func:`~tdacm.batch.params.robot_rows`)
_ROBOT_FIELDS = ("stiffness", "damping", "step_mass", "mb6", "tendon_d", "tendon_dd")
_GAINS = ("beta", "A_d", "A_p", "A_a")


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


def _sensor_for(local, target, scene):
    """A copy of the tip camera ``local`` seeing ``target`` at ``scene``'s pose (for the
    reference snapshot of a world with its own target pose)."""
    out = copy.copy(local)
    out.front_end = AnalyticFrontEnd(local.front_end.camera, target, scene.target_pose)
    out._fifo = deque(maxlen=local.model.latency_steps + 1)
    return out


class _Robot:
    """A world's robot as :func:`~tdacm.control.hierarchical.default_gains` reads a system:
    its size and its mass matrix (of the world's model arrays ``m``)."""

    def __init__(self, system, m):
        self.n, self.floating, self.n_s = system.n, system.floating, system.n_s
        self._m, self._loads = m, system.loads.packed()

    def terms(self, q, qd):
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        return SimpleNamespace(M=coupled_terms(q, qd, self._m, self._loads, True)[0])


def _gains_of(a, f) -> np.ndarray | None:
    """``(3, n, n)`` the gains ``A_d, A_p, A_a`` of the robot of factors ``f`` (5,) when the
    scenario's controller has the default gains (shaped by the robot's inertia at the desired
    configuration); ``None``: the scenario's (other gains, or the scenario's masses)."""
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
    m = s.model_arrays._replace(mb6=rows["mb6"][0], step_mass=rows["step_mass"][0])
    g = default_gains(_Robot(s, m), q_star, c.config)
    return np.ascontiguousarray(np.stack([g.A_d, g.A_p, g.A_a]), dtype=float)


def _world_rows(a, seed: int, params: WorldParams | None, w: int) -> dict:
    """World ``w``'s rows (seed ``seed``, parameters row ``w`` of ``params``): the
    controller's model error, scalars and gains, its camera model, reference snapshot and
    target."""
    loop = a.loop
    a.model.reseed(int(seed))
    ca, _ = controller_arrays(loop.controller, loop.dt)
    out = {"coord": ca.coord, "damping": ca.damping, "params": ca.params, "gains": ca.gains}
    f = None if params is None else params.robot_factors(params.n_worlds)[w]
    if f is not None and np.any(f != 1.0):
        gains = _gains_of(a, f)
        if gains is not None:
            out["gains"] = gains
        sd = a.model.damping_scale
        d = a.model.system.model_arrays.damping * f[ROBOT_FACTORS.index("damping")]
        out["damping"] = np.ascontiguousarray(sd[:, None] * d * sd[None, :])
        c = loop.controller.controller
        s = loop.plant.system
        mb = s.base.mass * f[ROBOT_FACTORS.index("drone_mass")] if s.floating else 0.0
        rod = s.arms[0].rod
        total = mb + (rod.mass * f[ROBOT_FACTORS.index("rod_mass")] + rod.tip_mass)
        p = ca.params.copy()
        p[P_MIN_LIFT_FORCE] = c.min_lift * float(total * np.linalg.norm(s.loads.gravity))
        out["params"] = p
    world = a.world
    scene = world_scene(world, params, w)
    local = loop.sensors.local
    err = local.model.intrinsics_error
    own_target = scene is not world.scene
    cam = None
    if err > 0:  # the seed's camera model and the reference snapshot it takes
        cam = perturbed_camera(world.robot.local_camera, err, np.random.default_rng([seed, 1]))
    if err > 0 or own_target:
        sensor = _sensor_for(local, world.target, scene) if own_target else local
        ctl = loop.perception.local_camera if cam is None else cam
        out["ctl"] = ctl
        out["ref"] = reference_snapshot(sensor, world.robot, world.target, scene, world.q_star, ctl)
    if own_target:
        out["target"] = target_points(world.target, scene.target_pose)
    return out


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
    a = build_loop(sc, int(seeds[0])) if assembly is None else assembly
    loop = a.loop
    try:
        check_loop(loop)  # the blocks first: a refusal names the scenario's key
        base, cm = controller_arrays(loop.controller, loop.dt)
        pa, pm = plant_arrays(loop.plant)
        if any(not np.array_equal(getattr(pm, k), getattr(cm, k)) for k in _ROBOT_FIELDS):
            raise Unsupported("the controller's model describes another robot than the plant")
        rows = [_world_rows(a, int(s), params, w) for w, s in enumerate(seeds)]
        a.model.reseed(int(seeds[0]))
        ctl = refs = targets = None
        if any("ref" in r for r in rows):
            ctl = [r.get("ctl", loop.perception.local_camera) for r in rows]
            refs = [r.get("ref", (loop.servo.desired_points, loop.servo.desired_depths))
                    for r in rows]  # fmt: skip
        if any("target" in r for r in rows):
            fe = loop.sensors.local.front_end
            shared = (np.array(fe._corners_w, float), fe._features_w)
            targets = [r.get("target", shared) for r in rows]
        sensor = None
        if params is not None and params.given(SENSOR_FIELDS):
            m = loop.sensors.local.model
            sensor = params.sensor_rows([m.pixel_noise, m.dropout, m.latency_steps])
        sm = servo_model(loop, seeds.size, ctl, refs, targets, sensor)
    except (Unsupported, ValueError) as exc:
        raise ScenarioError(f"{sc.source}: the batched engine: {exc}") from None
    f = (
        np.ones((seeds.size, len(ROBOT_FACTORS)))
        if params is None
        else params.robot_factors(seeds.size)
    )
    robot = robot_rows(pm, f)
    dur = float(sc.data["duration"] if duration is None else duration)
    steps = int(round(dur / loop.dt))
    model = BatchModel(
        sm, base, cm,
        np.ascontiguousarray([r["coord"] for r in rows]),
        np.ascontiguousarray([r["damping"] for r in rows]),
        np.ascontiguousarray([r["params"] for r in rows]),
        pa, pm, float(loop.dt), steps,
        robot["stiffness"], robot["rod_damping"], robot["step_mass"], robot["mb6"],
        robot["tendon_d"], robot["tendon_dd"],
        np.ascontiguousarray([r["gains"] for r in rows]),
    )  # fmt: skip
    q0 = a.world.q0 if q0 is None else q0
    n_u = loop.plant.system.n_u
    batch = Batch(model, seeds, q0, a.world.qd0, n_u, threads)
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
    world; ``None``: the batch's own for ``w``): its rows in place, drawn as
    :func:`build_batch` draws them, and ``batch.seeds[w]``, from which
    :meth:`~tdacm.batch.Batch.reset` starts its random streams. A latency beyond the one the
    batch was built with is refused (its buffers are sized then). Call ``batch.reset`` for
    the world afterwards."""
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    loop, model = assembly.loop, batch.model
    row, rw = params, 0
    if row is None and getattr(batch, "params", None) is not None:
        row, rw = batch.params, w
    r = _world_rows(assembly, seed, row, rw)
    model.coord[w] = r["coord"]
    model.damping[w] = r["damping"]
    model.control_params[w] = r["params"]
    model.gains[w] = r["gains"]
    sm = model.servo
    if "ref" in r:
        one = servo_model(loop, 1, [r["ctl"]], [r["ref"]])
        sm.ctl_camera[w] = one.ctl_camera[0]
        sm.desired_points[w] = one.desired_points[0]
        sm.desired_depths[w] = one.desired_depths[0]
        sm.desired_features[w] = one.desired_features[0]
        sm.desired_interaction[w] = one.desired_interaction[0]
    fe = loop.sensors.local.front_end
    corners, features = r.get("target", (np.array(fe._corners_w, float), fe._features_w))
    sm.corners[w] = corners
    sm.features[w] = features
    m = loop.sensors.local.model
    nominal = [m.pixel_noise, m.dropout, m.latency_steps]
    sn = nominal if row is None else row.sensor_rows(nominal)[rw]
    if sn[2] > batch.data.fifo_found.shape[1] - 1:
        raise ValueError(
            f"latency {int(sn[2])}: the batch buffers {batch.data.fifo_found.shape[1] - 1} frames"
        )
    sm.sensor[w] = sn
    f = (
        np.ones((1, len(ROBOT_FACTORS)))
        if row is None
        else row.robot_factors(row.n_worlds)[rw : rw + 1]
    )
    rr = robot_rows(model.plant_model, f)
    model.stiffness[w] = rr["stiffness"][0]
    model.rod_damping[w] = rr["rod_damping"][0]
    model.step_mass[w] = rr["step_mass"][0]
    model.mb6[w] = rr["mb6"][0]
    model.tendon_d[w] = rr["tendon_d"][0]
    model.tendon_dd[w] = rr["tendon_dd"][0]
    batch.seeds[w] = seed
