"""Recovery planner and mode switch of the dual-camera algorithm (paper, "Smooth Joint
Trajectory Tracking").

1. :func:`estimate_target_pose`: pose of the target in the global camera C_G from one
   snapshot (``cv2.solvePnP(..., flags=cv2.SOLVEPNP_IPPE_SQUARE)`` on a square marker: the
   ArUco marker itself, or one tag of the AprilTag pattern, shifted to the pattern's centre).
2. :func:`target_in_local_camera`: the target centre in C_L through the kinematic chain
   ``r^{C_L} = (g_{C_L}^L)^-1 (g_L^a(q_s))^-1 (g_a^b)^-1 g_{C_G}^b r^{C_G}``.
3. :func:`plan_rod_configuration`: ``q_s^d = argmin |[x, y]| s.t. z > 0`` of that point
   (SLSQP from several starts; ``z >= z_min`` with ``z_min`` the camera's near plane).
4. The cubic trajectory (:class:`~.trajectory.CubicTrajectory`) to ``q_s^d``.
5. :class:`ModeSwitch`: IBVS takes over as soon as all four features are at least
   ``margin_px`` inside C_L's image for ``confirm`` consecutive frames; it hands back to
   recovery only after ``lose`` consecutive frames without a full detection (hysteresis:
   no chattering).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np
from scipy.optimize import minimize

from ..vision.targets import ArucoMarker

#: order of OpenCV's marker corners (TL, TR, BR, BL) that IPPE_SQUARE expects
#: ((-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2) in a y-down target frame)
_IPPE_ORDER = (3, 2, 1, 0)


def estimate_target_pose(detection, camera, target) -> np.ndarray:
    """4x4 pose of the target frame in the camera frame from a detection (raw corners per
    marker id) with ``SOLVEPNP_IPPE_SQUARE``."""
    if detection is None or not detection.corners:
        raise ValueError("no marker corners in the detection")
    if isinstance(target, ArucoMarker):
        mid = target.marker_id
        if mid not in detection.corners:
            raise ValueError(f"marker {mid} not detected")
    else:
        seen = [i for i in target.ids if i in detection.corners]
        if not seen:
            raise ValueError("no tag of the pattern detected")
        mid = max(seen, key=lambda i: np.ptp(detection.corners[i], axis=0).sum())
    obj = target.corner_points(mid)  # OpenCV order, target frame
    centre = obj.mean(axis=0)
    side = float(np.linalg.norm(obj[1] - obj[0]))
    h = side / 2
    obj_sq = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    img = np.asarray(detection.corners[mid], float)[list(_IPPE_ORDER)]
    dist = np.asarray(camera.distortion) if camera.has_distortion else None
    ok, rvec, tvec = cv2.solvePnP(
        obj_sq, img.reshape(-1, 1, 2), camera.K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
    )
    if not ok:
        raise ValueError("solvePnP failed")
    r, _ = cv2.Rodrigues(rvec)
    g = np.eye(4)
    g[:3, :3] = r
    g[:3, 3] = tvec.ravel() - r @ centre  # marker centre sits at `centre` in the target frame
    return g


def _rod_tip_in_body(system, q_s, base_q=None) -> np.ndarray:
    """``g_a^b g_L^a(q_s)``: the tip pose in the body (or clamp) frame."""
    q_s = np.asarray(q_s, float)
    if system.floating:
        q = np.zeros(system.n)
        if base_q is not None:
            q[:6] = base_q
        q[6:] = q_s
    else:
        q = q_s
    return np.linalg.solve(system.base_pose(q), system.tip_pose(q))


def target_in_local_camera(system, q_s, point_body, tip_mount) -> np.ndarray:
    """Target point (given in the body frame) expressed in C_L for rod strains ``q_s``."""
    g_cl_b = _rod_tip_in_body(system, q_s) @ tip_mount
    p = np.append(np.asarray(point_body, float), 1.0)
    return np.linalg.solve(g_cl_b, p)[:3]


@dataclass(frozen=True)
class PlanResult:
    q_s: np.ndarray
    point_local: np.ndarray  # target centre in C_L at q_s
    cost: float  # |[x, y]| (m)
    success: bool


def plan_rod_configuration(
    system, point_body, tip_mount, q_s0=None, z_min: float = 0.5, bound: float = 1.5
) -> PlanResult:
    """``q_s^d`` of the paper's constrained minimization (see module docstring)."""
    ns = system.n_s
    starts = [np.zeros(ns)] if q_s0 is None else [np.asarray(q_s0, float), np.zeros(ns)]

    def pt(x):
        return target_in_local_camera(system, x, point_body, tip_mount)

    def cost(x):
        p = pt(x)
        return float(p[0] ** 2 + p[1] ** 2)

    cons = [{"type": "ineq", "fun": lambda x: pt(x)[2] - z_min}]
    best = None
    for x0 in starts:
        res = minimize(
            cost,
            x0,
            method="SLSQP",
            constraints=cons,
            bounds=[(-bound, bound)] * ns,
            options={"ftol": 1e-14, "maxiter": 200},
        )
        p = pt(res.x)
        feasible = p[2] >= z_min - 1e-6
        cand = (not feasible, float(np.hypot(p[0], p[1])), res.x, p)
        if best is None or cand[:2] < best[:2]:
            best = cand
    infeasible, c, x, p = best
    return PlanResult(np.asarray(x), p, c, bool(not infeasible and c < 1e-3))


class Mode(StrEnum):
    """The servo's mode: IBVS on C_L, or recovery from one C_G snapshot."""

    IBVS = "ibvs"
    RECOVERY = "recovery"


class ModeSwitch:
    """IBVS / recovery switching with a margin and hysteresis (module docstring)."""

    def __init__(
        self,
        camera,
        margin_px: float = 20.0,
        confirm: int = 2,
        lose: int = 5,
        initial: Mode | str = Mode.RECOVERY,
    ):
        self.camera = camera
        self.margin_px = float(margin_px)
        self.confirm = int(confirm)
        self.lose = int(lose)
        self.reset(initial)

    def reset(self, mode: Mode | str = Mode.RECOVERY) -> None:
        """Start in ``mode`` with the hysteresis counters cleared."""
        try:
            self.mode = Mode(mode)
        except ValueError:
            raise ValueError(f"initial mode must be 'ibvs' or 'recovery', got {mode!r}") from None
        self._good = 0
        self._bad = 0

    def inside(self, pixels) -> bool:
        if pixels is None:
            return False
        return bool(np.all(self.camera.pixels_in_image(pixels, self.margin_px)))

    def update(self, pixels) -> Mode:
        """Feed the detected pixels (``None`` when not detected); returns the mode."""
        found = pixels is not None
        if self.mode == Mode.RECOVERY:
            self._good = self._good + 1 if self.inside(pixels) else 0
            if self._good >= self.confirm:
                self.mode, self._bad = Mode.IBVS, 0
        else:
            self._bad = 0 if found else self._bad + 1
            if self._bad >= self.lose:
                self.mode, self._good = Mode.RECOVERY, 0
        return self.mode
