"""Lie-group kernels on SE(3) (angular-first twists), ZYX Euler angles, Magnus steps."""

from .euler import euler_from_rotation, euler_rate_matrix, euler_rate_matrix_dot, rot_zyx
from .magnus import MAGNUS_POINTS, magnus_step
from .se3 import (
    Ad,
    Ad_inv,
    ad,
    coad,
    expmap,
    hat,
    inv_se3,
    rotation_angle,
    skew,
    so3_exp_and_left_jacobian,
    so3_log,
    tangent,
    tangent_and_rate,
    unskew,
    vee,
    wrench_skew,
)

__all__ = [
    "Ad",
    "Ad_inv",
    "MAGNUS_POINTS",
    "ad",
    "coad",
    "euler_from_rotation",
    "euler_rate_matrix",
    "euler_rate_matrix_dot",
    "expmap",
    "hat",
    "inv_se3",
    "magnus_step",
    "rot_zyx",
    "rotation_angle",
    "skew",
    "so3_exp_and_left_jacobian",
    "so3_log",
    "tangent",
    "tangent_and_rate",
    "unskew",
    "vee",
    "wrench_skew",
]
