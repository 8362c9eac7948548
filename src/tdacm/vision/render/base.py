"""The renderer interface: any object with these methods can feed the vision pipeline.

A renderer owns a static :class:`~tdacm.vision.scene.SceneConfig` and draws it, plus the
TD-ACM given as poses (never a model object, so the vision layer does not depend on the
dynamics: data flows model -> sensors -> controllers), from any camera pose with any
:class:`~tdacm.vision.camera.PinholeCamera`. The image's geometry must follow the camera's
intrinsics exactly (OpenCV pixel-centre convention), so that detected corners can be compared
with :meth:`PinholeCamera.project`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from .. import _checks as C
from ..camera import PinholeCamera


class Renderer(ABC):
    """Abstract renderer: ``set_arm(...)`` then ``render(camera, camera_pose)``."""

    #: Whether :meth:`set_arm` has a visible effect (the planar renderer ignores the arm).
    draws_arm: bool = False

    @abstractmethod
    def render(self, camera: PinholeCamera, camera_pose: np.ndarray) -> np.ndarray:
        """RGB image ``(H, W, 3)`` ``uint8`` seen by ``camera`` at ``camera_pose`` (4x4
        ``T_wc``: camera frame x right, y down, z forward, expressed in the world)."""

    def set_arm(self, base_pose=None, backbone=None) -> None:  # noqa: B027 - optional
        """Place the TD-ACM: drone pose ``g_b`` (4x4) and the rod backbone as ``(n, 4, 4)``
        poses or ``(n, 3)`` positions from the attachment to the tip. ``None`` hides it."""

    def close(self) -> None:  # noqa: B027 - optional
        """Release resources."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def check_render_args(camera, camera_pose) -> np.ndarray:
    if not isinstance(camera, PinholeCamera):
        raise ValueError(f"camera must be a PinholeCamera, got {camera!r}")
    return C.transform("camera_pose", camera_pose)


def backbone_positions(backbone) -> np.ndarray:
    """``(n, 3)`` positions from ``(n, 4, 4)`` poses or ``(n, 3)`` positions."""
    b = np.asarray(backbone, dtype=float)
    if b.ndim == 3 and b.shape[1:] == (4, 4):
        b = b[:, :3, 3]
    b = C.array("backbone", b, (-1, 3))
    if b.shape[0] < 2:
        raise ValueError(f"backbone needs at least 2 points, got {b.shape[0]}")
    return b


def resample_polyline(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced in arc length along the polyline ``points``."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    if s[-1] <= 0.0:
        return np.repeat(points[:1], n, axis=0)
    t = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(t, s, points[:, k]) for k in range(3)])
