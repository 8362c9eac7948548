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
* the window forgets: a slow bias (camera-pose or intrinsics errors) is followed with a lag
  of about ``window`` frames.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ..lie.se3 import expmap
from . import _checks as C
from .camera import PinholeCamera

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


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _hats(x):
    """Skew matrices of the rows of ``x`` ``(k, 3)`` -> ``(k, 3, 3)``."""
    out = np.zeros((x.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -x[:, 2], x[:, 1]
    out[:, 1, 0], out[:, 1, 2] = x[:, 2], -x[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -x[:, 1], x[:, 0]
    return out


@njit(cache=True)
def _normal_equations(rt, pt, rc, pc, z, obj, wx, wy):
    """Gauss-Newton normal equations of the window: information ``sum h^T W h`` (6x6),
    gradient ``sum h^T W res`` and cost ``sum res^T W res``, with the residuals and Jacobians
    of :meth:`TargetFilter._residuals` (``h = dpi/dr R_C^T R_T [-X_k^, I]``), accumulated frame
    by frame without the ``(N, 4, 2, 6)`` arrays; ``ok`` is False if a point is behind a
    camera."""
    info = np.zeros((6, 6))
    grad = np.zeros(6)
    cost = 0.0
    xw = obj @ rt.T
    for k in range(4):
        for j in range(3):
            xw[k, j] += pt[j]
    dr = np.empty((3, 6))
    hx = np.empty(6)
    hy = np.empty(6)
    for f in range(rc.shape[0]):
        a = rc[f] @ rt
        for k in range(4):
            r = rc[f] @ (xw[k] - pc[f])
            if r[2] <= 1e-6:
                return info, grad, cost, False
            iz = 1.0 / r[2]
            px, py = r[0] * iz, r[1] * iz
            ex, ey = z[f, k, 0] - px, z[f, k, 1] - py
            cost += wx * ex * ex + wy * ey * ey
            x0, x1, x2 = obj[k, 0], obj[k, 1], obj[k, 2]
            for i in range(3):  # dr = [-A X_k^, A]
                dr[i, 0] = -(a[i, 1] * x2 - a[i, 2] * x1)
                dr[i, 1] = -(a[i, 2] * x0 - a[i, 0] * x2)
                dr[i, 2] = -(a[i, 0] * x1 - a[i, 1] * x0)
                dr[i, 3], dr[i, 4], dr[i, 5] = a[i, 0], a[i, 1], a[i, 2]
            for c in range(6):
                hx[c] = iz * dr[0, c] - px * iz * dr[2, c]
                hy[c] = iz * dr[1, c] - py * iz * dr[2, c]
                grad[c] += wx * hx[c] * ex + wy * hy[c] * ey
            for c in range(6):
                for d in range(6):
                    info[c, d] += wx * hx[c] * hx[d] + wy * hy[c] * hy[d]
    return info, grad, cost, True


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
    """

    def __init__(
        self,
        camera: PinholeCamera,
        object_points,
        pixel_sigma: float = 1.0,
        window: int = 250,
        iterations: int = 2,
        gate: float = GATE_CHI2_8,
        young: int = 100,
        decisive: float = 25.0,
        reset_after: int = 5,
        recheck: int = 10,
    ):
        self.camera = camera
        self.recheck = int(recheck)
        self.decisive = C.positive("decisive", decisive)
        self.object_points = C.array("object_points", object_points, (4, 3))
        self.pixel_sigma = C.positive("pixel_sigma", pixel_sigma)
        self.window = C.positive_int("window", window)
        self.iterations = C.positive_int("iterations", iterations)
        self.gate = C.positive("gate", gate)
        self.young = int(young)
        self.reset_after = C.positive_int("reset_after", reset_after)
        self._xhat = _hats(self.object_points)
        self.reset()

    @property
    def _rinv(self):
        f = np.array([self.camera.fx, self.camera.fy]) / self.pixel_sigma
        return f * f  # 1 / sigma_normalized^2 for x, y

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
        self._rc = deque(maxlen=self.window)  # R_C^T of each frame
        self._pc = deque(maxlen=self.window)  # p_C of each frame
        self._z = deque(maxlen=self.window)  # normalized points (4, 2)

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
    def points_in(self, camera_pose):
        """Predicted normalized points ``(4, 2)`` and depths ``(4,)`` of the estimated target
        in a camera at ``camera_pose`` (4x4, world); ``None`` before the first frame."""
        if self.pose is None:
            return None
        g = np.linalg.solve(np.asarray(camera_pose, float), self.pose)
        r = self.object_points @ g[:3, :3].T + g[:3, 3]
        return r[:, :2] / r[:, 2:3], r[:, 2].copy()

    def _residuals(self, pose, rc, pc, z):
        """Residuals ``(N, 4, 2)`` and Jacobians ``(N, 4, 2, 6)`` of frames ``rc, pc, z``."""
        rt, pt = pose[:3, :3], pose[:3, 3]
        xw = self.object_points @ rt.T + pt  # (4, 3)
        r = np.einsum("nij,nkj->nki", rc, xw[None, :, :] - pc[:, None, :])  # (N, 4, 3)
        depth = r[:, :, 2]
        if np.any(depth <= 1e-6):
            return None, None
        iz = 1.0 / depth
        pred = r[:, :, :2] * iz[:, :, None]
        a = np.einsum("nij,jk->nik", rc, rt)  # R_C^T R_T (N, 3, 3)
        dr = np.empty((rc.shape[0], 4, 3, 6))
        dr[:, :, :, :3] = -np.einsum("nij,kjl->nkil", a, self._xhat)
        dr[:, :, :, 3:] = a[:, None, :, :]
        dpi = np.zeros((rc.shape[0], 4, 2, 3))
        dpi[:, :, 0, 0] = iz
        dpi[:, :, 1, 1] = iz
        dpi[:, :, 0, 2] = -pred[:, :, 0] * iz
        dpi[:, :, 1, 2] = -pred[:, :, 1] * iz
        h = np.einsum("nkij,nkjl->nkil", dpi, dr)
        return z - pred, h

    def _gauss_newton(self, pose, rc, pc, z, iterations):
        """``iterations`` GN steps; returns ``(pose, information, cost)`` (``None`` if the
        target falls behind a camera)."""
        w = self._rinv
        for it in range(iterations + 1):
            info, g, cost, ok = _normal_equations(
                np.ascontiguousarray(pose[:3, :3]), pose[:3, 3].copy(), rc, pc, z,
                self.object_points, w[0], w[1],
            )  # fmt: skip
            if not ok:
                return None
            if it == iterations:
                return pose, info, cost
            try:
                dx = np.linalg.solve(info, g)
            except np.linalg.LinAlgError:
                return pose, info, cost
            pose = pose @ expmap(dx)
        return None  # pragma: no cover

    def _pnp_hypotheses(self, xy, g_c):
        ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            self.object_points, xy.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
        )
        out = []
        for rv, tv in zip(rvecs if ok else (), tvecs if ok else (), strict=True):
            g = np.eye(4)
            g[:3, :3] = cv2.Rodrigues(rv)[0]
            g[:3, 3] = np.ravel(tv)
            if np.all((self.object_points @ g[:3, :3].T + g[:3, 3])[:, 2] > 0):
                out.append(g_c @ g)
        return out

    # ------------------------------------------------------------------ filter
    def update(self, pixels, camera_pose) -> bool:
        """Fuse one detection: ``pixels`` ``(4, 2)`` (paper order) captured with the camera
        at ``camera_pose`` (4x4, world, *at the capture time*). Returns True if fused,
        False if the frame was gated out (or unusable)."""
        xy = self.camera.normalize(C.array("pixels", pixels, (4, 2)))
        g_c = C.transform("camera_pose", camera_pose)
        rc1, pc1 = g_c[:3, :3].T[None], g_c[:3, 3][None]
        if self.pose is None:
            hyp = self._pnp_hypotheses(xy, g_c)
            if not hyp:
                return False
            self._append(g_c, xy)
            self._hyp = hyp
            return self._refine()
        res, h = self._residuals(self.pose, rc1, pc1, xy[None])
        if res is None:
            return self._reject(pixels, camera_pose)
        h8 = h.reshape(8, 6)
        scale = (self.sigma / self.pixel_sigma) ** 2
        s = h8 @ self.P @ h8.T + scale * np.diag(np.tile(1.0 / self._rinv, 4))
        nu = res.ravel()
        if float(nu @ np.linalg.solve(s, nu)) > self.gate:
            return self._reject(pixels, camera_pose)
        self._bad = 0
        self._append(g_c, xy)
        ok = self._refine()
        if ok and self.recheck > 0 and self.updates % self.recheck == 0:
            self._rescue(xy, g_c)
        return ok

    def _rescue(self, xy, g_c) -> None:
        """Escape the wrong branch of the planar ambiguity: refine both PnP solutions of the
        latest frame on the whole window and adopt one whose cost is lower."""
        rc, pc, z = np.array(self._rc), np.array(self._pc), np.array(self._z)
        cur = self._gauss_newton(self.pose, rc, pc, z, 0)
        if cur is None:
            return
        for pose in self._pnp_hypotheses(xy, g_c):
            r = self._gauss_newton(pose, rc, pc, z, 4)
            if r is not None and r[2] < cur[2] - 1.0:
                cur = r
                self.pose = r[0]
                self.P = np.linalg.inv(r[1]) * (self.sigma / self.pixel_sigma) ** 2
                self.P = 0.5 * (self.P + self.P.T)
                self.switches += 1

    def _append(self, g_c, xy):
        self._rc.append(g_c[:3, :3].T.copy())
        self._pc.append(g_c[:3, 3].copy())
        self._z.append(xy)

    def _reject(self, pixels, camera_pose) -> bool:
        self.rejected += 1
        self._bad += 1
        if self._bad >= self.reset_after:
            rejected = self.rejected
            self.reset()
            self.rejected = rejected
            return self.update(pixels, camera_pose)
        return False

    def _refine(self) -> bool:
        rc, pc, z = np.array(self._rc), np.array(self._pc), np.array(self._z)
        young = len(self._hyp) > 1
        cands = self._hyp if self._hyp else [self.pose]
        n_it = max(self.iterations, 3) if self.updates < 3 else self.iterations
        results = [r for r in (self._gauss_newton(p, rc, pc, z, n_it) for p in cands) if r]
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
            merged = (
                other is None
                or np.linalg.norm(np.linalg.solve(best[0], other[0]) - np.eye(4)) < 1e-4
            )
            done = other is None or other[2] - best[2] > self.decisive
            if merged or done or self.updates + 1 >= self.young:
                self._hyp = []
            else:
                self._hyp = [r[0] for r in results]
        self.pose, info = best[0], best[1]
        self.P = np.linalg.inv(info)
        self.P = 0.5 * (self.P + self.P.T)
        self.updates += 1
        n = len(self._z)
        if n >= 10:  # cost / dof = (sigma_true / pixel_sigma)^2
            self.sigma_hat = self.pixel_sigma * float(np.sqrt(best[2] / (8 * n - 6)))
        self.P *= (self.sigma / self.pixel_sigma) ** 2
        return True
