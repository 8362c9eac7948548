"""The perception block: detections -> normalized image points and depths.

The controller interprets pixels with *its* model of the camera (intrinsics possibly wrong,
``sensors.intrinsics_error``): ``x = (u - c_x) / f_x``, ``y = (v - c_y) / f_y``, and
the depths of the four points come from the known target geometry (planar PnP by IPPE,
:func:`~tdacm.vision.features.estimate_depths`) - the paper's depth estimation. A detection
whose corners admit no pose with the target in front of the camera (large pixel noise does
that) is rejected: the view is "not seen" that period, as a missed frame.
"""

from __future__ import annotations

from ..vision import _checks as C
from ..vision.camera import PinholeCamera
from ..vision.features import _estimate_depths
from ..vision.ippe import canonical_frame
from .data import CameraMeasurement, DeferredMeasurement, GlobalView, LocalView


class Perception:
    """``local(measurement) -> LocalView``, ``global_(measurement) -> GlobalView``."""

    def __init__(self, local_camera: PinholeCamera, global_camera: PinholeCamera, target):
        self.local_camera = local_camera
        self.global_camera = global_camera
        self.target = target
        self._object = C.array("target.feature_points", target.feature_points, (4, 3))
        self._object_2d = canonical_frame(self._object)[0]  # the IPPE depths' plane frame

    def reset(self) -> None:
        pass

    def local(self, m: CameraMeasurement) -> LocalView:
        det = m.detection
        if not det.found:
            return LocalView(m.t_capture)
        # checked once here: the servo and its target filter take the view's arrays as they are
        uv = C.array("detection.points", det.points, (4, 2))
        xy = self.local_camera.normalize_checked(uv)
        z, _ = _estimate_depths(xy, self._object, self._object_2d)
        if z is None:  # no pose puts the target in front: a corrupted frame, rejected
            return LocalView(m.t_capture)
        return LocalView(m.t_capture, True, uv, xy, z)

    def global_(self, m: CameraMeasurement | DeferredMeasurement | None) -> GlobalView | None:
        if m is None:
            return None
        if isinstance(m, DeferredMeasurement):
            return GlobalView.deferred(m)  # C_G renders only if the servo reads the view
        return GlobalView(m.t_capture, m.detection)
