"""One local-camera servo step: image -> detection -> C_V points -> features -> twist.

:class:`LocalCameraServo` chains the pieces of this package in the order of the paper's
dual-camera algorithm (local-camera branch):

1. detect the target in the C_L image (:mod:`.detect`), pixels -> normalized coordinates;
2. depths of the four points from the known target geometry (planar PnP,
   :func:`~.features.estimate_depths`);
3. roll/pitch compensation into the virtual camera C_V (:mod:`.virtual`), if the caller
   gives ``g_{C_L}^{C_V}`` (floating base); skipped for a fixed base;
4. advanced features and the IBVS twist of C_V (:mod:`.features`, :mod:`.ibvs`).

The caller maps the twist to joint rates with :func:`~.tip.camera_joint_rates`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._linalg import solve as _solve
from ..lie.se3 import expmap, so3_log
from .camera import PinholeCamera
from .detect import Detection, TargetDetector
from .features import advanced_features, estimate_depths
from .ibvs import IBVSController
from .target_filter import TargetFilter, target_in_camera
from .targets import FiducialTarget
from .virtual import virtual_camera_points


@dataclass(frozen=True)
class ServoStep:
    """Everything one servo step computed (``twist`` is ``None`` if not detected)."""

    detection: Detection
    points: np.ndarray | None = None  # normalized, in C_V (or C_L without compensation)
    depths: np.ndarray | None = None
    features: np.ndarray | None = None
    error: np.ndarray | None = None
    twist: np.ndarray | None = None  # [w; v] of C_V in its own frame

    @property
    def found(self) -> bool:
        return self.detection.found


class LocalCameraServo:
    """Advanced-feature IBVS on the tip camera's images.

    Parameters
    ----------
    camera:
        The local camera (e.g. :data:`~.camera.LOCAL_CAMERA`).
    target:
        The fiducial target.
    desired_points, desired_depths:
        Reference snapshot (normalized points in paper order and their depths), e.g. from
        :meth:`reference_from_pose`.
    gain, mode:
        IBVS gain and interaction-matrix choice (see :class:`~.ibvs.IBVSController`).
    compensation:
        Virtual-camera mapping used when a transform is given to :meth:`step`
        (``"exact"``, ``"rotation"`` or ``"approx"``).
    track:
        Let the detector search near the previous detection first.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        target: FiducialTarget,
        desired_points,
        desired_depths,
        gain: float = 0.5,
        mode: str = "current",
        compensation: str = "exact",
        track: bool = True,
    ):
        self.camera = camera
        self.target = target
        self.detector = TargetDetector(target, track=track)
        self.controller = IBVSController(desired_points, desired_depths, gain=gain, mode=mode)
        self.compensation = compensation

    @staticmethod
    def reference_from_pose(
        camera: PinholeCamera, target: FiducialTarget, target_pose, camera_pose
    ):
        """Desired normalized points and depths of ``target`` (at ``target_pose``) seen from
        ``camera_pose`` - the paper's reference snapshot, computed analytically."""
        pc = target_in_camera(target.feature_points, camera_pose, target_pose)
        if np.any(pc[:, 2] <= 0):
            raise ValueError("the target is behind the camera in the reference pose")
        return pc[:, :2] / pc[:, 2:3], pc[:, 2]

    def step(self, image, virtual_transform=None) -> ServoStep:
        """Process one C_L image; ``virtual_transform`` is ``g_{C_L}^{C_V}``
        (:func:`~.virtual.virtual_camera_transform`) or ``None`` (no compensation)."""
        det = self.detector.detect(image)
        if not det.found:
            return ServoStep(det)
        xy = self.camera.normalize(det.points)
        z = estimate_depths(xy, self.target.feature_points)
        if virtual_transform is not None:
            xy, zv = virtual_camera_points(
                xy, virtual_transform, z, self.compensation, return_depths=True
            )
            # "exact" returns z^{C_V}; the other methods the ratio z^{C_V} / z^{C_L}
            z = zv if self.compensation == "exact" else zv * z
        f = advanced_features(xy)
        e = self.controller.error(xy, features=f)  # the features once, not three times
        v = self.controller.twist(xy, z, error=e)
        return ServoStep(det, xy, z, f, e, v)


@dataclass(frozen=True)
class PredictedStep:
    """One step of :class:`PredictiveServo` (``twist`` is ``None`` before the first frame).

    ``points``/``depths``: the target's feature points predicted in the servo camera (C_V)
    from the world-frame estimate; ``pixels_local``: the same points predicted in the real
    camera C_L (pixels), for the field-of-view test of the mode switch."""

    points: np.ndarray | None = None
    depths: np.ndarray | None = None
    features: np.ndarray | None = None
    error: np.ndarray | None = None
    twist: np.ndarray | None = None
    pixels_local: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return self.twist is not None


class PredictiveServo:
    """Advanced-feature IBVS on features predicted from a world-frame target estimate.

    The detections of C_L update a :class:`~.target_filter.TargetFilter` (static target,
    corner pixels as measurements, each associated with the camera pose at its capture
    time); every control period the four feature points are predicted at the *current*
    pose of the servo camera (C_V for a flying base, C_L for a held one) and the paper's
    advanced features, their interaction matrix and the well-conditioned solve
    (:func:`~.ibvs.robust_solve`, singular-value ``floor``) give the twist.
    See docs/control.md, "Robust servo".

    Parameters
    ----------
    camera, target, desired_points, desired_depths, gain, mode:
        As :class:`LocalCameraServo`.
    floor, solver:
        Singular-value floor of the IBVS solve (:class:`~.ibvs.IBVSController`).
    pixel_sigma, window:
        Noise model of the filter (:class:`~.target_filter.TargetFilter`).
    smoothing:
        Time constant (s) of a first-order filter on the target estimate used for the
        prediction (0: none). The target is static, so this adds no lag to the camera's
        motion (which enters through the exact camera pose); it only spreads the estimate's
        corrections - large along the weakly observable directions while few frames are
        fused - over time, so that they do not kick the TD-ACM.
    track:
        Tracking window of the detector.
    level_prior, level_normal:
        Standard deviation (rad) of the filter's prior that the target's z axis is along
        ``level_normal`` (world; default straight down: the target lies level, facing up);
        0 disables it (:class:`~.target_filter.TargetFilter`).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        target: FiducialTarget,
        desired_points,
        desired_depths,
        gain: float = 1.0,
        mode: str = "mean",
        floor: float = 0.05,
        solver: str = "floor",
        pixel_sigma: float = 1.0,
        window: int = 250,
        smoothing: float = 1.0,
        track: bool = True,
        level_prior: float = 0.0,
        level_normal=(0.0, 0.0, -1.0),
    ):
        self.camera = camera
        self.target = target
        self.detector = TargetDetector(target, track=track)
        self.controller = IBVSController(
            desired_points, desired_depths, gain=gain, mode=mode, floor=floor, solver=solver
        )
        self.filter = TargetFilter(
            camera,
            target.feature_points,
            pixel_sigma=pixel_sigma,
            window=window,
            level_prior=level_prior,
            level_normal=level_normal,
        )
        if not np.isfinite(smoothing) or smoothing < 0:
            raise ValueError(f"smoothing must be >= 0, got {smoothing!r}")
        self.smoothing = float(smoothing)
        self.target_pose = None  # smoothed estimate used by the prediction

    def measure(self, detection: Detection, camera_pose, camera_cov=None) -> bool:
        """Fuse a detection captured with C_L at ``camera_pose`` (4x4, world, at the capture
        time; ``camera_cov``: its 6 x 6 error covariance if it comes from an estimate,
        :meth:`~.target_filter.TargetFilter.update`); False if not found or gated out."""
        if detection is None or not detection.found:
            return False
        return self.filter.update(detection.points, camera_pose, camera_cov)

    def predict(self, dt: float) -> None:
        """Advance the smoothed target pose toward the filter's estimate by one period."""
        self.filter.predict(dt)
        est = self.filter.pose
        if est is None:  # not seen yet, or the filter restarted: keep the last estimate
            return
        if self.target_pose is None or self.smoothing == 0:
            self.target_pose = est.copy()
            return
        a = min(1.0, dt / self.smoothing)
        d = _solve(self.target_pose, est)  # g_s^-1 g_T
        w = a * so3_log(np.ascontiguousarray(d[:3, :3]))
        step = expmap(np.array([w[0], w[1], w[2], 0.0, 0.0, 0.0]))  # rotation by a * log(R)
        step[:3, 3] = a * d[:3, 3]
        self.target_pose = self.target_pose @ step

    def _points_in(self, camera_pose):
        return self.filter.points_in(camera_pose, self.target_pose)

    def step(self, servo_pose, camera_pose=None) -> PredictedStep:
        """Twist of the servo camera at ``servo_pose`` (4x4 world pose of C_V, or of C_L
        for a held base); ``camera_pose`` (C_L) adds the predicted C_L pixels."""
        if self.target_pose is None:
            if self.filter.pose is None:
                return PredictedStep()
            self.target_pose = self.filter.pose.copy()
        pred = self._points_in(servo_pose)
        xy, z = pred
        if np.any(z <= 0):
            return PredictedStep()
        pix = None
        if camera_pose is not None:
            xl, zl = self._points_in(camera_pose)
            pix = self.camera.denormalize_checked(xl) if np.all(zl > 0) else None
        f, e, v = self.controller.features_error_twist(xy, z)
        return PredictedStep(xy, z, f, e, v, pix)
