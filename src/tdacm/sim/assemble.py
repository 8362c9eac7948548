"""Assembling the closed loop from a scenario (``tdacm run``, campaigns and the env use it).

:func:`build_loop` turns a validated :class:`~tdacm.sim.scenario.Scenario` into an
:class:`Assembly`: the :class:`~tdacm.loop.ClosedLoop` with the :class:`World` it was built
from and its seed. It reads the scenario's typed record once
(:attr:`~tdacm.sim.scenario.Scenario.config`) and wires the blocks the factories of
:mod:`tdacm.sim.blocks` build from its sections: the robot of ``[robot]`` and the scene
(:func:`build_world`), the cameras and their imperfections (``[cameras]``, ``[sensors]``), the
reference snapshot, the servo (``[ibvs]``, ``[recovery]``, ``[touch]``; a learned policy's twist with
``[servo] policy``), the controller
(``[model]``, ``[controller]``, or a user class), the plant with its disturbances, aerodynamics,
wind and obstacles, the estimator (``[estimation]``) and the safety monitor (``[safety]``).
Randomness: the model perturbation is drawn from the run's seed, the sensor imperfections from
``[seed, 1]``, the disturbances from ``seed`` and the turbulence from ``[seed, 21]``, so a run
is reproducible from its seed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..control import EstimatedModel
from ..loop.closed_loop import ClosedLoop
from ..loop.logger import RunLog
from ..loop.safety import SafetyMonitor
from ..vision import PAPER_MARKER, PAPER_PATTERN, SceneConfig
from .blocks import (
    air_of,
    arms_camera_sensors,
    camera_imperfections,
    camera_pose_error,
    camera_sensors,
    contact_logger,
    contact_plant_options,
    controller_block,
    controller_model,
    estimation_block,
    force_block,
    known_rotor_drag,
    perception_block,
    plant_block,
    policy_block,
    proprioceptive_sensors,
    reference_snapshot,
    reference_views,
    search_folders,
    servo_block,
    truth_ablation,
    truth_of,
    warm_up,
)
from .robot import Robot, build_robot
from .scenario import Scenario, ScenarioError, check_run, check_with_world

__all__ = [
    "PAPER_PROFILE",
    "Assembly",
    "World",
    "air_of",
    "apply_profile",
    "build_loop",
    "build_world",
    "camera_pose_error",
    "contact_logger",
    "contact_plant_options",
    "estimation_block",
    "known_rotor_drag",
    "proprioceptive_sensors",
    "reference_snapshot",
    "reference_views",
    "reseed",
    "warm_up",
]

#: What ``controller.profile = "paper"`` sets (the paper's literal choices, docs/control.md
#: "Profiles"): gravity lumped into Delta_hat, the approximate compensation p_V = R p_L on the
#: measured points, the plain law v = -lambda J_img^-1 e (no floor, and no command shaping:
#: :data:`tdacm.sim.blocks.PLAIN_SHAPING`; rates held at zero on a missed frame), the bare
#: 5 % safety rule.
PAPER_PROFILE = {
    "model": {"gravity_feedforward": False},
    "ibvs": {"compensation": "approx", "features": "measured", "floor": 0.0},
    "safety": {"min_increase": 0.0, "grace": 0.0},
}


def apply_profile(scenario: Scenario) -> Scenario:
    """The scenario with its ``controller.profile`` applied (unchanged for "default")."""
    cfg = scenario.config
    if cfg.controller.profile != "paper":
        return scenario
    update = {sec: getattr(cfg, sec).model_copy(update=kv) for sec, kv in PAPER_PROFILE.items()}
    return replace(
        scenario, config=cfg.model_copy(update=update), source=scenario.source + " (profile paper)"
    )


@dataclass(frozen=True)
class World:
    """The static world and the robot of a scenario: the robot, the scene (box and target),
    the target, the initial state ``(q0, qd0)`` and the desired configuration ``q_star``;
    with ``[[robot.arms]]``, one scene per arm (its marker on its own box, ``scenes``)."""

    def arm(self, k: int) -> World:
        """The world as arm ``k`` sees it: its scene (a robot with several arms)."""
        return replace(self, scene=self.scenes[k]) if self.scenes else self

    robot: Robot
    scene: SceneConfig
    target: object
    q0: np.ndarray
    qd0: np.ndarray
    q_star: np.ndarray
    scenes: tuple = ()  # several arms: each arm's scene (its marker's box); scene = arm 0's


def build_world(scenario: Scenario) -> World:
    """The :class:`World` of a scenario, checked against the built robot
    (:func:`~tdacm.sim.scenario.check_with_world`: the plant's step limit, the target in front
    of C_L at the desired configuration)."""
    cfg = scenario.config
    held = cfg.system.held_base_q if not scenario.floating else None
    try:
        robot = build_robot(cfg.robot, held)
    except ValueError as exc:
        raise ScenarioError(f"{scenario.source}: {exc}") from None
    sc = cfg.scene
    target = PAPER_MARKER if sc.target == "aruco" else PAPER_PATTERN
    scene = SceneConfig(
        target=target,
        box_size=sc.box_size,
        box_xy=tuple(sc.box_xy),
        target_yaw_deg=sc.target_yaw_deg,
        target_tilt_deg=tuple(sc.target_tilt_deg),
    )
    try:
        scenes = tuple(
            replace(scene, box_xy=arm.marker_xy, target_yaw_deg=arm.marker_yaw_deg,
                    target_tilt_deg=tuple(np.add(sc.target_tilt_deg, arm.marker_tilt_deg)))
            for arm in robot.arms
        )  # fmt: skip
    except ValueError as exc:
        raise ScenarioError(
            f"{scenario.source}: robot.arms[].marker.extra_tilt_deg: {exc}"
        ) from None
    if scenes:
        scene = scenes[0]
    n = robot.system.n
    q0 = np.asarray(cfg.initial.q, float)
    qd0 = np.zeros(n) if cfg.initial.qd is None else np.asarray(cfg.initial.qd, float)
    world = World(robot, scene, target, q0, qd0, np.asarray(cfg.desired.q, float), scenes)
    check_with_world(scenario, world)
    return world


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
        if self.scenario is None or self.model is None:
            return False
        cfg = self.scenario.config
        return (
            cfg.sensors.intrinsics_error == 0
            and cfg.estimation.source == "true"
            and not cfg.controller.class_
        )


def reseed(assembly: Assembly, seed: int) -> Assembly:
    """The assembled loop with the random streams of ``seed``, without rebuilding it: the
    controller's model perturbation (drawn from ``seed``), C_L's imperfections (``[seed, 1]``),
    the disturbances (``seed``) and the turbulence (``[seed, 21]``), as :func:`build_loop` seeds
    them, so a reseeded loop runs as one built with ``seed`` (tested). Only when
    :attr:`Assembly.reseedable`."""
    if not assembly.reseedable:
        raise ValueError("this loop cannot be reseeded in place (see Assembly.reseedable)")
    seed = int(seed)
    loop = assembly.loop
    assembly.model.reseed(seed)
    loop.sensors.local.rng = np.random.default_rng([seed, 1])
    for k, sensor in enumerate(getattr(loop.sensors, "locals_", [])[1:], start=1):
        sensor.rng = np.random.default_rng([seed, 1, k])  # arm k's C_L ([[robot.arms]])
    wind = None
    if loop.plant.wind is not None:  # the turbulence of [seed, WIND_STREAM]
        sc = assembly.scenario
        wind = air_of(sc.config, assembly.world, seed, sc.source)[1]
    loop.plant.reseed(np.random.default_rng(seed), wind)
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
    check_run(scenario, seed=seed, flags=False)  # the seed named, before any work
    scenario = apply_profile(scenario)
    cfg, src = scenario.config, scenario.source
    seed = int(cfg.seed if seed is None else seed)
    paper = cfg.controller.profile == "paper"
    world = build_world(scenario)
    robot, s = world.robot, world.robot.system
    if robot.arms:
        return _build_arms_loop(scenario, world, seed, video, controller, servo, estimator,
                                frame_composer)  # fmt: skip
    # the proprioceptive sensors of the EKF (estimation.source = "estimated"), read every period
    suite = None
    if estimator is None and cfg.estimation.source == "estimated":
        suite = proprioceptive_sensors(cfg.sensors, s, seed)
    imperfections = camera_imperfections(cfg.sensors)
    sensors, ctl_camera = camera_sensors(cfg.cameras, imperfections, world, seed, video, suite)
    perception = perception_block(ctl_camera, world)
    local_ref, desired = reference_views(
        sensors.local, robot, world.target, world.scene, world.q_star, ctl_camera
    )
    touch = cfg.touch
    if touch.enabled and not (cfg.scene.obstacles or cfg.scene.contact.target_box):
        raise ScenarioError(
            f"{src}: touch.enabled needs something to touch: "
            "scene.contact.target_box = true or [[scene.obstacles]]"
        )
    if servo is None:
        servo = servo_block(cfg.ibvs, cfg.recovery, touch, paper, world, ctl_camera, desired, src,
                            local_reference=local_ref)  # fmt: skip
        servo = policy_block(cfg, servo, world, ctl_camera, src, scenario.folder)
    model, controller, plant = _controller_and_plant(scenario, world, seed, controller, suite)
    force = force_block(touch, servo, model, robot)
    if suite is not None:
        estimator = estimation_block(
            cfg.estimation, cfg.ibvs.target_level_normal, s, seed, plant, suite, world.q0,
            model, robot.tip_mount, world.target, ctl_camera,
        )  # fmt: skip
    log = RunLog(servo.desired_points, frame_composer, truth_of(world, sensors.local))
    if force is not None:  # servoing into contact: the task's image error, in C_L
        log.local_reference = local_ref[0]
        log.truth_local = truth_of(world, sensors.local, virtual=False)
    blocks = (plant, sensors, perception, servo, controller)
    return _assembly(scenario, world, seed, model, blocks, estimator, log, force)


def _controller_and_plant(scenario, world, seed, controller, suite):
    """The controller's model (``[model]``), the low-level controller (``controller`` if given,
    else ``[controller]``'s, with ``estimation.controller_truth``) and the plant; ``suite``:
    the proprioceptive sensors of the estimator (the plant then keeps ``qdd``), or ``None``."""
    cfg, src = scenario.config, scenario.source
    model = controller_model(cfg.model, cfg.aerodynamics, world.robot.system, seed)
    if controller is None:
        folders = search_folders(scenario.folder)
        controller = controller_block(cfg.controller, model, world, cfg.dt, src, folders)
    plant = plant_block(cfg, world, seed, suite is not None, src)
    controller = truth_ablation(controller, cfg.estimation.controller_truth, plant, src)
    return model, controller, plant


def _assembly(scenario, world, seed, model, blocks, estimator, log, force=None) -> Assembly:
    """The :class:`~tdacm.loop.ClosedLoop` of ``blocks`` (plant, sensors, perception, servo,
    controller) with the safety monitor of ``[safety]`` and the obstacles' forces logged, its
    kernels warmed up, as an :class:`Assembly`."""
    cfg = scenario.config
    plant = blocks[0]
    safety = SafetyMonitor.from_config(cfg.safety)
    loop = ClosedLoop(
        *blocks, cfg.dt, estimator=estimator, safety=safety, log=log, name=scenario.name,
        force=force,
    )  # fmt: skip
    if plant.contact is not None:
        loop.log.contact = contact_logger(plant.system, plant.contact)
    warm_up(plant.system, world.q0)
    return Assembly(loop, world, seed, model, scenario)


# ----------------------------------------------------------------------------- several arms
def _refuse_for_arms(cfg, src: str) -> None:
    """What the loop of several arms does not run yet: one line naming the key."""
    checks = (
        (cfg.scene.contact.target_box, "scene.contact.target_box"),
        (cfg.aerodynamics.enabled, "aerodynamics.enabled"),
        (cfg.servo.policy is not None, "servo.policy"),
    )
    for bad, key in checks:
        if bad:
            raise ScenarioError(f"{src}: {key} is for one arm (not with [[robot.arms]])")
    if cfg.touch.enabled and not cfg.scene.obstacles:
        raise ScenarioError(f"{src}: touch.enabled needs something to touch: [[scene.obstacles]]")
    arms = cfg.robot.arms
    for k, arm in enumerate(arms[1:], start=1):  # the kernels carry one probe for every rod
        if arm.tip.probe_length != arms[0].tip.probe_length:
            raise ScenarioError(
                f"{src}: robot.arms[{k}].tip.probe_length must equal robot.arms[0]'s "
                "(one probe for every arm)"
            )


def _build_arms_loop(scenario, world, seed, video, controller, servo, estimator, composer):
    """:func:`build_loop` for ``[[robot.arms]]`` (:mod:`tdacm.loop.arms`): one C_L sensor,
    perception, reference snapshot and single-arm servo per arm, joined by
    :class:`~tdacm.loop.arms.ArmsServo`; the controller, plant and safety monitor as for one
    arm, over all coordinates and inputs."""
    from ..loop.arms import ArmsLog, ArmsPerception, ArmsServo
    from ..loop.touch_arms import ArmsForceBlock, ArmsTouchLog, ArmsTouchServo, arm_contact_forces
    from ..system.contact import probe_offset

    cfg, src = scenario.config, scenario.source
    _refuse_for_arms(cfg, src)
    robot = world.robot
    suite = None  # the EKF's proprioceptive sensors, as for one arm
    if estimator is None and cfg.estimation.source == "estimated":
        suite = proprioceptive_sensors(cfg.sensors, robot.system, seed)
    imperfections = camera_imperfections(cfg.sensors)
    sensors, cams = arms_camera_sensors(cfg.cameras, imperfections, world, seed, video, suite)
    perception = ArmsPerception([perception_block(c, world.arm(k)) for k, c in enumerate(cams)])
    views = [
        reference_views(sensors.locals_[k], robot, world.target, world.scenes[k],
                        world.q_star, cams[k])
        for k in range(len(robot.arms))
    ]  # fmt: skip
    desired = [v[1] for v in views]
    paper = cfg.controller.profile == "paper"
    touch = cfg.touch.enabled
    if servo is None:
        servo = [
            servo_block(cfg.ibvs, cfg.recovery, cfg.touch, paper, world.arm(k), cams[k],
                        desired[k], src, arm=arm, local_reference=views[k][0])
            for k, arm in enumerate(robot.arms)
        ]  # fmt: skip
        servo = ArmsTouchServo(servo, cfg.touch) if touch else ArmsServo(servo)
    model, controller, plant = _controller_and_plant(scenario, world, seed, controller, suite)
    if suite is not None:  # the EKF over all coordinates; it fuses arm 0's view of its marker
        arm0 = world.arm(0)
        estimator = estimation_block(
            cfg.estimation, cfg.ibvs.target_level_normal, robot.system, seed, plant, suite,
            world.q0, model, robot.arms[0].tip_mount, arm0.target, cams[0],
        )  # fmt: skip
    truths = [truth_of(world.arm(k), sensors.locals_[k]) for k in range(len(robot.arms))]
    force = None
    if touch and isinstance(servo, ArmsTouchServo):
        tc = cfg.touch
        offset = probe_offset(robot.tip_mount, robot.probe_length)
        force = ArmsForceBlock(model, [a.tip_mount for a in robot.arms], offset,
                               tc.input_sigma, tc.force_estimator, tc.observer_gain)  # fmt: skip
        truths_local = [truth_of(world.arm(k), sensors.locals_[k], virtual=False)
                        for k in range(len(robot.arms))]  # fmt: skip
        log = ArmsTouchLog([p for p, _ in desired], composer, truths,
                           arm_contact_forces(robot.system, plant.contact),
                           [v[0][0] for v in views], truths_local)  # fmt: skip
    else:
        log = ArmsLog([p for p, _ in desired], composer, truths)
    blocks = (plant, sensors, perception, servo, controller)
    return _assembly(scenario, world, seed, model, blocks, estimator, log, force)
