"""World-frame estimate of a static target from the tip camera's detections.

Why (docs/control.md, "Robust servo"): for a 20 cm marker seen from 1.5-3.5 m, one image
determines two combinations of the relative pose only weakly (rotation about the camera x
axis with translation along y, and about y with x; ``J_img`` has two singular values 30-60x
below the others): from one frame with 1 px of corner noise the target's tilt is known to
about 9 degrees only. The target, however, does not move: its pose in the world frame,
``g_T = g_C(t_k) g_T^C(t_k)``, is the same at every capture time ``t_k``. Fusing the corner
measurements of many frames through the known camera poses averages the noise out (the
covariance falls like ``1/N``, the weak directions included) and lets the servo work on
features *predicted* from the estimate at the current camera pose: noise-free between
detections, defined through missed frames, and exactly compensated for latency (a frame
captured ``k`` periods ago is associated with the camera pose at its capture time).

Estimator: maximum likelihood over a sliding window of frames (a fixed-lag batch
Gauss-Newton, the smoother form of an information filter; a recursive EKF was tried first
and measured: linearized at the first frames' poor tilt it stayed 1-15 degrees off after
250 frames, well outside its own covariance):

* state: ``g_T`` (4x4, target frame in the world); perturbation ``g_T <- g_T exp(delta^)``,
  ``delta = [w; v]`` (angular-first, target frame, like every twist of the model);
* measurement of frame ``j``: the four feature points in normalized coordinates,
  ``z_jk = pi(g_{C_j}^-1 g_T X_k) + n``, ``n ~ N(0, diag(sigma/f_x, sigma/f_y)^2)`` with
  ``sigma`` the corner noise in pixels and ``pi([X, Y, Z]) = [X/Z, Y/Z]``;
* Jacobian (camera coordinates ``r = R_{C_j}^T (R_T X_k + p_T - p_{C_j})``):
  ``d r / d delta = R_{C_j}^T R_T [-X_k^, I]``,
  ``d pi / d r = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]``;
* cost ``sum_j sum_k |z_jk - pi(...)|^2_{R^-1}`` over the last ``window`` accepted frames,
  minimized by ``iterations`` Gauss-Newton steps per new frame, warm-started at the previous
  estimate; ``P = (H^T R^-1 H)^-1`` (the window's information) is the covariance;
* gate: a new frame is fused only if its innovation ``nu`` passes the Mahalanobis test
  ``nu^T (H P H^T + R)^-1 nu <= gate`` (chi-square, 8 degrees of freedom); ``reset_after``
  consecutive rejected frames mean the estimate is wrong and restart it from the current
  frame;
* initialization: both solutions of planar PnP (IPPE, :mod:`.ippe`: the poses of
  ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)``, the classic two-fold ambiguity of a small
  planar target) are kept as hypotheses and refined on the same frames until their costs
  differ by ``decisive`` (or for ``young`` frames); the estimate is always the lower-cost
  one; every ``recheck`` frames both PnP solutions of the latest frame are refined on the
  window again and adopted if their cost is lower (measured: a run of paper-out-of-fov at
  1 px otherwise stayed 18 degrees off on the wrong branch after the target entered at the
  image border);
* noise level: the gate and ``P`` use ``max(pixel_sigma, sigma_hat)`` with ``sigma_hat`` the
  RMS residual of the window (measured: with 2 px of noise and 1 px assumed, half of the
  frames were gated out and the resets made the prediction jump);
* uncertain camera poses (the loop on a state estimate, docs/estimation.md): a frame may come
  with the covariance ``Sigma_c`` of its camera pose; its measurement covariance is then
  ``R_j = R + G_j Sigma_c G_j^T`` (``G_j = dz_j / d eps``, ``g_C <- g_C exp(eps^)``,
  :func:`pose_noise`), and the frame enters the normal equations, the gate and
  ``sigma_hat`` through its full ``8 x 8`` weight ``R_j^-1`` (``_normal_equations``); a
  covariance of zeros is an exact pose.
  A pose error moves the four points almost together, so the weight discounts the common
  image shift and keeps the shape (perspective) information that determines the tilt;
  frames with an exact pose keep the diagonal fast path;
* the window forgets: a slow bias (camera-pose or intrinsics errors) is followed with a lag
  of about ``window`` frames;
* known target plane (optional, ``level_prior > 0``): a target on a level surface has its
  normal along gravity. With ``n0`` the nominal normal of the target's z axis in the world
  (``level_normal``, default straight down: the target faces up) and ``m = R_T^T n0`` (the
  nominal normal in the target frame, ``e_z`` when level), the prior residual is
  ``e_p = -m_xy`` with ``d m_xy / d delta = [m^]_xy`` on the rotation (``m <- exp(-w^) m``),
  weighted by ``1 / level_prior^2`` (rad). It informs exactly the two weak directions (the
  target's tilt) and leaves the yaw and the position to the images. It enters the cost, the
  Gauss-Newton step and ``P``; the self-calibrated noise scale multiplies the frames'
  information only.

The block's constants are a :class:`TargetFilterParams` record and its state (the estimate,
the hypotheses, the window's frames and their weights, the counters) a
:class:`TargetFilterState`; :func:`filter_update` is its compiled step (one frame of one
filter), which :class:`TargetFilter` (the Python block) and the servo's compiled step
(:mod:`tdacm.loop.servo`, run by the block loop and the batched engine) call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from .._jit import kernel
from .._linalg import solve_small
from ..lie.se3 import expmap
from . import _checks as C
from .camera import PinholeCamera
from .ippe import canonical_frame, ippe_poses

#: chi-square quantile, 8 degrees of freedom (4 points x 2), p = 0.9999
GATE_CHI2_8 = 31.83


@dataclass(frozen=True)
class TargetEstimate:
    """Current estimate: ``pose`` (4x4 ``g_T``, world), ``covariance`` (6x6, ``[w; v]`` in
    the target frame), number of fused frames, frames rejected by the gate."""

    pose: np.ndarray
    covariance: np.ndarray
    updates: int
    rejected: int


class TargetFilterParams(NamedTuple):
    """The filter's constants (the record of :func:`filter_update`; :class:`TargetFilter`'s
    arguments): ``pixel_sigma`` (px), ``window`` (frames), ``iterations``, ``gate``,
    ``young``, ``decisive``, ``reset_after``, ``recheck``, the level prior's weight
    ``prior_weight`` (``1 / level_prior^2``, 0 without the prior) and normal
    ``level_normal`` (3,), the camera's ``fx``, ``fy``, ``cx``, ``cy`` (px; its pixels are
    normalized with them and ``R = diag(pixel_sigma / fx, pixel_sigma / fy)^2``), the target's
    points ``object_points`` (4, 3), the same points in the target plane's canonical frame
    ``object_2d`` (4, 2) and the target-to-canonical transform ``canon_inv`` (4, 4)
    (:func:`~.ippe.canonical_frame`, for planar PnP)."""

    pixel_sigma: float
    window: int
    iterations: int
    gate: float
    young: int
    decisive: float
    reset_after: int
    recheck: int
    prior_weight: float
    fx: float
    fy: float
    cx: float
    cy: float
    object_points: np.ndarray
    object_2d: np.ndarray
    canon_inv: np.ndarray
    level_normal: np.ndarray

    def with_camera(self, camera) -> TargetFilterParams:
        """The same filter on the pixels of ``camera`` (its ``fx``, ``fy``, ``cx``, ``cy``)."""
        return self._replace(
            fx=float(camera.fx), fy=float(camera.fy), cx=float(camera.cx), cy=float(camera.cy)
        )


class TargetFilterState(NamedTuple):
    """The filter's state (one-element arrays for its scalars): ``initialized`` (an estimate
    exists), ``updates`` (frames fused since the last restart), ``rejected`` (frames gated
    out), ``switches`` (rescues adopted), ``sigma_hat`` (px, the window's RMS residual),
    ``bad`` (consecutive rejections), ``n_hyp`` (PnP hypotheses still refined), ``count``
    (frames in the window) and ``slot`` (the window's next slot); the estimate ``pose``
    (4, 4) and its covariance ``cov`` (6, 6), the hypotheses ``hyp`` (2, 4, 4) and the
    window as ring buffers (the sums do not depend on the frames' order): each frame's
    ``R_C^T`` ``rc`` (W, 3, 3), ``p_C`` ``pc`` (W, 3), normalized points ``z`` (W, 4, 2),
    weight (inverse covariance) ``w`` (W, 8, 8) and whether that weight is diagonal
    ``diagonal`` (W,)."""

    initialized: np.ndarray
    updates: np.ndarray
    rejected: np.ndarray
    switches: np.ndarray
    sigma_hat: np.ndarray
    bad: np.ndarray
    n_hyp: np.ndarray
    count: np.ndarray
    slot: np.ndarray
    pose: np.ndarray
    cov: np.ndarray
    hyp: np.ndarray
    rc: np.ndarray
    pc: np.ndarray
    z: np.ndarray
    w: np.ndarray
    diagonal: np.ndarray

    @classmethod
    def initial(cls, window: int) -> TargetFilterState:
        """No estimate and an empty window of ``window`` frames."""
        n = int(window)

        def count():
            return np.zeros(1, np.int64)

        return cls(
            np.zeros(1, np.bool_), count(), count(), count(), np.zeros(1), count(), count(),
            count(), count(), np.zeros((4, 4)), np.zeros((6, 6)), np.zeros((2, 4, 4)),
            np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 4, 2)), np.zeros((n, 8, 8)),
            np.zeros(n, np.bool_),
        )  # fmt: skip


def planar_pnp_poses(object_points, xy, camera_pose) -> list:
    """World poses (4x4) of a planar target from one view: both solutions of planar PnP
    (:func:`pnp_kernel`, the poses of ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`` on
    normalized points ``xy``: the two-fold ambiguity of a small planar target) that put every
    point in front of the camera, composed with ``camera_pose``, the better first."""
    obj = np.ascontiguousarray(object_points, float)
    obj2d, canon = canonical_frame(obj)
    out = np.empty((2, 4, 4))
    cnt = pnp_kernel(
        obj, obj2d, np.ascontiguousarray(np.linalg.inv(canon)),
        np.ascontiguousarray(xy, float).reshape(-1, 2), np.ascontiguousarray(camera_pose, float),
        out,
    )  # fmt: skip
    return [out[i].copy() for i in range(cnt)]


def target_in_camera(object_points, camera_pose, target_pose) -> np.ndarray:
    """Camera coordinates ``r = g_C^-1 g_T X_k`` (k, 3) of a target's points ``X_k`` (its
    frame) for world poses ``camera_pose`` ``g_C`` and ``target_pose`` ``g_T`` (4x4, rigid;
    :func:`camera_points_into`)."""
    obj = np.ascontiguousarray(object_points, float)
    r = np.empty((obj.shape[0], 3))
    camera_points_into(
        obj, np.ascontiguousarray(camera_pose, float), np.ascontiguousarray(target_pose, float), r
    )
    return r


def reference_from_pose(target, target_pose, camera_pose):
    """Desired normalized points ``(4, 2)`` and depths ``(4,)`` of ``target`` (at world pose
    ``target_pose``) seen from a camera at world pose ``camera_pose``: the paper's reference
    snapshot, computed analytically (``ValueError`` if the target is behind the camera)."""
    pc = target_in_camera(target.feature_points, camera_pose, target_pose)
    if np.any(pc[:, 2] <= 0):
        raise ValueError("the target is behind the camera in the reference pose")
    return pc[:, :2] / pc[:, 2:3], pc[:, 2]


@njit(cache=True)
def _target_points(rt, pt, obj):
    """World coordinates ``(4, 3)`` of the target's points at ``(R_T, p_T)``."""
    xw = np.empty((4, 3))
    for k in range(4):
        for j in range(3):
            xw[k, j] = rt[j, 0] * obj[k, 0] + rt[j, 1] * obj[k, 1] + rt[j, 2] * obj[k, 2] + pt[j]
    return xw


@kernel
def _frame_residuals(rcf, pcf, rt, xw, obj, zf, a, h, e):
    """Residuals ``e`` (8) and Jacobian ``h`` (8 x 6) of one frame (module docstring:
    ``h = dpi/dr R_C^T R_T [-X_k^, I]``), written into preallocated arrays (``a``: 3 x 3
    scratch for ``R_C^T R_T``); False if a point is behind the camera."""
    for i in range(3):
        for j in range(3):
            a[i, j] = rcf[i, 0] * rt[0, j] + rcf[i, 1] * rt[1, j] + rcf[i, 2] * rt[2, j]
    for k in range(4):
        d0, d1, d2 = xw[k, 0] - pcf[0], xw[k, 1] - pcf[1], xw[k, 2] - pcf[2]
        r0 = rcf[0, 0] * d0 + rcf[0, 1] * d1 + rcf[0, 2] * d2
        r1 = rcf[1, 0] * d0 + rcf[1, 1] * d1 + rcf[1, 2] * d2
        r2 = rcf[2, 0] * d0 + rcf[2, 1] * d1 + rcf[2, 2] * d2
        if r2 <= 1e-6:
            return False
        iz = 1.0 / r2
        px, py = r0 * iz, r1 * iz
        e[2 * k] = zf[k, 0] - px
        e[2 * k + 1] = zf[k, 1] - py
        x0, x1, x2 = obj[k, 0], obj[k, 1], obj[k, 2]
        for c in range(6):
            if c == 0:  # dr/d delta = [-A X_k^, A], column by column
                g0, g1, g2 = (
                    a[0, 2] * x1 - a[0, 1] * x2,
                    a[1, 2] * x1 - a[1, 1] * x2,
                    a[2, 2] * x1 - a[2, 1] * x2,
                )
            elif c == 1:
                g0, g1, g2 = (
                    a[0, 0] * x2 - a[0, 2] * x0,
                    a[1, 0] * x2 - a[1, 2] * x0,
                    a[2, 0] * x2 - a[2, 2] * x0,
                )
            elif c == 2:
                g0, g1, g2 = (
                    a[0, 1] * x0 - a[0, 0] * x1,
                    a[1, 1] * x0 - a[1, 0] * x1,
                    a[2, 1] * x0 - a[2, 0] * x1,
                )
            else:
                g0, g1, g2 = a[0, c - 3], a[1, c - 3], a[2, c - 3]
            h[2 * k, c] = iz * (g0 - px * g2)
            h[2 * k + 1, c] = iz * (g1 - py * g2)
    return True


@njit(cache=True)
def _diagonal_flags(w):
    """Whether each matrix of the stack ``w`` (N, m, m) is diagonal (exact zeros off it)."""
    out = np.ones(w.shape[0], np.bool_)
    for f in range(w.shape[0]):
        for i in range(w.shape[1]):
            for m in range(w.shape[2]):
                if m != i and w[f, i, m] != 0.0:
                    out[f] = False
    return out


@kernel
def _normal_sums(rt, xw, rc, pc, z, obj, w, diagonal, a, h, e, wh, we, info, grad):
    """The window's sums of :func:`_normal_equations` into ``info`` (upper triangle) and
    ``grad`` (zeroed by the caller), with its scratch arrays; returns ``(cost, ok)``. Without
    reference counting (:mod:`tdacm._jit`): the frames' rows are views, two a frame."""
    cost = 0.0
    shared = w.shape[0] != rc.shape[0]  # one weight for every frame (w: 1 x 8 x 8)
    for f in range(rc.shape[0]):
        if not _frame_residuals(rc[f], pc[f], rt, xw, obj, z[f], a, h, e):
            return cost, False
        fw = 0 if shared else f
        wf = w[fw]
        if diagonal[fw]:  # the weight of a frame with an exact camera pose
            # the same sums without the exact zeros of the full products (8x fewer flops)
            for i in range(8):
                acc = wf[i, i] * e[i]
                we[i] = acc
                cost += e[i] * acc
                for c in range(6):
                    wh[i, c] = wf[i, i] * h[i, c]
        else:
            for i in range(8):
                acc = 0.0
                for m in range(8):
                    acc += wf[i, m] * e[m]
                we[i] = acc
                cost += e[i] * acc
                for c in range(6):
                    acc = 0.0
                    for m in range(8):
                        acc += wf[i, m] * h[m, c]
                    wh[i, c] = acc
        for c in range(6):
            acc = 0.0
            for i in range(8):
                acc += h[i, c] * we[i]
            grad[c] += acc
            for d in range(c, 6):
                acc = 0.0
                for i in range(8):
                    acc += h[i, c] * wh[i, d]
                info[c, d] += acc
    return cost, True


@njit(cache=True)
def _normal_equations(rt, pt, rc, pc, z, obj, w, diagonal):
    """Gauss-Newton normal equations of the window: information ``sum h_j^T W_j h_j`` (6x6),
    gradient ``sum h_j^T W_j e_j`` and cost ``sum e_j^T W_j e_j`` over the frames ``j``, with
    ``W_j = w[j]`` (8 x 8: the inverse of the frame's measurement covariance, diagonal for an
    exact camera pose; ``diagonal[j]`` tells, :func:`_diagonal_flags`, computed once per
    frame; ``w`` and ``diagonal`` of one entry when every frame has that weight). Allocation-free per frame (measured: 5.7x faster than the
    matrix-product form, same sums to 1e-16); ``ok`` is False if a point is behind a
    camera."""
    info = np.zeros((6, 6))
    grad = np.zeros(6)
    xw = _target_points(rt, pt, obj)
    a = np.empty((3, 3))
    h = np.empty((8, 6))
    e = np.empty(8)
    wh = np.empty((8, 6))
    we = np.empty(8)
    cost, ok = _normal_sums(rt, xw, rc, pc, z, obj, w, diagonal, a, h, e, wh, we, info, grad)
    if not ok:
        return info, grad, cost, False
    for c in range(6):
        for d in range(c):
            info[c, d] = info[d, c]
    return info, grad, cost, True


@njit(cache=True)
def _level_prior_into(rt, normal, weight, info, grad):
    """Add the level prior (module docstring) at ``R_T`` to ``info`` (6 x 6) and ``grad``
    (6): residual ``e = -m[:2]``, ``m = R_T^T n``, Jacobian ``h = [m^]_{0:2}`` on the
    rotation; returns its cost ``weight |e|^2``."""
    m0 = rt[0, 0] * normal[0] + rt[1, 0] * normal[1] + rt[2, 0] * normal[2]
    m1 = rt[0, 1] * normal[0] + rt[1, 1] * normal[1] + rt[2, 1] * normal[2]
    m2 = rt[0, 2] * normal[0] + rt[1, 2] * normal[1] + rt[2, 2] * normal[2]
    h0 = (0.0, -m2, m1)  # first two rows of skew(m)
    h1 = (m2, 0.0, -m0)
    e0, e1 = -m0, -m1
    for i in range(3):
        grad[i] += weight * (h0[i] * e0 + h1[i] * e1)
        for j in range(3):
            info[i, j] += weight * (h0[i] * h0[j] + h1[i] * h1[j])
    return weight * (e0 * e0 + e1 * e1)


@njit(cache=True)
def _gauss_newton_kernel(pose, rc, pc, z, obj, w, diagonal, iterations, normal, prior_weight):
    """``iterations`` Gauss-Newton steps ``g_T <- g_T exp(dx^)``, ``info dx = grad``, on the
    frames ``rc, pc, z`` with weights ``w`` (``diagonal``: :func:`_normal_equations`) and
    the level prior (``prior_weight > 0``), then the normal equations at the result.

    Returns ``(pose, info, cost, prior_info, prior_grad, prior_cost, ok)``: the prior's terms
    at the result, included in ``info`` and ``cost``; ``ok`` is False if a point falls behind
    a camera. A singular step system ends the iterations at the current pose."""
    prior_info = np.zeros((6, 6))
    prior_grad = np.zeros(6)
    for it in range(iterations + 1):
        rt = np.ascontiguousarray(pose[:3, :3])
        pt = pose[:3, 3].copy()
        info, g, cost, ok = _normal_equations(rt, pt, rc, pc, z, obj, w, diagonal)
        if not ok:
            return pose, info, cost, prior_info, prior_grad, 0.0, False
        prior_cost = 0.0
        if prior_weight > 0.0:
            prior_info[:, :] = 0.0
            prior_grad[:] = 0.0
            prior_cost = _level_prior_into(rt, normal, prior_weight, prior_info, prior_grad)
            info += prior_info
            g += prior_grad
            cost += prior_cost
        if it == iterations:
            return pose, info, cost, prior_info, prior_grad, prior_cost, True
        dx, solved = solve_small(info, g)
        if not solved:
            return pose, info, cost, prior_info, prior_grad, prior_cost, True
        pose = np.dot(pose, expmap(dx))
    # not reached (every pass returns at it == iterations); numba types the function's end
    return pose, prior_info, 0.0, prior_info, prior_grad, 0.0, False


# ----------------------------------------------------------------------------- geometry
@njit(cache=True)
def _rigid_between(a, b, out):
    """``out = a^-1 b`` for rigid 4x4 ``a``."""
    for i in range(3):
        for j in range(4):
            acc = a[0, i] * b[0, j] + a[1, i] * b[1, j] + a[2, i] * b[2, j]
            if j == 3:
                acc -= a[0, i] * a[0, 3] + a[1, i] * a[1, 3] + a[2, i] * a[2, 3]
            out[i, j] = acc
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@njit(cache=True)
def camera_points_into(obj, camera_pose, target_pose, r):
    """Camera coordinates ``r = g_C^-1 g_T X_k`` (k, 3) of the target's points ``obj`` (k, 3)
    at ``target_pose`` ``g_T`` seen from ``camera_pose`` ``g_C`` (both rigid 4x4, world)."""
    g = np.empty((4, 4))
    _rigid_between(camera_pose, target_pose, g)
    for k in range(obj.shape[0]):
        for i in range(3):
            r[k, i] = g[i, 0] * obj[k, 0] + g[i, 1] * obj[k, 1] + g[i, 2] * obj[k, 2] + g[i, 3]


@njit(cache=True)
def points_in_kernel(obj, camera_pose, target_pose, xy, z):
    """:meth:`TargetFilter.points_in`: normalized points ``xy`` (k, 2) and depths ``z`` (k,)
    of the target's points ``obj`` (k, 3) at ``target_pose`` seen from ``camera_pose``
    (:func:`camera_points_into`)."""
    r = np.empty((obj.shape[0], 3))
    camera_points_into(obj, camera_pose, target_pose, r)
    for k in range(obj.shape[0]):
        xy[k, 0] = r[k, 0] / r[k, 2]
        xy[k, 1] = r[k, 1] / r[k, 2]
        z[k] = r[k, 2]


@njit(cache=True)
def pnp_kernel(obj, obj2d, canon_inv, xy, g_c, out):
    """Planar PnP of one view: both IPPE poses (:func:`~.ippe.ippe_poses` on the canonical
    points ``obj2d``; ``canon_inv`` the target-to-canonical transform) that put every point
    ``obj`` (4, 3) in front, composed with ``g_c``, into ``out`` (2, 4, 4), the better first.
    Returns how many."""
    rots = np.empty((2, 3, 3))
    trans = np.empty((2, 3))
    errors = np.empty(2)
    if not ippe_poses(obj2d, xy, rots, trans, errors):
        return 0
    g = np.eye(4)
    gt = np.empty((4, 4))
    cnt = 0
    for s in range(2):
        for i in range(3):
            for j in range(3):
                g[i, j] = rots[s, i, j]
            g[i, 3] = trans[s, i]
        gt[:, :] = np.dot(g, canon_inv)
        front = True
        for k in range(obj.shape[0]):
            zk = gt[2, 0] * obj[k, 0] + gt[2, 1] * obj[k, 1] + gt[2, 2] * obj[k, 2] + gt[2, 3]
            if not zk > 0.0:
                front = False
        if front:
            out[cnt] = np.dot(g_c, gt)
            cnt += 1
    return cnt


@njit(cache=True)
def pose_noise(points_camera, camera_cov):
    """Covariance (8 x 8, normalized coordinates, rows ``x_1, y_1, ..., y_4``) that an
    uncertain camera pose adds to a frame: ``G Sigma_c G^T`` with ``Sigma_c`` the 6 x 6
    covariance ``camera_cov`` of the camera-pose error ``g_C <- g_C exp(eps^)``, ``eps = [w;
    v]`` in the camera frame, and ``G = dpi/dr [r^, -I]`` (``r' = exp(-w^)(r - v)``) at the
    points' camera coordinates ``points_camera`` (4, 3).

    Why: with an estimated state (docs/estimation.md) the camera pose of every frame is off
    by the estimator's error. Its effect on the image is nearly common to the four points (a
    camera rotation shifts them all), so the filter must not read it as information on the
    target - unweighted, a 2-5 mrad attitude error (1-3 px) was absorbed along the weakly
    observed tilt, which ended 10-16 deg off and made the servo chase it (measured,
    paper-in-fov, 1 px, estimated state)."""
    g = np.zeros((8, 6))
    dpi = np.empty((2, 3))
    sk = np.empty((3, 3))
    for k in range(4):
        x, y, zk = points_camera[k, 0], points_camera[k, 1], points_camera[k, 2]
        dpi[0, 0], dpi[0, 1], dpi[0, 2] = 1.0 / zk, 0.0, -x / zk**2
        dpi[1, 0], dpi[1, 1], dpi[1, 2] = 0.0, 1.0 / zk, -y / zk**2
        sk[0, 0], sk[0, 1], sk[0, 2] = 0.0, -zk, y  # r^
        sk[1, 0], sk[1, 1], sk[1, 2] = zk, 0.0, -x
        sk[2, 0], sk[2, 1], sk[2, 2] = -y, x, 0.0
        for i in range(2):
            for j in range(3):
                g[2 * k + i, j] = dpi[i, 0] * sk[0, j] + dpi[i, 1] * sk[1, j] + dpi[i, 2] * sk[2, j]
                g[2 * k + i, 3 + j] = -dpi[i, j]
    return np.dot(np.dot(g, camera_cov), g.T)


# ----------------------------------------------------------------------------- the step
@njit(cache=True)
def filter_reset(s):
    """Forget the estimate, the hypotheses and the window's frames, and zero the counters."""
    s.initialized[0] = False
    s.updates[0] = 0
    s.rejected[0] = 0
    s.switches[0] = 0
    s.sigma_hat[0] = 0.0
    s.bad[0] = 0
    s.n_hyp[0] = 0
    s.count[0] = 0
    s.slot[0] = 0


@njit(cache=True)
def _restart(s):
    """:func:`filter_reset`, the count of rejected frames kept (the filter restarts)."""
    rejected = s.rejected[0]
    filter_reset(s)
    s.rejected[0] = rejected


@njit(cache=True)
def filter_sigma(pixel_sigma, sigma_hat):
    """Corner noise (px) of the gate and the covariance: the assumed ``pixel_sigma``, or the
    window's RMS residual ``sigma_hat`` if larger (self-calibrating: a camera noisier than
    assumed would otherwise see its frames gated out)."""
    return max(pixel_sigma, sigma_hat)


@njit(cache=True)
def _pixel_information(p):
    """``(1 / sigma_x^2, 1 / sigma_y^2)``: the information of one normalized coordinate at
    ``pixel_sigma`` px of corner noise (``sigma_x = pixel_sigma / fx``)."""
    fx, fy = p.fx / p.pixel_sigma, p.fy / p.pixel_sigma
    return fx * fx, fy * fy


@njit(cache=True)
def _is_exact(camera_cov):
    """Whether the camera-pose covariance is all zeros: an exact pose."""
    for i in range(camera_cov.shape[0]):
        for j in range(camera_cov.shape[1]):
            if camera_cov[i, j] != 0.0:
                return False
    return True


@njit(cache=True)
def _camera_noise(p, target_pose, g_c, camera_cov, exact):
    """:func:`pose_noise` (8 x 8) of a frame taken at ``g_c`` of the target at
    ``target_pose``; zeros for an exact pose."""
    if exact:
        return np.zeros((8, 8))
    r = np.empty((4, 3))
    camera_points_into(p.object_points, g_c, target_pose, r)
    return pose_noise(r, camera_cov)


@njit(cache=True)
def _weight_into(p, extra, exact, out):
    """The frame's weight ``R_j^-1`` (8 x 8) into ``out``: ``R_j = R + extra``, ``extra``
    its camera-pose noise (:func:`_camera_noise`); diagonal (``R^-1``) for an exact pose."""
    ix, iy = _pixel_information(p)
    if exact:
        out[:, :] = 0.0
        for k in range(4):
            out[2 * k, 2 * k] = ix
            out[2 * k + 1, 2 * k + 1] = iy
        return
    r = extra.copy()
    for k in range(4):
        r[2 * k, 2 * k] += 1.0 / ix
        r[2 * k + 1, 2 * k + 1] += 1.0 / iy
    w = np.linalg.inv(r)
    out[:, :] = 0.5 * (w + w.T)


@njit(cache=True)
def frame_weight(p, target_pose, g_c, camera_cov, out):
    """The weight (8 x 8, inverse covariance) into ``out`` of a frame taken from ``g_c``
    with the camera-pose covariance ``camera_cov`` (6 x 6, zeros: exact) of the target at
    ``target_pose`` (module docstring, "uncertain camera poses")."""
    exact = _is_exact(camera_cov)
    _weight_into(p, _camera_noise(p, target_pose, g_c, camera_cov, exact), exact, out)


@njit(cache=True)
def _covariance_into(p, s, info, p_info, out):
    """``P`` into ``out`` from the total information ``info`` of a solve and its level-prior
    part ``p_info``: the frames' part scaled by the self-calibrated noise
    (``(pixel_sigma / sigma)^2``, :func:`filter_sigma`), the prior's not."""
    ps = p.pixel_sigma
    sigma = filter_sigma(ps, s.sigma_hat[0])
    if p.prior_weight <= 0.0:
        c = np.linalg.inv(info)
        c = 0.5 * (c + c.T)
        out[:, :] = c * (sigma / ps) ** 2
        return
    k = (ps / sigma) ** 2
    c = np.linalg.inv((info - p_info) * k + p_info)
    out[:, :] = 0.5 * (c + c.T)


@njit(cache=True)
def _append(p, s, g_c, xy, extra, exact):
    """Store a frame in the window (overwriting the oldest once it is full) with its weight
    (:func:`_weight_into`)."""
    k = s.slot[0]
    for i in range(3):
        for j in range(3):
            s.rc[k, i, j] = g_c[j, i]
        s.pc[k, i] = g_c[i, 3]
    for i in range(4):
        s.z[k, i, 0] = xy[i, 0]
        s.z[k, i, 1] = xy[i, 1]
    _weight_into(p, extra, exact, s.w[k])
    s.diagonal[k] = _diagonal_flags(s.w[k : k + 1])[0]
    n = s.rc.shape[0]
    s.slot[0] = (k + 1) % n
    s.count[0] = min(s.count[0] + 1, n)


@njit(cache=True)
def _solve_window(p, s, start, iterations):
    """:func:`_gauss_newton_kernel` from ``start`` on the window's frames with the filter's
    level prior."""
    n = s.count[0]
    return _gauss_newton_kernel(
        np.ascontiguousarray(start), s.rc[:n], s.pc[:n], s.z[:n], p.object_points, s.w[:n],
        s.diagonal[:n], iterations, p.level_normal, p.prior_weight,
    )  # fmt: skip


@njit(cache=True)
def _refine(p, s):
    """Gauss-Newton on the window from each hypothesis (or the estimate): the lower-cost
    result becomes the estimate, with ``sigma_hat`` and ``P``; the other PnP branch is kept
    while young (module docstring). Returns ``(ok, cost)``, the cost of the window (prior
    included) at the estimate; not ``ok`` (and the filter restarted) if every solve put a
    point behind a camera."""
    n = s.count[0]
    nh = s.n_hyp[0]
    n_it = max(p.iterations, 3) if s.updates[0] < 3 else p.iterations
    r_pose = np.empty((2, 4, 4))
    r_info = np.empty((2, 6, 6))
    r_pinfo = np.empty((2, 6, 6))
    r_cost = np.empty(2)
    r_pcost = np.empty(2)
    cnt = 0
    for c in range(max(nh, 1)):
        start = s.hyp[c] if nh > 0 else s.pose
        pose, info, cost, p_info, _, p_cost, ok = _solve_window(p, s, start, n_it)
        if ok:
            r_pose[cnt] = pose
            r_info[cnt] = info
            r_pinfo[cnt] = p_info
            r_cost[cnt] = cost
            r_pcost[cnt] = p_cost
            cnt += 1
    if cnt == 0:
        _restart(s)
        return False, np.inf
    b, o = 0, 1
    if cnt == 2 and r_cost[1] < r_cost[0]:  # the better first (a stable sort by cost)
        b, o = 1, 0
    if nh > 1:  # young: keep the other branch until the data decide
        # a log-likelihood margin of `decisive` (cost difference), `young` frames at most,
        # or the branches merged
        merged, done = True, True
        if cnt == 2:
            d = np.empty((4, 4))
            _rigid_between(r_pose[b], r_pose[o], d)
            acc = 0.0
            for i in range(4):
                for j in range(4):
                    e = d[i, j] - (1.0 if i == j else 0.0)
                    acc += e * e
            merged = np.sqrt(acc) < 1e-4
            done = r_cost[o] - r_cost[b] > p.decisive
        if merged or done or s.updates[0] + 1 >= p.young:
            s.n_hyp[0] = 0
        else:
            s.hyp[0] = r_pose[b]
            s.hyp[1] = r_pose[o]
            s.n_hyp[0] = 2
    s.pose[:, :] = r_pose[b]
    s.initialized[0] = True
    s.updates[0] += 1
    if n >= 10:  # cost / dof = (sigma_true / pixel_sigma)^2, the frames' cost only
        cost = r_cost[b] - (r_pcost[b] if p.prior_weight > 0.0 else 0.0)
        s.sigma_hat[0] = p.pixel_sigma * np.sqrt(max(cost, 0.0) / (8 * n - 6))
    _covariance_into(p, s, r_info[b], r_pinfo[b], s.cov)
    return True, r_cost[b]


@njit(cache=True)
def _start(p, s, xy, g_c, camera_cov, exact):
    """The first frame (or the first after a restart): both PnP hypotheses, the frame
    weighted at the better one, refined."""
    cnt = pnp_kernel(p.object_points, p.object_2d, p.canon_inv, xy, g_c, s.hyp)
    if cnt == 0:
        return False
    _append(p, s, g_c, xy, _camera_noise(p, s.hyp[0], g_c, camera_cov, exact), exact)
    s.n_hyp[0] = cnt
    ok, _ = _refine(p, s)
    return ok


@njit(cache=True)
def _reject(p, s, xy, g_c, camera_cov, exact):
    """A frame gated out: after ``reset_after`` in a row the estimate is taken as wrong and
    the filter restarts from this frame."""
    s.rejected[0] += 1
    s.bad[0] += 1
    if s.bad[0] >= p.reset_after:
        _restart(s)
        return _start(p, s, xy, g_c, camera_cov, exact)
    return False


@njit(cache=True)
def _rescue(p, s, xy, g_c, cost):
    """Escape the wrong branch of the planar ambiguity: refine both PnP solutions of the
    latest frame on the whole window and adopt one whose cost is lower than ``cost`` (the
    window's at the estimate) by more than 1."""
    cand = np.empty((2, 4, 4))
    for c in range(pnp_kernel(p.object_points, p.object_2d, p.canon_inv, xy, g_c, cand)):
        pose, info, c_cost, p_info, _, _, ok = _solve_window(p, s, cand[c], np.int64(4))
        if ok and c_cost < cost - 1.0:
            cost = c_cost
            s.pose[:, :] = pose
            _covariance_into(p, s, info, p_info, s.cov)
            s.switches[0] += 1


@njit(cache=True)
def filter_fuse(p, s, xy, g_c, camera_cov):
    """:func:`filter_update` of the normalized points ``xy`` (4, 2) of a frame."""
    exact = _is_exact(camera_cov)
    if not s.initialized[0]:
        return _start(p, s, xy, g_c, camera_cov, exact)
    obj = p.object_points
    rt = np.ascontiguousarray(s.pose[:3, :3])
    xw = _target_points(rt, s.pose[:3, 3].copy(), obj)
    h8 = np.empty((8, 6))
    nu = np.empty(8)
    rcf = np.ascontiguousarray(g_c[:3, :3].T)
    if not _frame_residuals(rcf, g_c[:3, 3].copy(), rt, xw, obj, xy, np.empty((3, 3)), h8, nu):
        return _reject(p, s, xy, g_c, camera_cov, exact)
    # the gate: nu^T (H P H^T + sigma-scaled R + camera-pose noise)^-1 nu
    ps = p.pixel_sigma
    scale = (filter_sigma(ps, s.sigma_hat[0]) / ps) ** 2
    ix, iy = _pixel_information(p)
    extra = _camera_noise(p, s.pose, g_c, camera_cov, exact)
    sm = np.dot(np.dot(h8, s.cov), h8.T)
    for k in range(4):
        sm[2 * k, 2 * k] += scale * (1.0 / ix)
        sm[2 * k + 1, 2 * k + 1] += scale * (1.0 / iy)
    if not exact:
        sm += extra
    if np.dot(nu, np.linalg.solve(sm, nu)) > p.gate:
        return _reject(p, s, xy, g_c, camera_cov, exact)
    s.bad[0] = 0
    _append(p, s, g_c, xy, extra, exact)
    ok, cost = _refine(p, s)
    if ok and p.recheck > 0 and s.updates[0] % p.recheck == 0:
        # the window's cost at the estimate is the refined one (the same frames and pose)
        _rescue(p, s, xy, g_c, cost)
    return ok


@njit(cache=True)
def filter_update(p, s, pixels, g_c, camera_cov):
    """One frame of the filter (module docstring), its compiled step: the detection
    ``pixels`` (4, 2) (paper order, an undistorted camera) captured from the camera pose
    ``g_c`` (4x4, world, at the capture time) with that pose's error covariance
    ``camera_cov`` (6 x 6, ``[w; v]`` in the camera frame; all zeros: an exact pose) fused
    into the state ``s`` (a :class:`TargetFilterState`, in place) of the filter ``p`` (a
    :class:`TargetFilterParams`). Returns whether the frame was fused (False: gated out,
    or unusable)."""
    xy = np.empty((4, 2))
    for k in range(4):
        xy[k, 0] = (pixels[k, 0] - p.cx) / p.fx
        xy[k, 1] = (pixels[k, 1] - p.cy) / p.fy
    return filter_fuse(p, s, xy, g_c, camera_cov)


# ----------------------------------------------------------------------------- the block
class TargetFilter:
    """Sliding-window maximum-likelihood estimate of a static target's world pose (module
    docstring): the Python block around :func:`filter_update`. It validates its arguments
    once into :attr:`params` (a :class:`TargetFilterParams`) and keeps its state in
    :attr:`state` (a :class:`TargetFilterState`); what it reports is read from the state.

    Parameters
    ----------
    camera:
        The camera whose pixels are measured (for normalization and the noise scale).
    object_points:
        The target's feature points ``(4, 3)`` in its own frame (paper order, planar).
    pixel_sigma:
        Standard deviation of the corner noise (px) assumed by the filter (> 0).
    window:
        Number of accepted frames kept (>= 1).
    iterations:
        Gauss-Newton steps per accepted frame.
    gate:
        Mahalanobis gate on the 8-dimensional innovation (default: chi-square p = 0.9999).
    young, decisive:
        Both PnP hypotheses are refined until their costs differ by ``decisive`` (twice the
        log-likelihood ratio) or for ``young`` frames at most.
    reset_after:
        Consecutive rejected frames after which the filter re-initializes.
    recheck:
        Every ``recheck`` fused frames, both PnP solutions of the latest frame are refined
        on the window and adopted if their cost is lower (escapes the wrong branch of the
        ambiguity once the camera has moved enough to tell them apart; 0 disables).
    level_prior:
        Standard deviation (rad) of the prior that the target's z axis is along
        ``level_normal`` (world), i.e. that it lies on a level surface (module docstring);
        0 disables it (a scenario's ``[ibvs] target_level_prior_deg``).
    level_normal:
        The nominal direction of the target's z axis in the world (default ``[0, 0, -1]``:
        the target faces up, its z axis into the surface).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        object_points,
        pixel_sigma: float = 1.0,
        *,
        level_prior: float,
        window: int = 250,
        iterations: int = 2,
        gate: float = GATE_CHI2_8,
        young: int = 100,
        decisive: float = 25.0,
        reset_after: int = 5,
        recheck: int = 10,
        level_normal=(0.0, 0.0, -1.0),
    ):
        self.camera = camera
        self.level_prior = C.nonnegative("level_prior", level_prior)
        obj = C.array("object_points", object_points, (4, 3))
        try:
            obj2d, canon = canonical_frame(obj)
        except ValueError:
            raise ValueError("object_points: the target's points are not planar") from None
        window = C.positive_int("window", window)
        self.params = TargetFilterParams(
            pixel_sigma=C.positive("pixel_sigma", pixel_sigma),
            window=window,
            iterations=C.positive_int("iterations", iterations),
            gate=C.positive("gate", gate),
            young=int(young),
            decisive=C.positive("decisive", decisive),
            reset_after=C.positive_int("reset_after", reset_after),
            recheck=int(recheck),
            prior_weight=1.0 / self.level_prior**2 if self.level_prior > 0.0 else 0.0,
            fx=0.0, fy=0.0, cx=0.0, cy=0.0,
            object_points=np.ascontiguousarray(obj),
            object_2d=np.ascontiguousarray(obj2d),
            canon_inv=np.ascontiguousarray(np.linalg.inv(canon)),
            level_normal=np.ascontiguousarray(C.unit_vector("level_normal", level_normal)),
        ).with_camera(camera)  # fmt: skip
        self.state = TargetFilterState.initial(window)
        self._exact = np.zeros((6, 6))  # the camera-pose covariance of an exact pose

    # ------------------------------------------------------------------ constants
    @property
    def pixel_sigma(self) -> float:
        return self.params.pixel_sigma

    @property
    def window(self) -> int:
        return self.params.window

    @property
    def iterations(self) -> int:
        return self.params.iterations

    @property
    def gate(self) -> float:
        return self.params.gate

    @property
    def young(self) -> int:
        return self.params.young

    @property
    def decisive(self) -> float:
        return self.params.decisive

    @property
    def reset_after(self) -> int:
        return self.params.reset_after

    @property
    def recheck(self) -> int:
        return self.params.recheck

    @property
    def object_points(self) -> np.ndarray:
        return self.params.object_points

    @property
    def level_normal(self) -> np.ndarray:
        return self.params.level_normal

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the estimate and the stored frames (:func:`filter_reset`)."""
        filter_reset(self.state)

    @property
    def initialized(self) -> bool:
        return bool(self.state.initialized[0])

    @property
    def pose(self) -> np.ndarray | None:
        """The estimate ``g_T`` (4x4, world; a copy), ``None`` before the first frame."""
        return self.state.pose.copy() if self.state.initialized[0] else None

    @pose.setter
    def pose(self, value) -> None:
        """Correct the estimate (its covariance and the window stay)."""
        if not self.state.initialized[0]:
            raise ValueError("pose: the filter has no estimate to correct yet")
        self.state.pose[:, :] = C.transform("pose", value)

    @property
    def P(self) -> np.ndarray | None:
        """Covariance (6x6, ``[w; v]`` in the target frame; a copy) of the estimate."""
        return self.state.cov.copy() if self.state.initialized[0] else None

    @property
    def updates(self) -> int:
        """Frames fused since the filter last (re)started."""
        return int(self.state.updates[0])

    @property
    def rejected(self) -> int:
        """Frames gated out since the last :meth:`reset`."""
        return int(self.state.rejected[0])

    @property
    def switches(self) -> int:
        """Rescues of the other branch of the planar ambiguity adopted."""
        return int(self.state.switches[0])

    @property
    def sigma_hat(self) -> float:
        """RMS residual of the window (px), once it holds 10 frames (0 before)."""
        return float(self.state.sigma_hat[0])

    @property
    def sigma(self) -> float:
        """Corner noise (px) used by the gate and the covariance (:func:`filter_sigma`)."""
        return float(filter_sigma(self.params.pixel_sigma, float(self.state.sigma_hat[0])))

    @property
    def estimate(self) -> TargetEstimate | None:
        if not self.initialized:
            return None
        return TargetEstimate(self.pose, self.P, self.updates, self.rejected)

    def predict(self, dt: float) -> None:
        """Nothing to propagate: the target is static (the window does the forgetting)."""

    # ------------------------------------------------------------------ model
    def pose_noise(self, points_camera, camera_cov) -> np.ndarray:
        """:func:`pose_noise`: the covariance (8 x 8) that a camera pose uncertain by
        ``camera_cov`` (6 x 6) adds to a frame whose points are at ``points_camera`` (4, 3,
        camera coordinates)."""
        r = C.array("points_camera", points_camera, (4, 3))
        return pose_noise(r, C.array("camera_cov", camera_cov, (6, 6)))

    def information(
        self, target_pose, camera_poses, camera_covs=None, with_prior: bool = False
    ) -> np.ndarray:
        """Fisher information (6 x 6, ``[w; v]`` in the target frame) on ``g_T`` of one frame
        from each of ``camera_poses`` (4x4, world) with this filter's pixel noise (and the
        optional camera-pose covariances, :func:`frame_weight`): ``sum_j H_j^T R_j^-1 H_j`` at
        ``target_pose``. Its inverse is the Cramer-Rao bound of any unbiased estimate from
        those frames (the filter's ``P`` reaches it once the window has converged); used to
        tell what a camera trajectory can reveal about the target (docs/campaigns.md)."""
        g_t = C.transform("target_pose", target_pose)
        poses = [C.transform("camera_poses", g) for g in camera_poses]
        covs = [None] * len(poses) if camera_covs is None else list(camera_covs)
        if len(covs) != len(poses):
            raise ValueError("camera_covs must have one entry per camera pose")
        n = len(poses)
        rc = np.array([g[:3, :3].T for g in poses]).reshape(n, 3, 3)
        pc = np.array([g[:3, 3] for g in poses]).reshape(n, 3)
        z = np.empty((n, 4, 2))
        w = np.empty((n, 8, 8))
        for j, (g, c) in enumerate(zip(poses, covs, strict=True)):
            z[j] = self.points_in(g, g_t)[0]  # noise-free measurements: the residuals vanish
            cov = self._exact if c is None else C.array("camera_covs", c, (6, 6))
            frame_weight(self.params, g_t, g, cov, w[j])
        rt = np.ascontiguousarray(g_t[:3, :3])
        info, _, _, ok = _normal_equations(
            rt, g_t[:3, 3].copy(), rc, pc, z, self.object_points, w, _diagonal_flags(w)
        )
        if not ok:
            raise ValueError("a target point is behind one of the cameras")
        prior = self._prior_terms(g_t) if with_prior else None
        return info if prior is None else info + prior[0]

    def _prior_terms(self, pose):
        """``(information, gradient, cost)`` of the level prior at the target pose ``pose``
        (module docstring), or ``None`` without a prior."""
        if self.params.prior_weight <= 0.0:
            return None
        info, grad = np.zeros((6, 6)), np.zeros(6)
        rt = np.ascontiguousarray(np.asarray(pose, float)[:3, :3])
        cost = _level_prior_into(rt, self.level_normal, self.params.prior_weight, info, grad)
        return info, grad, cost

    def points_in(self, camera_pose, target_pose=None):
        """Predicted normalized points ``(4, 2)`` and depths ``(4,)`` of the target at
        ``target_pose`` (default: the estimate) in a camera at ``camera_pose`` (4x4, world;
        :func:`points_in_kernel`); ``None`` before the first frame."""
        if target_pose is None:
            if not self.state.initialized[0]:
                return None
            target_pose = self.state.pose
        xy, z = np.empty((4, 2)), np.empty(4)
        points_in_kernel(
            self.params.object_points, np.ascontiguousarray(camera_pose, float),
            np.ascontiguousarray(target_pose, float), xy, z,
        )  # fmt: skip
        return xy, z

    # ------------------------------------------------------------------ filter
    def update(self, pixels, camera_pose, camera_cov=None) -> bool:
        """Fuse one detection: ``pixels`` ``(4, 2)`` (paper order) captured with the camera
        at ``camera_pose`` (4x4, world, *at the capture time*). ``camera_cov`` (6 x 6,
        optional) is the covariance of that pose's error (:func:`pose_noise`; from the
        state estimator); ``None`` (or zeros) means the pose is exact. Returns True if fused,
        False if the frame was gated out (or unusable)."""
        pixels = C.array("pixels", pixels, (4, 2))
        g_c = C.transform("camera_pose", camera_pose)
        if camera_cov is not None:
            camera_cov = C.array("camera_cov", camera_cov, (6, 6))
        return self.update_checked(pixels, g_c, camera_cov)

    def update_checked(self, pixels, g_c, camera_cov=None) -> bool:
        """:meth:`update` of checked inputs: float ``(4, 2)`` pixels, a rigid 4x4 pose and
        a float ``(6, 6)`` covariance or ``None`` (the servo's per-period call: its inputs
        come from the perception block and the model): :func:`filter_update` (the pixels
        normalized first for a camera with lens distortion, :func:`filter_fuse`)."""
        g_c = np.ascontiguousarray(g_c, float)
        cov = self._exact if camera_cov is None else np.ascontiguousarray(camera_cov, float)
        if self.camera.has_distortion:
            xy = np.ascontiguousarray(self.camera.normalize_checked(pixels), float)
            return bool(filter_fuse(self.params, self.state, xy, g_c, cov))
        pixels = np.ascontiguousarray(pixels, float)
        return bool(filter_update(self.params, self.state, pixels, g_c, cov))
