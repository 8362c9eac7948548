"""Recovery planner and mode switch of the dual-camera algorithm (paper, "Smooth Joint
Trajectory Tracking").

1. :func:`estimate_target_pose`: pose of the target in the global camera C_G from one
   snapshot (planar pose by IPPE, :mod:`tdacm.vision.ippe`, on a square marker: the ArUco
   marker itself, or the largest tag of the AprilTag pattern, shifted to the pattern's
   centre; the pose of ``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)``).
2. :func:`target_in_local_camera`: the target centre in C_L through the kinematic chain
   ``r^{C_L} = (g_{C_L}^L)^-1 (g_L^a(q_s))^-1 (g_a^b)^-1 g_{C_G}^b r^{C_G}``.
3. :func:`plan_rod_configuration`: ``q_s^d = argmin |[x, y]| s.t. z > 0`` of that point
   (``z >= z_min`` with ``z_min`` the camera's near plane, ``|q_s| <= bound``), from the
   current strains and from the straight rod: Levenberg-Marquardt on the residuals
   ``[x, y, sqrt(mu) max(0, z_min - z)]`` with the analytic Jacobian
   ``d r^{C_L} / d q_s = [r^]_x J_w - J_v`` (``[J_w; J_v] = Ad(g_{C_L}^L)^-1 J_L^L``, the
   camera's twist per strain rate), steps projected onto the bounds
   (:func:`plan_kernel`, compiled: the batched engine calls it too).
4. The cubic trajectory (:class:`~.trajectory.CubicTrajectory`) to ``q_s^d``.
5. :class:`ModeSwitch`: IBVS takes over as soon as all four features are at least
   ``margin_px`` inside C_L's image for ``confirm`` consecutive frames; it hands back to
   recovery only after ``lose`` consecutive frames without a full detection (hysteresis:
   no chattering).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numba import njit

from ..system.kernels import chain_jacobian
from ..vision.ippe import best_pose
from ..vision.targets import ArucoMarker

#: order of OpenCV's marker corners (TL, TR, BR, BL) that IPPE_SQUARE expects
#: ((-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2) in a y-down target frame)
IPPE_ORDER = (3, 2, 1, 0)


def square_corners(side: float) -> np.ndarray:
    """A square marker's corners in the target frame's axes (x right, y down), in the order
    of :data:`IPPE_ORDER`'s pixels (bottom-left, bottom-right, top-right, top-left)."""
    h = 0.5 * side
    return np.array([[-h, h], [h, h], [h, -h], [-h, -h]])


def estimate_target_pose(detection, camera, target) -> np.ndarray:
    """4x4 pose of the target frame in the camera frame from a detection (raw corners per
    marker id): IPPE on one square marker (module docstring)."""
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
    if camera.has_distortion:
        raise ValueError("the snapshot's pose needs a camera without lens distortion")
    obj = target.corner_points(mid)  # OpenCV order, target frame
    centre = obj.mean(axis=0)
    side = float(np.linalg.norm(obj[1] - obj[0]))
    img = np.asarray(detection.corners[mid], float)[list(IPPE_ORDER)]
    xy = np.column_stack(((img[:, 0] - camera.cx) / camera.fx, (img[:, 1] - camera.cy) / camera.fy))
    g = np.eye(4)
    if not square_pose(square_corners(side), np.ascontiguousarray(xy), centre, g):
        raise ValueError("the marker's corners admit no pose")
    return g


@njit(cache=True)
def square_pose(square, xy, centre, out):
    """The target's pose (into ``out``, 4x4) in a camera that sees a square marker's corners
    (canonical plane points ``square`` (4, 2), :func:`_square`) at normalized points ``xy``
    (4, 2): the better IPPE pose of the marker (whose frame has the target frame's axes),
    shifted by the marker's ``centre`` (3,) in the target frame. False when no pose explains
    the corners."""
    r = np.empty((3, 3))
    t = np.empty(3)
    if not best_pose(square, xy, r, t):
        return False
    for i in range(3):
        for j in range(3):
            out[i, j] = r[i, j]
    for i in range(3):
        out[i, 3] = t[i] - (out[i, 0] * centre[0] + out[i, 1] * centre[1] + out[i, 2] * centre[2])
        out[3, i] = 0.0
    out[3, 3] = 1.0
    return True


def _rod_tip_in_body(system, q_s, base_q=None, rod: int = 0) -> np.ndarray:
    """``g_a^b g_L^a(q_s)``: the tip pose of rod ``rod`` (strains ``q_s``, those of that rod
    when the robot has several) in the body (or clamp) frame."""
    q_s = np.asarray(q_s, float)
    if system.n_rods > 1:
        full = np.zeros(system.n_s)
        full[rod_columns(system, rod)] = q_s
        q_s = full
    if system.floating:
        q = np.zeros(system.n)
        if base_q is not None:
            q[:6] = base_q
        q[6:] = q_s
    else:
        q = q_s
    return np.linalg.solve(system.base_pose(q), system.tip_pose(q, rod))


def target_in_local_camera(system, q_s, point_body, tip_mount, rod: int = 0) -> np.ndarray:
    """Target point (given in the body frame) expressed in C_L for rod strains ``q_s`` (of
    rod ``rod``)."""
    g_cl_b = _rod_tip_in_body(system, q_s, rod=rod) @ tip_mount
    p = np.append(np.asarray(point_body, float), 1.0)
    return np.linalg.solve(g_cl_b, p)[:3]


@dataclass(frozen=True)
class PlanResult:
    q_s: np.ndarray
    point_local: np.ndarray  # target centre in C_L at q_s
    cost: float  # |[x, y]| (m)
    success: bool


#: bound on each planned strain coordinate (rad/m): the rod's range of validity
PLAN_BOUND = 1.5
#: weight ``mu`` of the near-plane constraint's penalty residual (1/m^2 of violation)
_PENALTY = 1e8
#: Levenberg-Marquardt iterations per start
_ITERATIONS = 100


@njit(cache=True)
def _point_and_jacobian(qs, m, lo, hi, mount_inv, p_body, p, jac):
    """The body-frame point ``p_body`` in C_L at strains ``qs`` (into ``p`` (3,)) and its
    derivative ``d p / d q_s`` (into ``jac`` (3, n_s)): ``[p^] J_w - J_v``."""
    ns = qs.shape[0]
    off = 6 if m.floating else 0
    # the rod whose steps are lo:hi, its first strain column and the strains of all rods (the
    # other rods' strains stay zero: they do not move this rod's chain)
    rod = 0
    for r in range(m.rod_steps.shape[0] - 1):
        if m.rod_steps[r] == lo:
            rod = r
    col0 = m.step_col[lo]
    nst = 0
    for k in range(m.step_col.shape[0]):
        nst = max(nst, m.step_col[k] + m.step_nc[k])
    q = np.zeros(off + nst)
    for i in range(ns):
        q[off + col0 + i] = qs[i]
    g, j, _ = chain_jacobian(
        q, np.zeros(q.shape[0]), m.floating, m.g_fixed, m.g_att[rod], m.h[lo:hi],
        m.xi0s[lo:hi], m.bs[lo:hi], m.step_col[lo:hi], m.step_nc[lo:hi],
    )  # fmt: skip
    if not m.floating:  # relative to the clamp
        gi = np.linalg.inv(m.g_fixed)
        g = gi @ g
    gc = g @ np.linalg.inv(mount_inv)  # camera pose in the body frame
    for i in range(3):
        acc = 0.0
        for k in range(3):
            acc += gc[k, i] * (p_body[k] - gc[k, 3])
        p[i] = acc
    # the camera's twist per strain rate: Ad(mount)^-1 J (columns of the strains)
    r = mount_inv[:3, :3]
    t = mount_inv[:3, 3]
    for c in range(ns):
        jw = np.empty(3)
        jv = np.empty(3)
        jc = off + col0 + c
        w0, w1, w2 = j[0, jc], j[1, jc], j[2, jc]
        v0, v1, v2 = j[3, jc], j[4, jc], j[5, jc]
        for i in range(3):
            jw[i] = r[i, 0] * w0 + r[i, 1] * w1 + r[i, 2] * w2
        # v_c = R v + t x (R w)
        for i in range(3):
            jv[i] = r[i, 0] * v0 + r[i, 1] * v1 + r[i, 2] * v2
        jv[0] += t[1] * jw[2] - t[2] * jw[1]
        jv[1] += t[2] * jw[0] - t[0] * jw[2]
        jv[2] += t[0] * jw[1] - t[1] * jw[0]
        # d p / dt = -w x p - v = p x w - v
        jac[0, c] = p[1] * jw[2] - p[2] * jw[1] - jv[0]
        jac[1, c] = p[2] * jw[0] - p[0] * jw[2] - jv[1]
        jac[2, c] = p[0] * jw[1] - p[1] * jw[0] - jv[2]


@njit(cache=True)
def _residuals(p, z_min, r):
    r[0] = p[0]
    r[1] = p[1]
    r[2] = np.sqrt(_PENALTY) * max(0.0, z_min - p[2])
    return r[0] * r[0] + r[1] * r[1] + r[2] * r[2]


@njit(cache=True)
def _solve_from(x0, m, lo, hi, mount_inv, p_body, z_min, bound):
    """Levenberg-Marquardt from ``x0`` (module docstring): the strains and the final point."""
    ns = x0.shape[0]
    x = x0.copy()
    for i in range(ns):
        x[i] = min(max(x[i], -bound), bound)
    p = np.empty(3)
    jac = np.empty((3, ns))
    r = np.empty(3)
    _point_and_jacobian(x, m, lo, hi, mount_inv, p_body, p, jac)
    cost = _residuals(p, z_min, r)
    lam = 1e-3
    pt = np.empty(3)
    jt = np.empty((3, ns))
    rt = np.empty(3)
    for _ in range(_ITERATIONS):
        # the penalty row's Jacobian: -sqrt(mu) dz/dq while violated
        jr = np.zeros((3, ns))
        for c in range(ns):
            jr[0, c] = jac[0, c]
            jr[1, c] = jac[1, c]
            jr[2, c] = -np.sqrt(_PENALTY) * jac[2, c] if r[2] > 0.0 else 0.0
        a = jr.T @ jr
        g = jr.T @ r
        improved = False
        for _ in range(30):
            h = a.copy()
            for i in range(ns):
                h[i, i] += lam * (a[i, i] + 1e-12)
            step = np.linalg.solve(h, -g)
            xn = x + step
            for i in range(ns):
                xn[i] = min(max(xn[i], -bound), bound)
            _point_and_jacobian(xn, m, lo, hi, mount_inv, p_body, pt, jt)
            cn = _residuals(pt, z_min, rt)
            if cn < cost:
                move = 0.0
                for i in range(ns):
                    move = max(move, abs(xn[i] - x[i]))
                x = xn
                p[:] = pt
                jac[:, :] = jt
                r[:] = rt
                cost = cn
                lam = max(lam * 0.3, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or cost < 1e-24 or move < 1e-14:
            break
    return x, p


@njit(cache=True)
def plan_kernel(qs_now, m, lo, hi, mount_inv, p_body, z_min, bound, has_start):
    """``(q_s, point_local, cost, feasible)`` of the plan (module docstring): the better of
    the solutions from the current strains ``qs_now`` (when ``has_start``) and from the
    straight rod, judged by feasibility first, then by ``|[x, y]|``."""
    ns = qs_now.shape[0]
    best_x = np.zeros(ns)
    best_p = np.zeros(3)
    best_key = (True, np.inf)
    for s in range(2):
        if s == 0 and not has_start:
            continue
        x0 = qs_now.copy() if s == 0 else np.zeros(ns)
        x, p = _solve_from(x0, m, lo, hi, mount_inv, p_body, z_min, bound)
        key = (not (p[2] >= z_min - 1e-6), np.hypot(p[0], p[1]))
        if key < best_key:
            best_key = key
            best_x = x
            best_p = p
    return best_x, best_p, best_key[1], not best_key[0]


def rod_columns(system, rod: int = 0) -> slice:
    """The strain coordinates of rod ``rod`` among the strains ``q_s`` (a slice; the rods'
    strains are consecutive, rod 0 first)."""
    m = system.model_arrays
    if not 0 <= rod < len(m.rod_steps) - 1:
        raise ValueError(f"rod {rod} out of range (the robot has {len(m.rod_steps) - 1})")
    lo, hi = int(m.rod_steps[rod]), int(m.rod_steps[rod + 1])
    cols = m.step_col[lo:hi]
    return slice(int(cols.min()), int((cols + m.step_nc[lo:hi]).max()))


def plan_rod_configuration(
    system,
    point_body,
    tip_mount,
    q_s0=None,
    z_min: float = 0.5,
    bound: float = PLAN_BOUND,
    rod: int = 0,
) -> PlanResult:
    """``q_s^d`` of the paper's constrained minimization (see module docstring) for the
    strains of rod ``rod`` (its columns :func:`rod_columns`; ``q_s0`` and the result are that
    rod's strains, the other rods' do not enter its chain)."""
    m = system.model_arrays
    cols = rod_columns(system, rod)
    ns = cols.stop - cols.start
    has = q_s0 is not None
    start = np.asarray(q_s0, float) if has else np.zeros(ns)
    mount_inv = np.linalg.inv(np.asarray(tip_mount, float))
    x, p, c, feasible = plan_kernel(
        np.ascontiguousarray(start), m, int(m.rod_steps[rod]), int(m.rod_steps[rod + 1]),
        np.ascontiguousarray(mount_inv), np.ascontiguousarray(point_body, dtype=float),
        float(z_min), float(bound), has,
    )  # fmt: skip
    return PlanResult(np.asarray(x), np.asarray(p), float(c), bool(feasible and c < 1e-3))


class Mode(StrEnum):
    """The servo's mode: IBVS on C_L, or recovery from one C_G snapshot."""

    IBVS = "ibvs"
    RECOVERY = "recovery"


class ModeSwitch:
    """IBVS / recovery switching with a margin and hysteresis (module docstring); ``margin_px``,
    ``confirm`` and ``lose`` are the scenario's ``[recovery]`` keys (their defaults are those of
    :class:`tdacm.loop.config.RecoveryConfig`)."""

    def __init__(
        self,
        camera,
        margin_px: float,
        confirm: int,
        lose: int,
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
