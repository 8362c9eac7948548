"""Bases the rod hangs from: an underactuated quadrotor (paper eqs. (3), (4), (14), (15)) or a
fixed clamp (the paper's ground tests A and B).

Quadrotor (``+`` configuration, motors on the body x and y axes, numbered 1..4 counter-clockwise
from +x, spinning alternately): thrusts ``f`` map to the body wrench ``Gamma f`` with

    Gamma = [[0, r_m, 0, -r_m], [-r_m, 0, r_m, 0], [k_d, -k_d, k_d, -k_d], [0]*4, [0]*4, [1]*4]

i.e. ``[tau_x, tau_y, tau_z, f_x, f_y, f_z]`` with thrust along body +z.  The generalized input
matrix is ``B_m(q) = blkdiag(T^T, R_b) Gamma``.

Default values not given by the paper (documented guesses for a Holybro X650-class frame):
``arm_length = 0.325 m`` (650 mm motor-to-motor diagonal), ``drag_factor = 0.016 m`` (rotor
torque/thrust ratio of a 15-inch propeller), ``max_thrust = 15 N`` per motor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _validate as V
from .. import paper_values as PV


@dataclass
class Quadrotor:
    """Rigid quadrotor body; its frame is at the centre of mass, principal axes, z up."""

    mass: float = PV.DRONE_MASS
    inertia: tuple = PV.DRONE_INERTIA
    arm_length: float = PV.DRONE_ARM_LENGTH
    drag_factor: float = PV.DRONE_DRAG_FACTOR
    max_thrust: float = PV.DRONE_MAX_THRUST

    floating = True

    def __post_init__(self):
        self.mass = V.positive("mass", self.mass)
        ii = V.array("inertia", self.inertia, (3,))
        if np.any(ii <= 0):
            raise ValueError(f"inertia must be positive, got {self.inertia!r}")
        self.inertia = tuple(ii)
        self.arm_length = V.positive("arm_length", self.arm_length)
        self.drag_factor = V.nonnegative("drag_factor", self.drag_factor)
        self.max_thrust = V.positive("max_thrust", self.max_thrust)

    @property
    def spatial_inertia(self) -> np.ndarray:
        """``M_b = diag(I1, I2, I3, m, m, m)`` in the body frame."""
        return np.diag([*self.inertia, self.mass, self.mass, self.mass])

    @property
    def gamma(self) -> np.ndarray:
        """``Gamma`` (6x4): motor thrusts -> body wrench (paper eq. (15))."""
        return np.array(gamma_rows(self.arm_length, self.drag_factor), dtype=float)


def gamma_rows(r, k) -> list:
    """The rows of ``Gamma`` (paper eq. (15), module docstring) for the arm length ``r`` and
    the drag factor ``k``: numbers, or symbols (the other entries are the integers 0, 1)."""
    return [
        [0, r, 0, -r],
        [-r, 0, r, 0],
        [k, -k, k, -k],
        [0, 0, 0, 0],
        [0, 0, 0, 0],
        [1, 1, 1, 1],
    ]


@dataclass
class FixedBase:
    """A clamp holding the rod's base frame at ``pose`` (4x4, inertial frame).

    ``pose`` is the pose of the (virtual) base frame ``O_b``; the rod starts at
    ``pose @ attachment`` as for a drone, so a held drone is ``FixedBase(pose=g_b)``.
    """

    pose: np.ndarray = field(default_factory=lambda: np.eye(4))

    floating = False

    def __post_init__(self):
        self.pose = V.transform("pose", self.pose)
