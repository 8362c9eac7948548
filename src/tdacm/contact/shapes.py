"""Obstacles and contact parameters: small frozen records (the Python API of the scene).

Every obstacle has a ``position`` (its centre, or a point of a plane, inertial frame, m) and
an orientation ``rotation`` (3 x 3, its axes as columns; default identity):

* :class:`Plane`: the half-space below the plane through ``position`` with unit ``normal``
  (the solid side is opposite to the normal);
* :class:`Sphere` of ``radius``;
* :class:`Box` of ``size`` (full edge lengths along its axes);
* :class:`Cylinder` of ``radius`` and ``length`` along its third axis, with flat ends.

:class:`ContactModel` holds the parameters of the contact law (:mod:`tdacm.contact.geometry`),
every default with its reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as V
from . import layout as CL

#: an obstacle's default ``position`` (the world's origin)
ORIGIN = (0.0, 0.0, 0.0)


def _rotation(name: str, r) -> np.ndarray:
    a = V.array(name, r, (3, 3))
    if not np.allclose(a @ a.T, np.eye(3), atol=1e-9) or np.linalg.det(a) < 0:
        raise ValueError(f"{name} must be a rotation matrix (orthonormal, det +1)")
    return a


def rotation_about(axis: str, deg: float) -> np.ndarray:
    """Rotation by ``deg`` degrees about the inertial ``x``, ``y`` or ``z`` axis."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i = "xyz".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    r = np.eye(3)
    r[j, j], r[j, k], r[k, j], r[k, k] = c, -s, s, c
    return r


def _frame_with_z(n: np.ndarray) -> np.ndarray:
    """A rotation whose third column is the unit vector ``n``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, n)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(n, x), n])


@dataclass(frozen=True)
class Plane:
    """The half-space ``(x - position) . normal <= 0``."""

    position: tuple = ORIGIN
    normal: tuple = (0.0, 0.0, 1.0)

    def row(self) -> np.ndarray:
        n = V.array("normal", self.normal, (3,))
        if np.linalg.norm(n) == 0:
            raise ValueError("normal must be non-zero")
        return _row(CL.PLANE, _frame_with_z(n / np.linalg.norm(n)), self.position, (0, 0, 0))


@dataclass(frozen=True)
class Sphere:
    position: tuple = ORIGIN
    radius: float = 0.1

    def row(self) -> np.ndarray:
        V.positive("radius", self.radius)
        return _row(CL.SPHERE, np.eye(3), self.position, (self.radius, 0, 0))


@dataclass(frozen=True)
class Box:
    position: tuple = ORIGIN
    size: tuple = (0.4, 0.4, 0.4)
    rotation: tuple | np.ndarray | None = None

    def row(self) -> np.ndarray:
        s = V.array("size", self.size, (3,))
        if np.any(s <= 0):
            raise ValueError(f"size must be positive, got {list(s)}")
        r = np.eye(3) if self.rotation is None else _rotation("rotation", self.rotation)
        return _row(CL.BOX, r, self.position, 0.5 * s)


@dataclass(frozen=True)
class Cylinder:
    position: tuple = ORIGIN
    radius: float = 0.05
    length: float = 0.5
    rotation: tuple | np.ndarray | None = None

    def row(self) -> np.ndarray:
        V.positive("radius", self.radius)
        V.positive("length", self.length)
        r = np.eye(3) if self.rotation is None else _rotation("rotation", self.rotation)
        return _row(CL.CYLINDER, r, self.position, (self.radius, 0.5 * self.length, 0))


def _row(kind, r, position, size) -> np.ndarray:
    out = np.zeros(CL.SHAPE_SIZE)
    out[CL.KIND] = kind
    out[CL.ROT : CL.ROT + 9] = np.asarray(r, float).ravel()
    out[CL.POS : CL.POS + 3] = V.array("position", position, (3,))
    out[CL.SIZE : CL.SIZE + 3] = size
    return out


SHAPES = {"plane": Plane, "sphere": Sphere, "box": Box, "cylinder": Cylinder}


@dataclass(frozen=True)
class ContactModel:
    """Parameters of the contact law (:mod:`tdacm.contact.geometry`).

    rod_stiffness : 2e4 N/m^2, the rod's normal force per metre of contact and metre of
        penetration: 0.1 N/m pressed over 5 cm sinks 0.1 mm (a penalty far stiffer than the
        rod's bending, 3EI/L^3 = 0.12 N/m for the paper's rod, so the statics do not depend on
        it; the Hertz value of Nitinol on steel, ~E*, would need microsecond steps)
    tip_stiffness : 1e3 N/m, the tip sphere's: 0.3 N sinks 0.3 mm, 10^4 times the paper rod's
        tip stiffness; the contact vibrates at sqrt(k/m_tip) = 316 rad/s with the 10 g camera
    tip_radius : 0.01 m, the sphere around the tip body (a miniature camera)
    damping : 5 s/m, Hunt-Crossley ``c``; the restitution of an impact at ``v`` is about
        ``1 - 2 c v / 3`` for small ``c v`` (Hunt & Crossley 1975): 0.67 at 0.1 m/s
    mu_static, mu_kinetic : 0.5 and 0.4, dry polymer / metal pairs
    slip_speed : 2e-3 m/s, the regularization speed of Coulomb's law (a body "sticking" creeps
        at most about this speed)
    stribeck_speed : 1e-2 m/s, the speed over which the friction falls from static to kinetic
    rod, tip : which bodies touch the obstacles
    """

    rod_stiffness: float = 2e4
    tip_stiffness: float = 1e3
    tip_radius: float = 0.01
    damping: float = 5.0
    mu_static: float = 0.5
    mu_kinetic: float = 0.4
    slip_speed: float = 2e-3
    stribeck_speed: float = 1e-2
    rod: bool = True
    tip: bool = True
    obstacles: tuple = field(default_factory=tuple)

    def __post_init__(self):
        for name in ("rod_stiffness", "tip_stiffness", "tip_radius", "slip_speed"):
            V.positive(name, getattr(self, name))
        V.positive("stribeck_speed", self.stribeck_speed)
        for name in ("damping", "mu_static", "mu_kinetic"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.mu_kinetic > self.mu_static:
            raise ValueError(
                f"mu_kinetic ({self.mu_kinetic}) must not exceed mu_static ({self.mu_static})"
            )
        for o in self.obstacles:
            if not isinstance(o, tuple(SHAPES.values())):
                raise ValueError(f"obstacles must be Plane, Sphere, Box or Cylinder, got {o!r}")

    def header(self) -> np.ndarray:
        h = np.zeros(CL.N_HEADER)
        h[CL.N_SHAPES] = len(self.obstacles)
        h[CL.K_ROD] = self.rod_stiffness
        h[CL.K_TIP] = self.tip_stiffness
        h[CL.DAMPING] = self.damping
        h[CL.MU_S] = self.mu_static
        h[CL.MU_K] = self.mu_kinetic
        h[CL.V_SLIP] = self.slip_speed
        h[CL.V_STRIBECK] = self.stribeck_speed
        h[CL.ROD_ON] = float(self.rod)
        h[CL.TIP_ON] = float(self.tip)
        return h
