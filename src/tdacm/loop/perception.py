"""The perception block: detections -> normalized image points and depths.

The controller interprets pixels with *its* model of the camera (intrinsics possibly wrong,
``sensors.intrinsics_error``): ``x = (u - c_x) / f_x``, ``y = (v - c_y) / f_y``, and
the depths of the four points come from the known target geometry (planar PnP by IPPE,
:func:`~tdacm.vision.features.estimate_depths`) - the paper's depth estimation. A detection
whose corners admit no pose with the target in front of the camera (large pixel noise does
that) is rejected: the view is "not seen" that period, as a missed frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .. import _validate as C
from ..vision.camera import PinholeCamera, normalize_into
from ..vision.ippe import DEPTHS_OK, canonical_frame, point_depths
from .data import CameraMeasurement, DeferredMeasurement, GlobalView, LocalView


class PerceptionParams(NamedTuple):
    """The perception's parameters: the controller's model of C_L ``camera`` (a
    :class:`~tdacm.vision.camera.CameraParams`) and the target's feature points in their
    plane's canonical frame ``object_2d`` (4, 2)."""

    camera: object
    object_2d: np.ndarray


@njit(cache=True)
def perceive(camera, object_2d, uv, out_xy, out_z):
    """The perception of one frame (module docstring), compiled: the pixels ``uv`` (4, 2) as
    normalized points ``out_xy`` through the controller's camera model ``camera`` (a
    :class:`~tdacm.vision.camera.CameraParams`) and their depths ``out_z`` from the target's
    plane points ``object_2d`` (4, 2) (IPPE, :func:`~tdacm.vision.ippe.point_depths`); False
    for a frame no pose explains with the target in front (rejected: "not seen")."""
    normalize_into(camera, uv, out_xy)
    return point_depths(object_2d, out_xy, out_z) == DEPTHS_OK


class Perception:
    """``local(measurement) -> LocalView``, ``global_(measurement) -> GlobalView``."""

    def __init__(self, local_camera: PinholeCamera, global_camera: PinholeCamera, target):
        self.local_camera = local_camera
        self.global_camera = global_camera
        self.target = target
        self._object = C.array("target.feature_points", target.feature_points, (4, 3))
        #: the target's feature points in their plane's canonical frame (the IPPE depths')
        self.object_2d = canonical_frame(self._object)[0]
        self._camera = local_camera.params()
        #: the record of the compiled step (:func:`perceive`)
        self.params = PerceptionParams(self._camera, self.object_2d)

    def reset(self) -> None:
        pass

    def local(self, m: CameraMeasurement) -> LocalView:
        det = m.detection
        if not det.found:
            return LocalView(m.t_capture)
        # checked once here: the servo and its target filter take the view's arrays as they are
        uv = np.ascontiguousarray(C.array("detection.points", det.points, (4, 2)))
        xy, z = np.empty((4, 2)), np.empty(4)
        if not perceive(self._camera, self.object_2d, uv, xy, z):
            return LocalView(m.t_capture)  # no pose puts the target in front: rejected
        return LocalView(m.t_capture, True, uv, xy, z)

    def global_(self, m: CameraMeasurement | DeferredMeasurement | None) -> GlobalView | None:
        if m is None:
            return None
        if isinstance(m, DeferredMeasurement):
            return GlobalView.deferred(m)  # C_G renders only if the servo reads the view
        return GlobalView(m.t_capture, m.detection)
