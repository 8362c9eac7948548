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
* initialization: both solutions of planar PnP (``cv2.solvePnPGeneric(...,
  SOLVEPNP_IPPE)``, the classic two-fold ambiguity of a small planar target) are kept as
  hypotheses and refined on the same frames until their costs differ by ``decisive`` (or
  for ``young`` frames); the estimate is always the lower-cost one; every ``recheck`` frames
  both PnP solutions of the latest frame are refined on the window again and adopted if
  their cost is lower (measured: a run of paper-out-of-fov at 1 px otherwise stayed 18
  degrees off on the wrong branch after the target entered at the image border);
* noise level: the gate and ``P`` use ``max(pixel_sigma, sigma_hat)`` with ``sigma_hat`` the
  RMS residual of the window (measured: with 2 px of noise and 1 px assumed, half of the
  frames were gated out and the resets made the prediction jump);
* uncertain camera poses (the loop on a state estimate, docs/estimation.md): a frame may come
  with the covariance ``Sigma_c`` of its camera pose; its measurement covariance is then
  ``R_j = R + G_j Sigma_c G_j^T`` (``G_j = dz_j / d eps``, ``g_C <- g_C exp(eps^)``,
  :meth:`TargetFilter.pose_noise`), and the frame enters the normal equations, the gate and
  ``sigma_hat`` through its full ``8 x 8`` weight ``R_j^-1`` (``_normal_equations``).
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
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from .._jit import kernel
from .._linalg import solve as _solve
from .._linalg import solve_small
from ..lie.se3 import expmap, skew
from . import _checks as C
from .camera import PinholeCamera
from .ippe import ippe_poses

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


def planar_pnp_poses(object_points, xy, camera_pose) -> list:
    """World poses (4x4) of a planar target from one view: both solutions of planar PnP
    (``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`` on normalized points ``xy``, the two-fold
    ambiguity of a small planar target) that put every point in front of the camera,
    composed with ``camera_pose``."""
    obj = np.asarray(object_points, float)
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        obj, np.asarray(xy, float).reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
    )
    out = []
    for rv, tv in zip(rvecs if ok else (), tvecs if ok else (), strict=True):
        g = np.eye(4)
        g[:3, :3] = cv2.Rodrigues(rv)[0]
        g[:3, 3] = np.ravel(tv)
        if np.all((obj @ g[:3, :3].T + g[:3, 3])[:, 2] > 0):
            out.append(camera_pose @ g)
    return out


def target_in_camera(object_points, camera_pose, target_pose) -> np.ndarray:
    """Camera coordinates ``r = g_C^-1 g_T X_k`` (k, 3) of a target's points ``X_k`` (its
    frame) for world poses ``camera_pose`` ``g_C`` and ``target_pose`` ``g_T`` (4x4)."""
    g = _solve(np.asarray(camera_pose, float), np.asarray(target_pose, float))
    return object_points @ g[:3, :3].T + g[:3, 3]


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


# ----------------------------------------------------------------------------- compiled
# The filter's update as compiled code over one filter's plain arrays (the batched engine,
# :mod:`tdacm.batch.servo`): the same steps as :meth:`TargetFilter.update_checked` for frames
# with an exact camera pose (the engine runs on the true state), the same Gauss-Newton kernels,
# planar PnP by the compiled IPPE (:mod:`tdacm.vision.ippe`, the pose of
# ``cv2.solvePnPGeneric``). Rows of its scalar state ``st``:
F_INIT, F_UPDATES, F_REJECTED, F_SWITCHES, F_SIGMA_HAT, F_BAD, F_NHYP, F_COUNT, F_NEXT, N_FSTATE = (
    range(10)
)
#: rows of its constants ``prm`` (:func:`filter_params`)
(
    FP_PIXEL_SIGMA, FP_ITERATIONS, FP_GATE, FP_YOUNG, FP_DECISIVE, FP_RESET_AFTER, FP_RECHECK,
    FP_PRIOR_WEIGHT, FP_WINDOW, N_FPARAMS,
) = range(10)  # fmt: skip


def filter_params(f: TargetFilter) -> np.ndarray:
    """The constants of a :class:`TargetFilter` as the compiled update's ``prm`` row."""
    prm = np.zeros(N_FPARAMS)
    prm[FP_PIXEL_SIGMA] = f.pixel_sigma
    prm[FP_ITERATIONS] = f.iterations
    prm[FP_GATE] = f.gate
    prm[FP_YOUNG] = f.young
    prm[FP_DECISIVE] = f.decisive
    prm[FP_RESET_AFTER] = f.reset_after
    prm[FP_RECHECK] = f.recheck
    prm[FP_PRIOR_WEIGHT] = 1.0 / f.level_prior**2 if f.level_prior > 0.0 else 0.0
    prm[FP_WINDOW] = f.window  # the length of the window's arrays
    return prm


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
def points_in_kernel(obj, camera_pose, target_pose, xy, z):
    """:meth:`TargetFilter.points_in`: normalized points ``xy`` (4, 2) and depths ``z`` (4,)
    of the target's points ``obj`` (4, 3) at ``target_pose`` seen from ``camera_pose``."""
    g = np.empty((4, 4))
    _rigid_between(camera_pose, target_pose, g)
    for k in range(obj.shape[0]):
        r0 = g[0, 0] * obj[k, 0] + g[0, 1] * obj[k, 1] + g[0, 2] * obj[k, 2] + g[0, 3]
        r1 = g[1, 0] * obj[k, 0] + g[1, 1] * obj[k, 1] + g[1, 2] * obj[k, 2] + g[1, 3]
        r2 = g[2, 0] * obj[k, 0] + g[2, 1] * obj[k, 1] + g[2, 2] * obj[k, 2] + g[2, 3]
        xy[k, 0] = r0 / r2
        xy[k, 1] = r1 / r2
        z[k] = r2


@njit(cache=True)
def pnp_kernel(obj, obj2d, canon_inv, xy, g_c, out):
    """:func:`planar_pnp_poses` compiled: both IPPE poses (:func:`~.ippe.ippe_poses` on the
    canonical points ``obj2d``; ``canon_inv`` the target-to-canonical transform) that put
    every point ``obj`` (4, 3) in front, composed with ``g_c``, into ``out`` (2, 4, 4), the
    better first. Returns how many."""
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
def _filter_reset(st):
    """:meth:`TargetFilter.reset`, the rejected frames kept."""
    rejected = st[F_REJECTED]
    st[:] = 0.0
    st[F_REJECTED] = rejected


@njit(cache=True)
def _filter_covariance(prm, st, info, p_info, out):
    """:meth:`TargetFilter._covariance` into ``out``."""
    ps = prm[FP_PIXEL_SIGMA]
    sigma = max(ps, st[F_SIGMA_HAT])
    if prm[FP_PRIOR_WEIGHT] <= 0.0:
        p = np.linalg.inv(info)
        p = 0.5 * (p + p.T)
        out[:, :] = p * (sigma / ps) ** 2
        return
    k = (ps / sigma) ** 2
    p = np.linalg.inv((info - p_info) * k + p_info)
    out[:, :] = 0.5 * (p + p.T)


@njit(cache=True)
def _filter_append(st, rc, pc, z, g_c, xy):
    """:meth:`TargetFilter._append` into the window's ring buffers."""
    k = int(st[F_NEXT])
    for i in range(3):
        for j in range(3):
            rc[k, i, j] = g_c[j, i]
        pc[k, i] = g_c[i, 3]
    for i in range(4):
        z[k, i, 0] = xy[i, 0]
        z[k, i, 1] = xy[i, 1]
    st[F_NEXT] = (k + 1) % rc.shape[0]
    st[F_COUNT] = min(st[F_COUNT] + 1, rc.shape[0])


@njit(cache=True)
def _filter_refine(prm, st, pose, cov, hyp, rc, pc, z, obj, normal, w, diag):
    """:meth:`TargetFilter._refine`: ``(ok, cost)``, the cost of the window (prior included)
    at the refined ``pose``."""
    n = int(st[F_COUNT])
    nh = int(st[F_NHYP])
    iters = int(prm[FP_ITERATIONS])
    n_it = max(iters, 3) if st[F_UPDATES] < 3 else iters
    pw = prm[FP_PRIOR_WEIGHT]
    r_pose = np.empty((2, 4, 4))
    r_info = np.empty((2, 6, 6))
    r_pinfo = np.empty((2, 6, 6))
    r_cost = np.empty(2)
    r_pcost = np.empty(2)
    cnt = 0
    for c in range(max(nh, 1)):
        start = np.ascontiguousarray(hyp[c]) if nh > 0 else pose.copy()
        p, info, cost, p_info, _, p_cost, ok = _gauss_newton_kernel(
            start, rc[:n], pc[:n], z[:n], obj, w, diag, n_it, normal, pw
        )
        if ok:
            r_pose[cnt] = p
            r_info[cnt] = info
            r_pinfo[cnt] = p_info
            r_cost[cnt] = cost
            r_pcost[cnt] = p_cost
            cnt += 1
    if cnt == 0:
        _filter_reset(st)
        return False, np.inf
    b, o = 0, 1
    if cnt == 2 and r_cost[1] < r_cost[0]:  # the stable sort by cost
        b, o = 1, 0
    if nh > 1:  # young: keep the other branch until the data decide
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
            done = r_cost[o] - r_cost[b] > prm[FP_DECISIVE]
        if merged or done or st[F_UPDATES] + 1 >= prm[FP_YOUNG]:
            st[F_NHYP] = 0
        else:
            hyp[0] = r_pose[b]
            hyp[1] = r_pose[o]
            st[F_NHYP] = 2
    pose[:, :] = r_pose[b]
    st[F_INIT] = 1.0
    st[F_UPDATES] += 1
    if n >= 10:  # cost / dof = (sigma_true / pixel_sigma)^2, the frames' cost only
        cost = r_cost[b] - (r_pcost[b] if pw > 0.0 else 0.0)
        st[F_SIGMA_HAT] = prm[FP_PIXEL_SIGMA] * np.sqrt(max(cost, 0.0) / (8 * n - 6))
    _filter_covariance(prm, st, r_info[b], r_pinfo[b], cov)
    return True, r_cost[b]


@njit(cache=True)
def _filter_start(prm, st, pose, cov, hyp, rc, pc, z, obj, obj2d, canon_inv, normal, w, diag,
                  xy, g_c):  # fmt: skip
    """The first frame (or the first after a restart): both PnP hypotheses, refined."""
    cnt = pnp_kernel(obj, obj2d, canon_inv, xy, g_c, hyp)
    if cnt == 0:
        return False
    _filter_append(st, rc, pc, z, g_c, xy)
    st[F_NHYP] = cnt
    ok, _ = _filter_refine(prm, st, pose, cov, hyp, rc, pc, z, obj, normal, w, diag)
    return ok


@njit(cache=True)
def filter_update(prm, cam, st, pose, cov, hyp, rc, pc, z, obj, obj2d, canon_inv, normal,
                  pixels, g_c):  # fmt: skip
    """:meth:`TargetFilter.update_checked` of a frame with an exact camera pose, compiled:
    the filter's state ``st`` (:data:`F_INIT` ...), estimate ``pose`` (4, 4), covariance
    ``cov`` (6, 6), PnP hypotheses ``hyp`` (2, 4, 4) and window ``rc`` (W, 3, 3), ``pc`` (W,
    3), ``z`` (W, 4, 2) updated in place; ``prm`` its constants (:func:`filter_params`),
    ``cam`` the camera ``[fx, fy, cx, cy]``, ``obj`` (4, 3) the target's points, ``obj2d``
    and ``canon_inv`` their canonical frame (:func:`~.ippe.canonical_frame`), ``normal`` the
    level prior's normal. Returns whether the frame was fused."""
    xy = np.empty((4, 2))
    for k in range(4):
        xy[k, 0] = (pixels[k, 0] - cam[2]) / cam[0]
        xy[k, 1] = (pixels[k, 1] - cam[3]) / cam[1]
    ps = prm[FP_PIXEL_SIGMA]
    fx, fy = cam[0] / ps, cam[1] / ps
    rinv_x, rinv_y = fx * fx, fy * fy
    w = np.zeros((1, 8, 8))  # the weight of a frame with an exact pose
    for k in range(4):
        w[0, 2 * k, 2 * k] = rinv_x
        w[0, 2 * k + 1, 2 * k + 1] = rinv_y
    diag = np.ones(1, np.bool_)
    if st[F_INIT] == 0.0:
        return _filter_start(prm, st, pose, cov, hyp, rc, pc, z, obj, obj2d, canon_inv, normal,
                             w, diag, xy, g_c)  # fmt: skip
    rt = np.ascontiguousarray(pose[:3, :3])
    xw = _target_points(rt, pose[:3, 3].copy(), obj)
    h8 = np.empty((8, 6))
    nu = np.empty(8)
    rcf = np.ascontiguousarray(g_c[:3, :3].T)
    gated = not _frame_residuals(rcf, g_c[:3, 3].copy(), rt, xw, obj, xy, np.empty((3, 3)), h8,
                                 nu)  # fmt: skip
    if not gated:
        scale = (max(ps, st[F_SIGMA_HAT]) / ps) ** 2
        s = np.dot(np.dot(h8, cov), h8.T)
        for k in range(4):
            s[2 * k, 2 * k] += scale * (1.0 / rinv_x)
            s[2 * k + 1, 2 * k + 1] += scale * (1.0 / rinv_y)
        gated = np.dot(nu, np.linalg.solve(s, nu)) > prm[FP_GATE]
    if gated:  # :meth:`TargetFilter._reject`
        st[F_REJECTED] += 1
        st[F_BAD] += 1
        if st[F_BAD] >= prm[FP_RESET_AFTER]:
            _filter_reset(st)
            return _filter_start(prm, st, pose, cov, hyp, rc, pc, z, obj, obj2d, canon_inv,
                                 normal, w, diag, xy, g_c)  # fmt: skip
        return False
    st[F_BAD] = 0.0
    _filter_append(st, rc, pc, z, g_c, xy)
    ok, cur = _filter_refine(prm, st, pose, cov, hyp, rc, pc, z, obj, normal, w, diag)
    recheck = int(prm[FP_RECHECK])
    if ok and recheck > 0 and int(st[F_UPDATES]) % recheck == 0:  # :meth:`TargetFilter._rescue`
        n = int(st[F_COUNT])
        pw = prm[FP_PRIOR_WEIGHT]
        # the cost at the current pose is the refined one (the same window and pose: the
        # same sums), so the rescue starts from it without a pass over the window
        cand = np.empty((2, 4, 4))
        for c in range(pnp_kernel(obj, obj2d, canon_inv, xy, g_c, cand)):
            p, info, cost, p_info, _, _, okc = _gauss_newton_kernel(
                np.ascontiguousarray(cand[c]), rc[:n], pc[:n], z[:n], obj, w, diag, 4,
                normal, pw,
            )  # fmt: skip
            if okc and cost < cur - 1.0:
                cur = cost
                pose[:, :] = p
                _filter_covariance(prm, st, info, p_info, cov)
                st[F_SWITCHES] += 1
    return ok


class TargetFilter:
    """Sliding-window maximum-likelihood estimate of a static target's world pose (module
    docstring).

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
        self.level_normal = C.unit_vector("level_normal", level_normal)
        self.recheck = int(recheck)
        self.decisive = C.positive("decisive", decisive)
        self.object_points = C.array("object_points", object_points, (4, 3))
        self.pixel_sigma = C.positive("pixel_sigma", pixel_sigma)
        self.window = C.positive_int("window", window)
        self.iterations = C.positive_int("iterations", iterations)
        self.gate = C.positive("gate", gate)
        self.young = int(young)
        self.reset_after = C.positive_int("reset_after", reset_after)
        f = np.array([camera.fx, camera.fy]) / self.pixel_sigma
        self._rinv = f * f  # 1 / sigma_normalized^2 for x, y
        self._w_pixel = np.diag(np.tile(self._rinv, 4))  # weight of a frame with an exact pose
        self._r_pixel = np.diag(np.tile(1.0 / self._rinv, 4))  # its covariance
        self.reset()

    def pose_noise(self, points_camera, camera_cov) -> np.ndarray:
        """Covariance (8 x 8, normalized coordinates, rows ``x_1, y_1, ..., y_4``) that an
        uncertain camera pose adds to a frame: ``G Sigma_c G^T`` with ``Sigma_c`` the 6 x 6
        covariance of the camera-pose error ``g_C <- g_C exp(eps^)``, ``eps = [w; v]`` in
        the camera frame, and ``G = dpi/dr [r^, -I]`` (``r' = exp(-w^)(r - v)``) at the
        points' camera coordinates ``points_camera`` (4, 3).

        Why: with an estimated state (docs/estimation.md) the camera pose of every frame is
        off by the estimator's error. Its effect on the image is nearly common to the four
        points (a camera rotation shifts them all), so the filter must not read it as
        information on the target - unweighted, a 2-5 mrad attitude error (1-3 px) was
        absorbed along the weakly observed tilt, which ended 10-16 deg off and made the
        servo chase it (measured, paper-in-fov, 1 px, estimated state)."""
        r = np.asarray(points_camera, float)
        g = np.zeros((8, 6))
        for k in range(4):
            x, y, zk = r[k]
            dpi = np.array([[1.0 / zk, 0.0, -x / zk**2], [0.0, 1.0 / zk, -y / zk**2]])
            g[2 * k : 2 * k + 2, :3] = dpi @ skew(r[k])
            g[2 * k : 2 * k + 2, 3:] = -dpi
        return g @ np.asarray(camera_cov, float) @ g.T

    @property
    def sigma(self) -> float:
        """Corner noise (px) used by the gate and the covariance: the assumed
        ``pixel_sigma``, or the RMS residual of the window if larger (self-calibrating:
        a camera noisier than assumed would otherwise see its frames gated out)."""
        return max(self.pixel_sigma, self.sigma_hat)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the estimate and the stored frames."""
        self.pose = None
        self.P = None
        self.updates = 0
        self.rejected = 0
        self.switches = 0
        self.sigma_hat = 0.0  # RMS residual of the window (px), once >= 10 frames
        self._bad = 0
        self._hyp = []
        # the window as ring buffers (the sums do not depend on the frames' order)
        n = self.window
        self._rc = np.empty((n, 3, 3))  # R_C^T of each frame
        self._pc = np.empty((n, 3))  # p_C of each frame
        self._z = np.empty((n, 4, 2))  # normalized points
        self._w = np.empty((n, 8, 8))  # weight (inverse covariance) of each frame
        self._diag = np.empty(n, np.bool_)  # whether that weight is diagonal
        self._count = 0  # frames in the window
        self._next = 0  # slot of the next frame

    @property
    def initialized(self) -> bool:
        return self.pose is not None

    @property
    def estimate(self) -> TargetEstimate | None:
        if self.pose is None:
            return None
        return TargetEstimate(self.pose.copy(), self.P.copy(), self.updates, self.rejected)

    def predict(self, dt: float) -> None:
        """Nothing to propagate: the target is static (the window does the forgetting)."""

    # ------------------------------------------------------------------ model
    def information(
        self, target_pose, camera_poses, camera_covs=None, with_prior: bool = False
    ) -> np.ndarray:
        """Fisher information (6 x 6, ``[w; v]`` in the target frame) on ``g_T`` of one frame
        from each of ``camera_poses`` (4x4, world) with this filter's pixel noise (and the
        optional camera-pose covariances): ``sum_j H_j^T R_j^-1 H_j`` at ``target_pose``. Its
        inverse is the Cramer-Rao bound of any unbiased estimate from those frames (the
        filter's ``P`` reaches it once the window has converged); used to tell what a camera
        trajectory can reveal about the target (docs/campaigns.md)."""
        g_t = C.transform("target_pose", target_pose)
        poses = [C.transform("camera_poses", g) for g in camera_poses]
        covs = [None] * len(poses) if camera_covs is None else list(camera_covs)
        if len(covs) != len(poses):
            raise ValueError("camera_covs must have one entry per camera pose")
        rc = np.array([g[:3, :3].T for g in poses])
        pc = np.array([g[:3, 3] for g in poses])
        z = np.empty((len(poses), 4, 2))
        for j, g in enumerate(poses):  # noise-free measurements: the residuals vanish
            x = target_in_camera(self.object_points, g, g_t)
            z[j] = x[:, :2] / x[:, 2:3]
        w = np.array([self._frame_weight(g_t, g, c) for g, c in zip(poses, covs, strict=True)])
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
        if self.level_prior <= 0.0:
            return None
        info, grad = np.zeros((6, 6)), np.zeros(6)
        rt = np.ascontiguousarray(pose[:3, :3])
        cost = _level_prior_into(rt, self.level_normal, 1.0 / self.level_prior**2, info, grad)
        return info, grad, cost

    def _covariance(self, info, prior) -> np.ndarray:
        """``P`` from the total information of a solve and its level-prior terms ``prior``
        (:meth:`_prior_terms` at the solution, or ``None``): the frames' part scaled by the
        self-calibrated noise (``(pixel_sigma / sigma)^2``), the prior's not."""
        if prior is None:
            p = np.linalg.inv(info)
            p = 0.5 * (p + p.T)
            return p * (self.sigma / self.pixel_sigma) ** 2
        k = (self.pixel_sigma / self.sigma) ** 2
        p = np.linalg.inv((info - prior[0]) * k + prior[0])
        return 0.5 * (p + p.T)

    def points_in(self, camera_pose, target_pose=None):
        """Predicted normalized points ``(4, 2)`` and depths ``(4,)`` of the target at
        ``target_pose`` (default: the estimate) in a camera at ``camera_pose`` (4x4, world);
        ``None`` before the first frame."""
        target_pose = self.pose if target_pose is None else target_pose
        if target_pose is None:
            return None
        r = target_in_camera(self.object_points, camera_pose, target_pose)
        return r[:, :2] / r[:, 2:3], r[:, 2].copy()

    def _gauss_newton(self, pose, rc, pc, z, iterations, weights):
        """``iterations`` GN steps on the frames ``rc, pc, z`` with their ``weights``
        ``(w, diagonal)`` (N, 8, 8 and N, :meth:`_frames`): ``(pose, information, cost,
        prior)``, the level prior's terms included in the information and the cost,
        ``prior`` its :meth:`_prior_terms` at the result (``None`` without a prior); ``None``
        if the target falls behind a camera (:func:`_gauss_newton_kernel`)."""
        w_prior = 1.0 / self.level_prior**2 if self.level_prior > 0.0 else 0.0
        pose, info, cost, p_info, p_grad, p_cost, ok = _gauss_newton_kernel(
            np.ascontiguousarray(pose), rc, pc, z, self.object_points, *weights, iterations,
            self.level_normal, w_prior,
        )  # fmt: skip
        if not ok:
            return None
        return pose, info, cost, ((p_info, p_grad, p_cost) if w_prior > 0.0 else None)

    def _pnp_hypotheses(self, xy, g_c):
        return planar_pnp_poses(self.object_points, xy, g_c)

    # ------------------------------------------------------------------ filter
    def update(self, pixels, camera_pose, camera_cov=None) -> bool:
        """Fuse one detection: ``pixels`` ``(4, 2)`` (paper order) captured with the camera
        at ``camera_pose`` (4x4, world, *at the capture time*). ``camera_cov`` (6 x 6,
        optional) is the covariance of that pose's error (:meth:`pose_noise`; from the
        state estimator); ``None`` means the pose is exact. Returns True if fused, False if
        the frame was gated out (or unusable)."""
        pixels = C.array("pixels", pixels, (4, 2))
        g_c = C.transform("camera_pose", camera_pose)
        if camera_cov is not None:
            camera_cov = C.array("camera_cov", camera_cov, (6, 6))
        return self.update_checked(pixels, g_c, camera_cov)

    def update_checked(self, pixels, g_c, camera_cov=None) -> bool:
        """:meth:`update` of checked inputs: float ``(4, 2)`` pixels, a rigid 4x4 pose and
        a float ``(6, 6)`` covariance or ``None`` (the servo's per-period call: its inputs
        come from the perception block and the model)."""
        xy = self.camera.normalize_checked(pixels)
        if camera_cov is not None and not np.any(camera_cov):
            camera_cov = None
        if self.pose is None:
            hyp = self._pnp_hypotheses(xy, g_c)
            if not hyp:
                return False
            self._append(g_c, xy, self._frame_weight(hyp[0], g_c, camera_cov))
            self._hyp = hyp
            return self._refine()
        rt = np.ascontiguousarray(self.pose[:3, :3])
        xw = _target_points(rt, self.pose[:3, 3].copy(), self.object_points)
        h8, nu = np.empty((8, 6)), np.empty(8)
        rcf = np.ascontiguousarray(g_c[:3, :3].T)
        if not _frame_residuals(
            rcf, g_c[:3, 3].copy(), rt, xw, self.object_points, xy, np.empty((3, 3)), h8, nu
        ):
            return self._reject(pixels, g_c, camera_cov)
        scale = (self.sigma / self.pixel_sigma) ** 2
        extra = self._camera_noise(self.pose, g_c, camera_cov)
        s = h8 @ self.P @ h8.T + scale * self._r_pixel + extra
        if float(nu @ _solve(s, nu)) > self.gate:
            return self._reject(pixels, g_c, camera_cov)
        self._bad = 0
        self._append(g_c, xy, self._frame_weight(self.pose, g_c, camera_cov, extra))
        ok = self._refine()
        if ok and self.recheck > 0 and self.updates % self.recheck == 0:
            self._rescue(xy, g_c)
        return ok

    def _rescue(self, xy, g_c) -> None:
        """Escape the wrong branch of the planar ambiguity: refine both PnP solutions of the
        latest frame on the whole window and adopt one whose cost is lower."""
        rc, pc, z, w = self._frames()
        cur = self._gauss_newton(self.pose, rc, pc, z, 0, w)
        if cur is None:
            return
        for pose in self._pnp_hypotheses(xy, g_c):
            r = self._gauss_newton(pose, rc, pc, z, 4, w)
            if r is not None and r[2] < cur[2] - 1.0:
                cur = r
                self.pose = r[0]
                self.P = self._covariance(r[1], r[3])
                self.switches += 1

    def _camera_noise(self, target_pose, g_c, camera_cov):
        """:meth:`pose_noise` of a frame at the target estimate ``target_pose`` (0 if exact)."""
        if camera_cov is None:
            return 0.0
        return self.pose_noise(target_in_camera(self.object_points, g_c, target_pose), camera_cov)

    def _frame_weight(self, target_pose, g_c, camera_cov, extra=None):
        """8 x 8 weight (inverse covariance) of a frame: the pixel noise's for an exact pose."""
        if camera_cov is None:
            return self._w_pixel
        if extra is None:
            extra = self._camera_noise(target_pose, g_c, camera_cov)
        w = np.linalg.inv(self._r_pixel + extra)
        return 0.5 * (w + w.T)

    def _append(self, g_c, xy, weight):
        """Store a frame in the window (overwriting the oldest once it is full)."""
        k = self._next
        self._rc[k] = g_c[:3, :3].T
        self._pc[k] = g_c[:3, 3]
        self._z[k] = xy
        self._w[k] = weight
        self._diag[k] = _diagonal_flags(self._w[k : k + 1])[0]
        self._next = (k + 1) % self.window
        self._count = min(self._count + 1, self.window)

    def _reject(self, pixels, g_c, camera_cov=None) -> bool:
        self.rejected += 1
        self._bad += 1
        if self._bad >= self.reset_after:
            rejected = self.rejected
            self.reset()
            self.rejected = rejected
            return self.update_checked(pixels, g_c, camera_cov)
        return False

    def _frames(self):
        """Views of the window: ``R_C^T``, ``p_C``, points and ``(weights, diagonal)`` of its
        frames."""
        n = self._count
        return self._rc[:n], self._pc[:n], self._z[:n], (self._w[:n], self._diag[:n])

    def _refine(self) -> bool:
        rc, pc, z, w = self._frames()
        young = len(self._hyp) > 1
        cands = self._hyp if self._hyp else [self.pose]
        n_it = max(self.iterations, 3) if self.updates < 3 else self.iterations
        results = [r for r in (self._gauss_newton(p, rc, pc, z, n_it, w) for p in cands) if r]
        if not results:
            rejected = self.rejected
            self.reset()
            self.rejected = rejected
            return False
        results.sort(key=lambda r: r[2])
        best = results[0]
        if young:
            # keep the other PnP branch until the data decide: a log-likelihood margin of
            # `decisive` (cost difference), `young` frames at most, or the branches merged
            other = results[1] if len(results) > 1 else None
            merged = other is None or np.linalg.norm(_solve(best[0], other[0]) - np.eye(4)) < 1e-4
            done = other is None or other[2] - best[2] > self.decisive
            if merged or done or self.updates + 1 >= self.young:
                self._hyp = []
            else:
                self._hyp = [r[0] for r in results]
        self.pose, info = best[0], best[1]
        self.updates += 1
        n = self._count
        prior = best[3]
        if n >= 10:  # cost / dof = (sigma_true / pixel_sigma)^2, the frames' cost only
            cost = best[2] - (prior[2] if prior is not None else 0.0)
            self.sigma_hat = self.pixel_sigma * float(np.sqrt(max(cost, 0.0) / (8 * n - 6)))
        self.P = self._covariance(info, prior)
        return True
