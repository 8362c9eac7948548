"""Kinematic closed loops for checking the IBVS law without dynamics.

:func:`free_camera_servo` integrates a free-flying camera driven by the advanced-feature IBVS
twist, ``g <- g exp(dt [w; v])`` (body twist, :func:`tdacm.lie.se3.expmap`), with the features
computed analytically from the target's 3-D points (no rendering). :func:`random_initial_pose`
draws the seeded initial poses the tests and the benchmark use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lie.se3 import expmap, rotation_angle
from . import _checks as C
from .ibvs import DEFAULT_MODE, IBVSController
from .mounts import tip_camera_pose


@dataclass(frozen=True)
class LoopResult:
    """Outcome of one closed-loop run."""

    converged: bool
    steps: int
    feature_error: float  # final |e|
    position_error: float  # final |p - p_d| (m)
    rotation_error: float  # final rotation angle to the desired pose (rad)
    lost: bool  # a point went behind the camera / out of view
    final_pose: np.ndarray


def project_points(points_target, camera_pose_in_target):
    """Normalized coordinates ``(N, 2)`` and depths ``(N,)`` of target-frame points seen
    from a camera whose pose in the target frame is ``camera_pose_in_target``."""
    g = camera_pose_in_target
    r, t = g[:3, :3], g[:3, 3]
    pc = (points_target - t) @ r
    return pc[:, :2] / pc[:, 2:3], pc[:, 2]


def free_camera_servo(
    points_target,
    initial_pose,
    desired_pose,
    *,
    gain: float,
    dt: float = 0.02,
    max_steps: int = 600,
    mode: str = DEFAULT_MODE,
    tol: float = 1e-6,
    camera=None,
    margin: float = 0.0,
) -> LoopResult:
    """Servo a free camera from ``initial_pose`` to the view of ``desired_pose``.

    Parameters
    ----------
    points_target:
        ``(4, 3)`` feature points in the target frame (paper order).
    initial_pose, desired_pose:
        Camera poses in the target frame (4x4).
    gain, dt, max_steps:
        IBVS gain ``lambda``, integration step (s) and step limit.
    mode:
        Interaction matrix choice (``"current"``, ``"desired"``, ``"mean"``).
    tol:
        Convergence threshold on ``|e|``.
    camera:
        Optional :class:`~.camera.PinholeCamera`: the run counts as lost if a point leaves
        its field of view (with ``margin`` pixels).
    """
    pts = C.array("points_target", points_target, (4, 3))
    g = C.transform("initial_pose", initial_pose).copy()
    gd = C.transform("desired_pose", desired_pose)
    xd, zd = project_points(pts, gd)
    ctrl = IBVSController(xd, zd, gain=gain, floor=0.0, mode=mode)

    def view(g):
        xy, z = project_points(pts, g)
        if np.any(z <= 1e-3):
            return None
        if camera is not None:
            uv = np.column_stack(
                (camera.fx * xy[:, 0] + camera.cx, camera.fy * xy[:, 1] + camera.cy)
            )
            if not np.all(camera.pixels_in_image(uv, margin)):
                return None
        return xy, z

    converged, k, e_norm, g, lost = _ibvs_loop(
        view, ctrl, lambda g, v: g @ expmap(dt * v), g, max_steps, tol
    )
    pos = float(np.linalg.norm(g[:3, 3] - gd[:3, 3]))
    rot = rotation_angle(gd[:3, :3].T @ g[:3, :3])
    return LoopResult(converged, k, e_norm, pos, rot, lost, g)


def _ibvs_loop(view, ctrl, advance, state, max_steps, tol):
    """The kinematic IBVS loop: ``view(state) -> (xy, z)`` (``None``: the target is lost),
    ``advance(state, twist) -> state`` for one step, until ``|e| < tol`` or ``max_steps``.
    Returns ``(converged, steps, |e|, state, lost)``."""
    e_norm, lost, converged, k = np.inf, False, False, 0
    for k in range(1, int(max_steps) + 1):  # noqa: B007 - k is reported
        seen = view(state)
        if seen is None:
            lost = True
            break
        xy, z = seen
        e_norm = float(np.linalg.norm(ctrl.error(xy)))
        if e_norm < tol:
            converged = True
            break
        state = advance(state, ctrl.twist(xy, z))
    return converged and not lost, k, e_norm, state, lost


def random_initial_pose(
    rng: np.random.Generator,
    desired_pose,
    yaw_range_deg=(-180, 180),
    max_tilt_deg: float = 20.0,
    lateral: float = 0.3,
    depth_range=(-0.5, 1.0),
) -> np.ndarray:
    """A random camera pose around ``desired_pose`` (target frame): yaw about the optical
    axis uniform in ``yaw_range_deg``, tilt about x and y uniform in ``+-max_tilt_deg``, lateral
    offsets uniform in ``+-lateral`` m and a change of distance in ``depth_range`` m."""
    gd = C.transform("desired_pose", desired_pose)
    yaw = np.radians(rng.uniform(*yaw_range_deg))
    ax, ay = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, 2))
    cz, sz = np.cos(yaw), np.sin(yaw)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(ax), -np.sin(ax)], [0.0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0.0, np.sin(ay)], [0.0, 1.0, 0.0], [-np.sin(ay), 0.0, np.cos(ay)]])
    g = gd.copy()
    g[:3, :3] = gd[:3, :3] @ rz @ ry @ rx
    offset = np.array([*rng.uniform(-lateral, lateral, 2), -rng.uniform(*depth_range)])
    g[:3, 3] = gd[:3, 3] + gd[:3, :3] @ offset
    return g


@dataclass(frozen=True)
class ArmLoopResult:
    """Outcome of :func:`tdacm_servo`."""

    converged: bool
    steps: int
    feature_error: float
    q: np.ndarray  # final generalized coordinates
    lost: bool


def tdacm_servo(
    system,
    q0,
    q_desired,
    points_world,
    mount=None,
    *,
    gain: float,
    dt: float = 0.02,
    max_steps: int = 1000,
    tol: float = 1e-6,
    jacobian_at: str = "virtual",
    camera=None,
) -> ArmLoopResult:
    """Kinematic servo of the TD-ACM's tip camera (no dynamics, no rendering).

    Each step: project the target into C_L at ``q``, compensate roll/pitch exactly into
    C_V (:func:`~.virtual.virtual_camera_points`), IBVS twist of C_V (paper eq. (39)), tip
    twist ``Ad(g_{C_V}^L) v`` and ``qdot = pinv(J_L^L[:, commanded]) v_L``
    (:func:`~.tip.camera_joint_rates`), then ``q <- q + dt qdot``. The drone's roll and pitch
    are not commanded and keep their initial values (in flight the translational loop sets
    them), so the loop converges in C_V to the reference view of ``q_desired``.

    ``system`` needs ``n``, ``floating``, ``base_pose``, ``tip_pose`` and ``tip_jacobian``.
    """
    from .mounts import DEFAULT_TIP_CAMERA_MOUNT
    from .tip import camera_joint_rates
    from .virtual import virtual_camera_points, virtual_camera_transform

    mount = DEFAULT_TIP_CAMERA_MOUNT if mount is None else C.transform("mount", mount)
    pw = C.array("points_world", points_world, (4, 3))
    n = system.n
    q = C.array("q0", q0, (n,)).copy()
    qd = C.array("q_desired", q_desired, (n,))

    def view(qq):
        g_b = system.base_pose(qq)
        g_cl = tip_camera_pose(system, qq, mount)
        r, t = g_cl[:3, :3], g_cl[:3, 3]
        pc = (pw - t) @ r
        if np.any(pc[:, 2] <= 1e-3):
            return None, None, None
        xy = pc[:, :2] / pc[:, 2:3]
        if getattr(system, "floating", False):
            xy, z = virtual_camera_points(
                xy, virtual_camera_transform(g_b, g_cl), pc[:, 2], return_depths=True
            )
        else:
            z = pc[:, 2]
        return xy, z, (xy, pc) if camera is not None else None

    xd, zd, _ = view(qd)
    if xd is None:
        raise ValueError("the target is behind the camera at q_desired")
    ctrl = IBVSController(xd, zd, gain=gain, floor=0.0)

    def seen(qq):
        xy, z, extra = view(qq)
        if xy is None or (camera is not None and not camera.all_in_fov(extra[1])):
            return None
        return xy, z

    def advance(qq, v):
        return qq + dt * camera_joint_rates(system, qq, v, mount, jacobian_at=jacobian_at)

    converged, k, e_norm, q, lost = _ibvs_loop(seen, ctrl, advance, q, max_steps, tol)
    return ArmLoopResult(converged, k, e_norm, q, lost)
