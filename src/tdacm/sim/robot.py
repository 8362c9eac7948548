"""The robot of a scenario: section ``[robot]`` -> system, cameras and camera mounts.

Subsections and keys are the constructor arguments of the model classes; every key is optional
and an omitted key takes the paper's value (Table I for the robot, Table II for the cameras), so
a scenario without ``[robot]`` simulates the paper's TD-ACM:

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
  drag_factor, max_thrust``), or ``[robot.base]`` with ``pose_q = [phi, theta, psi, x, y, z]``
  for a rod clamped at that pose (a fixed base, as ``system.base = "fixed"``);
* ``[robot.attachment]``: ``offset`` of the rod's base below the drone's centre of mass;
* ``[robot.cameras.local]`` and ``[robot.cameras.global]``: the intrinsics of
  :class:`~tdacm.vision.PinholeCamera` (``width, height, fx, fy, cx, cy, near, far``) and the
  mounts: ``offset`` of C_L beyond the tip along the backbone; ``position`` and ``tilt_deg`` of
  C_G in the drone's body frame (:func:`~tdacm.vision.drone_camera_mount`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..base import FixedBase, Quadrotor
from ..rod import Rod, StrainBasis, Tendons
from ..system.tdacm import TDACM, default_attachment
from ..vision import GLOBAL_CAMERA, LOCAL_CAMERA, drone_camera_mount, tip_camera_mount
from ..vision.camera import PinholeCamera

_CAMERA_KEYS = {
    "width": (int, None),
    "height": (int, None),
    "fx": (float, None),
    "fy": (float, None),
    "cx": (float, None),
    "cy": (float, None),
    "near": (float, None),
    "far": (float, None),
}

#: ``[robot]`` subsections: key -> (type, default); ``None`` = the paper's value.
ROBOT_SCHEMA = {
    "rod": {
        "length": (float, 1.0),
        "diameter": (float, 2e-3),
        "density": (float, 6.45e3),
        "youngs_modulus": (float, 5e10),
        "poisson_ratio": (float, 0.33),
        "damping": (float, 1e2),
        "tip_mass": (float, 0.01),
        "basis": (str, "bending:0"),
        "n_gauss": (int, None),  # the paper's 5 for its basis, else the Rod default for the basis
        "magnus_order": (int, None),  # the paper's 2 for its basis, else 4
    },
    "tendons": {
        "offsets": ("points", None),
        "radius": (float, 0.01),
        "count": (int, 4),
        "max_tension": (float, 20.0),
    },
    "drone": {
        "mass": (float, 0.7331),
        "inertia": ("vec:3", [2.4388e-2, 2.6151e-2, 2.6929e-2]),
        "arm_length": (float, 0.325),
        "drag_factor": (float, 0.016),
        "max_thrust": (float, 15.0),
    },
    "base": {"pose_q": ("vec:6", None)},
    "attachment": {"offset": (float, 0.1)},
    "cameras": {
        "local": {**_CAMERA_KEYS, "offset": (float, 0.0)},
        "global": {
            **_CAMERA_KEYS,
            "position": ("vec:3", [0.10, 0.0, -0.06]),
            "tilt_deg": (float, 10.0),
        },
    },
}


class RobotError(ValueError):
    """Invalid ``[robot]`` data; the message names the key."""


def parse_basis(text: str) -> StrainBasis:
    """``"bending:P"``, ``"full:P"`` or ``"modes:name=P,name=P"`` -> :class:`StrainBasis`."""
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
        raise RobotError(f"robot.rod.basis = {text!r}: {exc}") from None
    raise RobotError(
        f"robot.rod.basis = {text!r}: write 'bending:P', 'full:P' or 'modes:torsion=1,...'"
    )


@dataclass(frozen=True)
class Robot:
    """A scenario's robot: the coupled model, both cameras and their mounts."""

    system: TDACM
    local_camera: PinholeCamera
    global_camera: PinholeCamera
    tip_mount: np.ndarray  # g_{C_L}^L
    drone_mount: np.ndarray  # g_{C_G}^b


def _camera(base: PinholeCamera, keys: dict, where: str) -> PinholeCamera:
    given = {k: v for k, v in keys.items() if k in _CAMERA_KEYS and v is not None}
    if not given:
        return base
    try:
        cam = replace(base, **given)
    except ValueError as exc:
        raise RobotError(f"{where}: {exc}") from None
    if "fx" in given and "fy" not in given:
        raise RobotError(f"{where}: give fx and fy together")
    return cam


def build_robot(robot: dict, held_base_q=None) -> Robot:
    """The :class:`Robot` of a validated ``[robot]`` section (defaults filled in).
    ``held_base_q`` (``system.held_base_q``) clamps the rod at that drone pose when the scenario
    says ``system.base = "fixed"``; ``robot.base.pose_q`` does the same."""
    r = robot["rod"]
    basis = parse_basis(r["basis"])
    paper_basis = basis == StrainBasis.bending(0)
    n_gauss = r["n_gauss"] if r["n_gauss"] is not None else (5 if paper_basis else None)
    magnus = r["magnus_order"] if r["magnus_order"] is not None else (2 if paper_basis else None)
    try:
        rod = Rod(
            length=r["length"],
            diameter=r["diameter"],
            density=r["density"],
            youngs_modulus=r["youngs_modulus"],
            poisson_ratio=r["poisson_ratio"],
            damping=r["damping"],
            basis=basis,
            n_gauss=n_gauss,
            magnus_order=magnus,
            tip_mass=r["tip_mass"],
        )
    except RobotError:
        raise
    except ValueError as exc:
        raise RobotError(f"robot.rod: {exc}") from None
    t = robot["tendons"]
    try:
        if t["offsets"] is not None:
            off = np.asarray(t["offsets"], float)
            if off.ndim != 2 or off.shape[1] not in (2, 3):
                raise ValueError("offsets must be a list of [y, z] (or [0, y, z]) pairs")
            if off.shape[1] == 2:
                off = np.column_stack([np.zeros(len(off)), off])
            tendons = Tendons(offsets=off, max_tension=t["max_tension"])
        else:
            tendons = Tendons.parallel(t["radius"], t["count"], t["max_tension"])
    except ValueError as exc:
        raise RobotError(f"robot.tendons: {exc}") from None
    if tendons.n < 3:
        raise RobotError(
            f"robot.tendons: {tendons.n} tendon(s) cannot bend the rod both ways (tendons only "
            "pull); give at least 3"
        )
    pose_q = robot["base"]["pose_q"]
    if pose_q is None and held_base_q is not None:
        pose_q = held_base_q
    try:
        if pose_q is None:
            d = robot["drone"]
            base = Quadrotor(
                mass=d["mass"],
                inertia=tuple(d["inertia"]),
                arm_length=d["arm_length"],
                drag_factor=d["drag_factor"],
                max_thrust=d["max_thrust"],
            )
        else:
            base = None
    except ValueError as exc:
        raise RobotError(f"robot.drone: {exc}") from None
    off = robot["attachment"]["offset"]
    if not off >= 0:
        raise RobotError(f"robot.attachment.offset must be >= 0, got {off!r}")
    attachment = default_attachment(off)
    if base is None:
        held = TDACM(rod, tendons, Quadrotor(), attachment)
        q = np.zeros(held.n)
        q[:6] = pose_q
        base = FixedBase(pose=held.base_pose(q))
    system = TDACM(rod, tendons, base, attachment)
    cams = robot["cameras"]
    local = _camera(LOCAL_CAMERA, cams["local"], "robot.cameras.local")
    glob = _camera(GLOBAL_CAMERA, cams["global"], "robot.cameras.global")
    try:
        tip_mount = tip_camera_mount(attachment, cams["local"]["offset"])
        drone_mount = drone_camera_mount(
            tuple(cams["global"]["position"]), cams["global"]["tilt_deg"]
        )
    except ValueError as exc:
        raise RobotError(f"robot.cameras: {exc}") from None
    return Robot(system, local, glob, tip_mount, drone_mount)


def strain_count(robot: dict) -> int:
    """``n_s`` of a ``[robot]`` section (for the length checks of ``q``), without building."""
    return parse_basis(robot["rod"]["basis"]).n
