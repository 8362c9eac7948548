"""The robot of a scenario: section ``[robot]`` -> system, cameras and camera mounts.

Subsections and keys are the constructor arguments of the model classes, declared as the
records :class:`RobotConfig` and its parts (defaults from :mod:`tdacm.paper_values`); every key
is optional and an omitted key takes the paper's value (Table I for the robot, Table II for the
cameras), so a scenario without ``[robot]`` simulates the paper's TD-ACM:

* ``[robot.rod]``: :class:`~tdacm.rod.Rod` (``length, diameter, density, youngs_modulus,
  poisson_ratio, damping, tip_mass, n_gauss, magnus_order``) and ``basis``, a strain basis
  written ``"bending:P"`` (both curvatures of order ``P``, the paper's is ``"bending:0"``),
  ``"full:P"`` (all six strains), or ``"modes:torsion=1,bending_y=2,..."``; ``n_gauss`` and
  ``magnus_order`` default to the paper's 5 and 2 for its basis, and to what
  :class:`~tdacm.rod.Rod` picks for any other (accurate by default);
* ``[robot.tendons]``: :class:`~tdacm.rod.Tendons`: ``offsets`` (one ``[y, z]`` or
  ``[0, y, z]`` offset per tendon, metres) or ``radius`` and ``count`` (evenly spaced, the
  first on +y); ``max_tension``;
* ``[robot.drone]``: :class:`~tdacm.base.Quadrotor` (``mass, inertia, arm_length,
  drag_factor, max_thrust``) and the rotors' ``rotor_radius`` and ``layout``
  (:class:`~tdacm.aero.RotorWake`, used by ``[aerodynamics]``), or ``[robot.base]`` with
  ``pose_q = [phi, theta, psi, x, y, z]`` for a rod clamped at that pose (a fixed base, as
  ``system.base = "fixed"``);
* ``[robot.attachment]``: ``offset`` of the rod's base below the drone's centre of mass;
* ``[robot.tip]``: ``probe_length``, a rigid probe ahead of C_L carrying the contact sphere;
* ``[robot.cameras.local]`` and ``[robot.cameras.global]``: the intrinsics of
  :class:`~tdacm.vision.PinholeCamera` (``width, height, fx, fy, cx, cy, near, far``) and the
  mounts: ``offset`` of C_L beyond the tip along the backbone; ``position`` and ``tilt_deg`` of
  C_G in the drone's body frame (:func:`~tdacm.vision.drone_camera_mount`);
* ``[[robot.arms]]`` (two or more): a robot with several arms under the drone, each with its
  own ``rod``, ``tendons``, ``attachment`` (``position`` [x, y] in the body frame and
  ``offset`` below it), tip ``camera`` (C_L's intrinsics and offset), ``tip`` (probe) and
  ``marker`` (its target's box ``xy`` and ``yaw_deg``); ``[robot.rod]``, ``[robot.tendons]``,
  ``[robot.attachment]``, ``[robot.tip]`` and ``[robot.cameras.local]`` then keep their
  defaults (:class:`ArmConfig`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import model_validator

from .. import paper_values as PV
from .._config import ConfigModel, Field
from ..aero.params import LAYOUTS, RotorWake
from ..base import FixedBase, Quadrotor
from ..loop.config import Vec2, Vec3, Vec6
from ..rod import Rod, StrainBasis, Tendons
from ..system.tdacm import TDACM, default_attachment
from ..vision import GLOBAL_CAMERA, LOCAL_CAMERA, drone_camera_mount, tip_camera_mount
from ..vision.camera import PinholeCamera


class RodConfig(ConfigModel):
    """``[robot.rod]``: the rod (:class:`~tdacm.rod.Rod`); defaults: Table I."""

    length: float = Field(PV.ROD_LENGTH, gt=0, description="m, rod length L")
    diameter: float = Field(PV.ROD_DIAMETER, gt=0, description="m, rod diameter")
    density: float = Field(PV.ROD_DENSITY, gt=0, description="kg/m^3")
    youngs_modulus: float = Field(PV.ROD_YOUNGS_MODULUS, gt=0, description="Pa, Young's modulus E")
    poisson_ratio: float = Field(PV.ROD_POISSON_RATIO, description="Poisson's ratio")
    damping: float = Field(PV.ROD_DAMPING, description="Pa s, material damping")
    tip_mass: float = Field(PV.TIP_MASS, description="kg, point mass at the tip (the camera)")
    basis: str = Field(
        PV.ROD_BASIS,
        description="strain basis: 'bending:P' (both curvatures of order P), 'full:P' (all six "
        "strains) or 'modes:torsion=1,bending_y=2,...'",
    )
    n_gauss: int | None = Field(
        None,
        description="Gauss points (unset: the paper's 5 for its basis, else the Rod default)",
    )
    magnus_order: int | None = Field(
        None, description="Magnus order (unset: the paper's 2 for its basis, else 4)"
    )


class TendonsConfig(ConfigModel):
    """``[robot.tendons]``: :class:`~tdacm.rod.Tendons`, given by ``offsets`` or by ``radius``
    and ``count`` (evenly spaced, the first on +y)."""

    offsets: list[list[float]] | None = Field(
        None,
        min_length=1,
        description="m, one [y, z] (or [0, y, z]) offset per tendon (unset: radius and count)",
    )
    radius: float = Field(PV.TENDON_RADIUS, gt=0, description="m, offset of the parallel tendons")
    count: int = Field(PV.TENDON_COUNT, ge=1, description="number of parallel tendons")
    max_tension: float = Field(
        PV.TENDON_MAX_TENSION, gt=0, description="N, upper bound used by the allocation"
    )


_ROTOR = RotorWake()  # the rotor geometry's defaults (one source: tdacm.aero.params)


class DroneConfig(ConfigModel):
    """``[robot.drone]``: :class:`~tdacm.base.Quadrotor`; defaults: Table I."""

    mass: float = Field(PV.DRONE_MASS, gt=0, description="kg")
    inertia: Vec3 = Field(list(PV.DRONE_INERTIA), description="kg m^2, principal inertias")
    arm_length: float = Field(PV.DRONE_ARM_LENGTH, gt=0, description="m, centre to motor")
    drag_factor: float = Field(PV.DRONE_DRAG_FACTOR, description="m, rotor torque/thrust ratio")
    max_thrust: float = Field(PV.DRONE_MAX_THRUST, gt=0, description="N per motor")
    rotor_radius: float = Field(
        _ROTOR.rotor_radius,
        gt=0,
        description="m, propeller radius (the rotor wake, [aerodynamics]): a 15-inch propeller",
    )
    layout: Literal[tuple(LAYOUTS)] = Field(  # type: ignore[valid-type]
        _ROTOR.layout,
        description="rotor positions of the wake: '+' (rotor 0 on body +x, the motor order of "
        "Gamma in eq. (15)) or 'x' (rotor 0 at +45 deg)",
    )

    @model_validator(mode="after")
    def _rotors_apart(self):
        # neighbouring rotors are arm_length * sqrt(2) apart in either layout
        if 2.0 * self.rotor_radius >= math.sqrt(2.0) * self.arm_length:
            raise ValueError(
                f"rotor_radius = {self.rotor_radius} m: the rotors overlap (must be below "
                f"arm_length / sqrt(2) = {self.arm_length / math.sqrt(2.0):.4g} m)"
            )
        return self


class BaseConfig(ConfigModel):
    """``[robot.base]``: a clamped rod instead of the drone."""

    pose_q: Vec6 | None = Field(
        None,
        description="[phi, theta, psi, x, y, z] (rad, m) of the clamp: a fixed base "
        "(as system.base = 'fixed')",
    )


class AttachmentConfig(ConfigModel):
    """``[robot.attachment]``."""

    offset: float = Field(
        PV.ATTACHMENT_OFFSET, ge=0, description="m, the rod's base below the drone's centre of mass"
    )


class CameraIntrinsics(ConfigModel):
    """Intrinsics of :class:`~tdacm.vision.PinholeCamera`; unset keys take Table II's value."""

    width: int | None = Field(None, description="px (unset: Table II)")
    height: int | None = Field(None, description="px (unset: Table II)")
    fx: float | None = Field(None, description="px, focal length (give fx and fy together)")
    fy: float | None = Field(None, description="px, focal length")
    cx: float | None = Field(None, description="px, principal point")
    cy: float | None = Field(None, description="px, principal point")
    near: float | None = Field(None, description="m, near clipping plane")
    far: float | None = Field(None, description="m, far clipping plane")


class LocalCameraConfig(CameraIntrinsics):
    """``[robot.cameras.local]``: the tip camera C_L."""

    offset: float = Field(
        PV.LOCAL_CAMERA_OFFSET, description="m, C_L beyond the tip along the backbone"
    )


class GlobalCameraConfig(CameraIntrinsics):
    """``[robot.cameras.global]``: the drone camera C_G."""

    position: Vec3 = Field(
        list(PV.GLOBAL_CAMERA_POSITION), description="m, C_G in the drone's body frame"
    )
    tilt_deg: float = Field(
        PV.GLOBAL_CAMERA_TILT_DEG, description="deg, optical axis tilted forward from straight down"
    )


class TipConfig(ConfigModel):
    """``[robot.tip]``: what the arm's tip carries besides the camera."""

    probe_length: float = Field(
        0.0,
        ge=0,
        description="m, a rigid, massless probe ahead of C_L along its optical axis: the "
        "contact sphere ([scene.contact] tip_radius) at its end (0: the sphere at the tip)",
    )


class RobotCamerasConfig(ConfigModel):
    """``[robot.cameras]``."""

    local: LocalCameraConfig = LocalCameraConfig()
    global_: GlobalCameraConfig = Field(GlobalCameraConfig(), alias="global")


class ArmAttachmentConfig(AttachmentConfig):
    """``[robot.arms.attachment]``: where the arm's rod hangs from the drone."""

    position: Vec2 = Field(
        ...,
        description="m, [x, y] of the rod's base in the drone's body frame (the rod hangs "
        "offset below it, along body -z)",
    )


class MarkerConfig(ConfigModel):
    """``[robot.arms.marker]``: the arm's own target (a marker on its own box; the box size
    and the marker type are those of ``[scene]``, its tilt that of ``[scene]`` plus its own)."""

    xy: Vec2 = Field(..., description="m, the centre of the box carrying this arm's marker")
    yaw_deg: float = Field(0.0, description="deg, the marker's yaw about world z")
    extra_tilt_deg: Vec2 = Field(
        [0.0, 0.0],
        description="deg, the marker's tilt about world x, y, added to scene.target_tilt_deg "
        "(the sum within +-30)",
    )


class ArmConfig(ConfigModel):
    """``[[robot.arms]]``: one arm of a robot with several rods under the drone (at least
    two; one arm is the single-arm form of ``[robot]``): its rod, tendons, attachment, tip
    camera C_L, probe and target marker. q = [drone (6), q_s of arm 0, q_s of arm 1, ...] and
    u = [thrusts (4), tensions of arm 0, tensions of arm 1, ...]."""

    attachment: ArmAttachmentConfig
    marker: MarkerConfig
    rod: RodConfig = RodConfig()
    tendons: TendonsConfig = TendonsConfig()
    camera: LocalCameraConfig = LocalCameraConfig()
    tip: TipConfig = TipConfig()


class RobotConfig(ConfigModel):
    """Section ``[robot]``: the robot; every key optional, an omitted key takes the paper's
    value (Table I, Table II), so a scenario without ``[robot]`` simulates the paper's TD-ACM.
    ``[[robot.arms]]`` (two or more) replaces ``rod``, ``tendons``, ``attachment``, ``tip`` and
    ``cameras.local`` by one set per arm."""

    rod: RodConfig = RodConfig()
    tendons: TendonsConfig = TendonsConfig()
    drone: DroneConfig = DroneConfig()
    base: BaseConfig = BaseConfig()
    attachment: AttachmentConfig = AttachmentConfig()
    cameras: RobotCamerasConfig = RobotCamerasConfig()
    tip: TipConfig = TipConfig()
    arms: list[ArmConfig] = Field(
        [],
        description="[[robot.arms]]: two or more arms under the drone, each with its own rod, "
        "tendons, attachment, tip camera, probe and marker (empty: the single arm of [robot])",
    )

    @model_validator(mode="after")
    def _arms(self):
        if not self.arms:
            return self
        if len(self.arms) < 2:
            raise ValueError(
                "robot.arms: give two or more arms (one arm is the single-arm form of [robot])"
            )
        # the single-arm records must keep their defaults (a written scenario holds them all)
        single = [k for k in ("rod", "tendons", "attachment", "tip")
                  if getattr(self, k) != type(getattr(self, k))()]  # fmt: skip
        if self.cameras.local != LocalCameraConfig():
            single.append("cameras.local")
        if single:
            raise ValueError(
                f"robot.{single[0]}: with [[robot.arms]] each arm has its own "
                f"(robot.arms[k].{single[0].removeprefix('cameras.').replace('local', 'camera')})"
            )
        return self


_CAMERA_KEYS = tuple(CameraIntrinsics.model_fields)
#: the [robot.rod] keys a :class:`~tdacm.rod.Rod` takes as they are
_ROD_KEYS = ("length", "diameter", "density", "youngs_modulus", "poisson_ratio", "damping",
             "tip_mass")  # fmt: skip


#: The drone's four rotors together must lift at least this many times the robot's weight
#: (drone, rod and tip): hovering takes 1, and the attitude and position loops need headroom
#: on top (the paper's drone has 8: 4 x 15 N for 0.76 kg).
MIN_THRUST_TO_WEIGHT = 1.5


class RobotError(ValueError):
    """Invalid ``[robot]`` data; the message names the key."""


def parse_basis(text: str, where: str = "robot.rod") -> StrainBasis:
    """``"bending:P"``, ``"full:P"`` or ``"modes:name=P,name=P"`` -> :class:`StrainBasis`
    (``where``: the rod's key, for messages)."""
    kind, _, arg = text.partition(":")
    try:
        if kind == "bending":
            return StrainBasis.bending(int(arg or 0))
        if kind == "full":
            return StrainBasis.full(int(arg or 0))
        if kind == "modes":
            modes = {}
            for item in arg.split(","):
                name, _, p = item.partition("=")
                modes[name.strip()] = int(p)
            return StrainBasis.from_modes(modes)
    except ValueError as exc:
        raise RobotError(f"{where}.basis = {text!r}: {exc}") from None
    raise RobotError(
        f"{where}.basis = {text!r}: write 'bending:P', 'full:P' or 'modes:torsion=1,...'"
    )


def rod_quadrature(basis: StrainBasis, n_gauss=None, magnus_order=None) -> tuple:
    """``(n_gauss, magnus_order)`` of a rod with ``basis``: the given values, else the paper's
    5 and 2 for its basis and ``None`` (what :class:`~tdacm.rod.Rod` picks) for any other."""
    paper_basis = basis == parse_basis(PV.ROD_BASIS)
    if n_gauss is None:
        n_gauss = PV.ROD_N_GAUSS if paper_basis else None
    if magnus_order is None:
        magnus_order = PV.ROD_MAGNUS_ORDER if paper_basis else None
    return n_gauss, magnus_order


@dataclass(frozen=True)
class ArmRobot:
    """One arm of a several-arm robot: its rod's index in the system (``rod`` of
    :meth:`~tdacm.system.TDACM.tip_pose`), tip camera, mount, probe and target marker."""

    rod: int
    local_camera: PinholeCamera
    tip_mount: np.ndarray  # g_{C_L}^L of this arm
    probe_length: float
    marker_xy: tuple
    marker_yaw_deg: float
    marker_tilt_deg: tuple = (0.0, 0.0)  # added to the scene's tilt


@dataclass(frozen=True)
class Robot:
    """A scenario's robot: the coupled model, both cameras and their mounts. With
    ``[[robot.arms]]``, ``arms`` holds one :class:`ArmRobot` per arm and the single-arm fields
    (``local_camera``, ``tip_mount``, ``probe_length``) are arm 0's."""

    system: TDACM
    local_camera: PinholeCamera
    global_camera: PinholeCamera
    tip_mount: np.ndarray  # g_{C_L}^L
    drone_mount: np.ndarray  # g_{C_G}^b
    probe_length: float  # m, the contact sphere ahead of C_L ([robot.tip])
    arms: tuple = ()  # ArmRobot per arm ([[robot.arms]]); empty: the single-arm form


def _camera(base: PinholeCamera, record: CameraIntrinsics, where: str) -> PinholeCamera:
    given = {k: getattr(record, k) for k in _CAMERA_KEYS if getattr(record, k) is not None}
    if not given:
        return base
    try:
        cam = replace(base, **given)
    except ValueError as exc:
        raise RobotError(f"{where}: {exc}") from None
    if "fx" in given and "fy" not in given:
        raise RobotError(f"{where}: give fx and fy together")
    return cam


def _rod(r: RodConfig, where: str) -> Rod:
    """The :class:`~tdacm.rod.Rod` of a rod record (``where``: its key, for messages)."""
    basis = parse_basis(r.basis, where)
    n_gauss, magnus = rod_quadrature(basis, r.n_gauss, r.magnus_order)
    try:
        material = {k: getattr(r, k) for k in _ROD_KEYS}
        return Rod(**material, basis=basis, n_gauss=n_gauss, magnus_order=magnus)
    except RobotError:
        raise
    except ValueError as exc:
        raise RobotError(f"{where}: {exc}") from None


def _tendons(t: TendonsConfig, where: str) -> Tendons:
    """The :class:`~tdacm.rod.Tendons` of a tendons record (at least three)."""
    try:
        if t.offsets is not None:
            lengths = sorted({len(o) for o in t.offsets})
            if lengths not in ([2], [3]):
                raise ValueError(
                    "offsets must be a list of [y, z] (or [0, y, z]) offsets, all of one "
                    f"length; got entries of {' and '.join(map(str, lengths))} numbers"
                )
            off = np.asarray(t.offsets, float)
            if off.shape[1] == 2:
                off = np.column_stack([np.zeros(len(off)), off])
            tendons = Tendons(offsets=off, max_tension=t.max_tension)
        else:
            tendons = Tendons.parallel(t.radius, t.count, t.max_tension)
    except ValueError as exc:
        raise RobotError(f"{where}: {exc}") from None
    if tendons.n < 3:
        raise RobotError(
            f"{where}: {tendons.n} tendon(s) cannot bend the rod both ways (tendons only "
            "pull); give at least 3"
        )
    if tendons.offsets is not None:
        problem = moment_arm_problem(tendons.offsets[:, 1:3])
        if problem is not None:
            key = f"{where}.offsets" if t.offsets is not None else f"{where}.radius"
            raise RobotError(f"{key}: {problem}")
    return tendons


def moment_arm_problem(yz) -> str | None:
    """Why tendons at the section offsets ``yz`` (``(n, 2)``, m) cannot steer the rod, or
    ``None``. A tendon's bending moment is its tension times its offset from the backbone
    (paper, eq. (6): the moment arm ``d_i``): offsets all at the backbone give no moment at
    all, and offsets all on one side of a line through it (an angular gap wider than pi between
    neighbours) bend the rod one way only, tendons pulling and never pushing."""
    yz = np.asarray(yz, float)
    r = np.hypot(yz[:, 0], yz[:, 1])
    scale = max(float(r.max()), 0.0)
    if scale <= 1e-9:
        return (
            f"every tendon lies on the backbone ({yz.tolist()} m): no moment arm, the tendons "
            "cannot bend the rod; give offsets around it, e.g. radius 0.01 m"
        )
    ang = np.sort(np.arctan2(yz[r > 1e-9 * scale, 1], yz[r > 1e-9 * scale, 0]))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))
    if gaps.max() > np.pi + 1e-9:
        return (
            f"the tendons {np.round(yz, 6).tolist()} m all lie on one side of the backbone: "
            "tendons only pull, so the rod bends one way only; place them around it"
        )
    return None


def build_robot(robot: RobotConfig, held_base_q=None) -> Robot:
    """The :class:`Robot` of a ``[robot]`` record.
    ``held_base_q`` (``system.held_base_q``) clamps the rod at that drone pose when the scenario
    says ``system.base = "fixed"``; ``robot.base.pose_q`` does the same. With
    ``[[robot.arms]]``: one rod, tendon set and attachment per arm (``default_attachment`` of
    the arm's offset, moved to its ``position`` in the body frame)."""
    arms = robot.arms
    if arms:
        rods = [_rod(a.rod, f"robot.arms[{k}].rod") for k, a in enumerate(arms)]
        tendons = [_tendons(a.tendons, f"robot.arms[{k}].tendons") for k, a in enumerate(arms)]
        attachment = []
        for a in arms:
            g = default_attachment(a.attachment.offset)
            g[:2, 3] = a.attachment.position
            attachment.append(g)
        rod_record = arms[0].rod
    else:
        rods = _rod(robot.rod, "robot.rod")
        tendons = _tendons(robot.tendons, "robot.tendons")
        off = robot.attachment.offset
        if not off >= 0:
            raise RobotError(f"robot.attachment.offset must be >= 0, got {off!r}")
        attachment = default_attachment(off)
        rod_record = robot.rod
    pose_q = robot.base.pose_q
    if pose_q is None and held_base_q is not None:
        pose_q = held_base_q
    try:
        if pose_q is None:
            d = robot.drone
            base = Quadrotor(
                mass=d.mass,
                inertia=tuple(d.inertia),
                arm_length=d.arm_length,
                drag_factor=d.drag_factor,
                max_thrust=d.max_thrust,
            )
        else:
            base = None
    except ValueError as exc:
        raise RobotError(f"robot.drone: {exc}") from None
    if base is None:
        held = TDACM(rods, tendons, Quadrotor(), attachment)
        q = np.zeros(held.n)
        q[:6] = pose_q
        base = FixedBase(pose=held.base_pose(q))
    system = TDACM(rods, tendons, base, attachment)
    if system.floating:
        _check_thrust(system, robot.drone, rod_record)
    cams = robot.cameras
    glob = _camera(GLOBAL_CAMERA, cams.global_, "robot.cameras.global")
    try:
        drone_mount = drone_camera_mount(tuple(cams.global_.position), cams.global_.tilt_deg)
    except ValueError as exc:
        raise RobotError(f"robot.cameras: {exc}") from None
    if not arms:
        local = _camera(LOCAL_CAMERA, cams.local, "robot.cameras.local")
        try:
            tip_mount = tip_camera_mount(attachment, cams.local.offset)
        except ValueError as exc:
            raise RobotError(f"robot.cameras: {exc}") from None
        return Robot(system, local, glob, tip_mount, drone_mount, robot.tip.probe_length)
    built = []
    for k, (a, att) in enumerate(zip(arms, attachment, strict=True)):
        where = f"robot.arms[{k}].camera"
        cam = _camera(LOCAL_CAMERA, a.camera, where)
        try:
            mount = tip_camera_mount(att, a.camera.offset)
        except ValueError as exc:
            raise RobotError(f"{where}: {exc}") from None
        built.append(ArmRobot(k, cam, mount, a.tip.probe_length, tuple(a.marker.xy),
                              a.marker.yaw_deg, tuple(a.marker.extra_tilt_deg)))  # fmt: skip
    first = built[0]
    return Robot(system, first.local_camera, glob, first.tip_mount, drone_mount,
                 first.probe_length, tuple(built))  # fmt: skip


def _check_thrust(system: TDACM, drone: DroneConfig, rod: RodConfig) -> None:
    """The rotors' total thrust against the robot's weight (:data:`MIN_THRUST_TO_WEIGHT`); the
    message names the heaviest part (the drone, or the rod with its dimensions)."""
    weight = system.total_mass * float(np.linalg.norm(system.loads.gravity))
    total = 4 * drone.max_thrust
    if total < MIN_THRUST_TO_WEIGHT * weight:
        rod_mass = sum(a.rod.mass for a in system.arms)
        tip_mass = sum(a.rod.tip_mass for a in system.arms)
        parts = (f"drone {drone.mass:.4g} kg, rod {rod_mass:.4g} kg, "
                 f"tip {tip_mass:.4g} kg")  # fmt: skip
        need = f"{MIN_THRUST_TO_WEIGHT * weight / 4:.4g} N"
        if rod_mass > drone.mass:
            fix = (
                f"the rod is the heaviest part: check robot.rod.diameter = {rod.diameter:g} "
                f"m, length = {rod.length:g} m and density = {rod.density:g} kg/m^3 "
                f"(or raise robot.drone.max_thrust to at least {need})"
            )
        else:
            fix = f"raise robot.drone.max_thrust to at least {need} or lower robot.drone.mass"
        raise RobotError(
            f"robot.drone: 4 x max_thrust = {total:g} N cannot fly the robot: its weight is "
            f"{weight:.4g} N ({system.total_mass:.4g} kg: {parts}) and the rotors need "
            f"{MIN_THRUST_TO_WEIGHT:g} times it; {fix}"
        )


def strain_count(robot: RobotConfig) -> int:
    """``n_s`` of a ``[robot]`` record (for the length checks of ``q``), without building:
    the sum over ``[[robot.arms]]`` when given."""
    if robot.arms:
        return sum(
            parse_basis(a.rod.basis, f"robot.arms[{k}].rod").n for k, a in enumerate(robot.arms)
        )
    return parse_basis(robot.rod.basis).n
