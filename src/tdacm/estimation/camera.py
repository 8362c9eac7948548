"""The tip camera as a measurement of the state estimator: the static target seen by C_L.

Why (docs/estimation.md, "The tip camera in the filter"): with the proprioceptive sensors alone the
drone's velocity estimate is off by about 5 mm/s below 1 Hz (a 3 mm / 50 Hz pose and a MEMS
accelerometer cannot do better), and the low-level controller turns that error into camera
motion. The tip camera sees a target that does not move; its image fixes exactly the
combination of the state that moves the image. Fusing it makes the estimate consistent with
what the servo regulates (visual-inertial estimation with a known landmark geometry).

Model (the same geometry as the servo's target filter, :mod:`tdacm.vision.target_filter`):

* extra filter states: the target pose in the world, ``p_T`` (3) and a rotation vector
  ``theta`` (3) with ``R_T = exp([theta]x) R_A`` (a left, world-frame perturbation of an anchor
  ``R_A`` set when the target is first seen; ``theta`` stays at the mrad level of the
  camera-attitude error at that moment). The target is static: no process noise;
* measurement of a detection: the target's ``k`` feature points in normalized coordinates of
  C_L, ``z_i = pi(c_i) + n``, ``c_i = R_C^T (p_T + R_T X_i - p_C)``, ``pi(c) = [c_x, c_y] / c_z``,
  ``n ~ N(0, diag(sigma / f_x, sigma / f_y)^2)``; ``g_C = g_L(q) g_{C_L}^L`` (paper eq. (10));
* Jacobians: ``d pi / d c = [[1, 0, -x], [0, 1, -y]] / c_z``; on the camera's body twist
  ``xi = [w; v]`` (``g_C <- g_C exp(xi^)``) ``d c / d xi = [[c]x, -I]``, and
  ``xi = Ad(g_{C_L}^L)^-1 J_L^L(q) dq`` (eq. (10)); on the target
  ``d c / d p_T = R_C^T``, ``d c / d theta = -R_C^T [R_T X_i]x J_l(theta)`` (``J_l`` the left
  Jacobian of SO(3));
* initialization at the first detection: planar PnP (both IPPE solutions,
  :func:`pose_from_view`; the one whose z axis is closest to the believed normal
  ``level_normal``) composed with the current camera-pose
  estimate, with a wide prior (``initial_*_std``) uncorrelated with the rest, so the frames
  themselves build the correlations. Written into every tick the filter keeps (no measurement
  touched the target states before, so this is exact);
* gate: a frame whose normalized innovation squared exceeds the chi-square 99.9 % quantile
  (``2k`` degrees of freedom) is not fused; after ``reinit_after`` seconds of rejected frames
  the target is initialized again from the current frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit
from scipy.special import chdtri

from .. import _validate as C
from ..lie.se3 import skew
from ..vision.ippe import canonical_frame
from ..vision.target_filter import pnp_kernel
from .config import EstimationConfig


@dataclass(frozen=True)
class TargetViewMeasurement:
    """The target's feature points detected by C_L at capture time ``t``, in normalized image
    coordinates of the controller's camera model (``(k, 2)``, the target's point order)."""

    t: float
    points: np.ndarray


@dataclass(frozen=True)
class TargetCamera:
    """What the filter knows of C_L and the target (module docstring).

    ``tip_mount``: ``g_{C_L}^L`` (4x4); ``object_points``: the target's feature points in its
    frame (``(k, 3)``, planar, ``k >= 4`` for the initialization); ``sigma``: corner noise in
    normalized coordinates (``[sigma_px / f_x, sigma_px / f_y]``); ``level_normal``: the
    believed direction of the target's z axis in the world (chooses between the two planar-PnP
    solutions); ``target_initial_position_std`` (m), ``target_initial_attitude_std`` (rad): the
    prior of the target pose at its initialization; ``reinit_after`` (s) of gated-out frames restart it.
    """

    tip_mount: np.ndarray
    object_points: np.ndarray
    sigma: np.ndarray
    level_normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    target_initial_position_std: float = EstimationConfig().target_initial_position_std
    target_initial_attitude_std: float = EstimationConfig().target_initial_attitude_std
    reinit_after: float = 0.5

    def __post_init__(self):
        object.__setattr__(self, "tip_mount", C.transform("tip_mount", self.tip_mount))
        obj = np.ascontiguousarray(C.array("object_points", self.object_points, (-1, 3)))
        if not 4 <= obj.shape[0] <= 8:
            raise ValueError(f"object_points must be (k, 3) with 4 <= k <= 8, got {obj.shape}")
        object.__setattr__(self, "object_points", obj)
        sig = C.array("sigma", self.sigma, (2,))
        if np.any(sig <= 0):
            raise ValueError(f"sigma must be positive, got {sig}")
        object.__setattr__(self, "sigma", sig)
        object.__setattr__(self, "level_normal", C.unit_vector("level_normal", self.level_normal))
        for name in ("target_initial_position_std", "target_initial_attitude_std", "reinit_after"):
            C.positive(name, getattr(self, name))

    @cached_property
    def gate(self) -> float:
        """Chi-square 99.9 % quantile for the view's ``2k`` degrees of freedom."""
        return float(chdtri(2 * self.object_points.shape[0], 1e-3))


@njit(cache=True)
def view_model(rc, pc, rt, pt, jl, obj):
    """Predicted normalized points ``z`` (2k,) and their Jacobians on the camera's body twist
    ``[w; v]`` (2k x 6) and on the target's ``[p_T, theta]`` (2k x 6); ``ok`` is False if a
    point is not in front of the camera (module docstring for the formulas)."""
    k = obj.shape[0]
    z = np.empty(2 * k)
    h_cam = np.zeros((2 * k, 6))
    h_tgt = np.zeros((2 * k, 6))
    rct = rc.T.copy()
    # per-point scratch, allocated once: the entries not written below stay zero
    dpi = np.zeros((2, 3))
    dc_dxi = np.zeros((3, 6))
    for j in range(3):
        dc_dxi[j, 3 + j] = -1.0
    dc_dt = np.zeros((3, 6))
    dc_dt[:, :3] = rct
    for i in range(k):
        rx = rt @ obj[i]
        c = rct @ (pt + rx - pc)
        if c[2] <= 1e-9:
            return z, h_cam, h_tgt, False
        x, y = c[0] / c[2], c[1] / c[2]
        z[2 * i], z[2 * i + 1] = x, y
        dpi[0, 0], dpi[0, 2] = 1.0 / c[2], -x / c[2]
        dpi[1, 1], dpi[1, 2] = 1.0 / c[2], -y / c[2]
        dc_dxi[:, :3] = skew(c)
        dc_dt[:, 3:] = -(rct @ skew(rx)) @ jl
        h_cam[2 * i : 2 * i + 2] = dpi @ dc_dxi
        h_tgt[2 * i : 2 * i + 2] = dpi @ dc_dt
    return z, h_cam, h_tgt, True


@njit(cache=True)
def pose_from_view(obj, obj2d, canon_inv, points, camera_pose, level_normal, out):
    """World pose (into ``out``, 4x4) of the target from one detection ``points`` (k, 2,
    normalized) seen from ``camera_pose``: of the two planar PnP solutions
    (:func:`~tdacm.vision.target_filter.pnp_kernel`, IPPE on the target's points ``obj`` with
    their canonical plane frame ``obj2d``, ``canon_inv``), the one whose z axis is closest to
    ``level_normal`` (the first on a tie). False if PnP fails or puts a point behind the
    camera."""
    poses = np.empty((2, 4, 4))
    got = pnp_kernel(obj, obj2d, canon_inv, points, camera_pose, poses)
    if got == 0:
        return False
    best = 0
    if got == 2:
        ln = level_normal
        d0 = poses[0, 0, 2] * ln[0] + poses[0, 1, 2] * ln[1] + poses[0, 2, 2] * ln[2]
        d1 = poses[1, 0, 2] * ln[0] + poses[1, 1, 2] * ln[1] + poses[1, 2, 2] * ln[2]
        if d1 > d0:
            best = 1
    out[:, :] = poses[best]
    return True


def target_pose_from_view(points, object_points, camera_pose, level_normal) -> np.ndarray | None:
    """World pose (4x4) of the target from one detection (:func:`pose_from_view`); ``None``
    if PnP fails or puts a point behind the camera."""
    obj = np.ascontiguousarray(object_points, dtype=float)
    obj2d, canon = canonical_frame(obj)
    out = np.empty((4, 4))
    ok = pose_from_view(
        obj, np.ascontiguousarray(obj2d), np.ascontiguousarray(np.linalg.inv(canon)),
        np.ascontiguousarray(points, dtype=float).reshape(-1, 2),
        np.ascontiguousarray(camera_pose, dtype=float), np.asarray(level_normal, dtype=float),
        out,
    )  # fmt: skip
    return out if ok else None
