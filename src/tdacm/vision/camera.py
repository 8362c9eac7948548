"""Pinhole cameras: intrinsics, projection, normalized coordinates and field-of-view tests.

Conventions (``docs/vision.md``): the camera frame has x right, y down, z forward (optical axis).
A point ``P = [X, Y, Z]`` in the camera frame has the normalized image coordinates
``x = X/Z``, ``y = Y/Z`` and the pixel coordinates ``u = fx x + cx``, ``v = fy y + cy``.
Pixel coordinates follow OpenCV: the centre of pixel ``(col, row)`` is at ``u = col``,
``v = row``, so the image spans ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.

The two presets are the paper's Table II ("Intrinsic parameters of the local (C_L) and global
(C_G) cameras in the PyBullet simulator"): ``LOCAL_CAMERA`` (tip camera C_L, 1024 x 1024,
f = 886.8 px, 60 deg, clip 0.5/10 m) and ``GLOBAL_CAMERA`` (drone camera C_G, 500 x 500,
f = 350.5 px, 71 deg, clip 0.01/20 m).

An optional OpenCV distortion vector (``k1, k2, p1, p2[, k3...]``) makes the same class usable
for a calibrated real camera: :meth:`PinholeCamera.normalize` then undistorts with
``cv2.undistortPoints`` and :meth:`PinholeCamera.project` distorts with ``cv2.projectPoints``.
The simulated presets have no distortion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import paper_values as PV
from . import _checks as C


class CameraParams(NamedTuple):
    """A pinhole camera without distortion as the record of the compiled steps
    (:meth:`PinholeCamera.params`): focal lengths, principal point, resolution and clipping
    planes."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: float
    height: float
    near: float
    far: float


@njit(cache=True)
def in_image(c, u, v, margin):
    """The pixel ``(u, v)`` lies at least ``margin`` px inside the image of ``c`` (a
    :class:`CameraParams`; :meth:`PinholeCamera.pixels_in_image`)."""
    return (
        u >= margin - 0.5
        and u <= c.width - 0.5 - margin
        and v >= margin - 0.5
        and v <= c.height - 0.5 - margin
    )


@njit(cache=True)
def all_in_image(c, uv, margin):
    """Every pixel of ``uv`` (N, 2) at least ``margin`` px inside the image of ``c``."""
    for k in range(uv.shape[0]):
        if not in_image(c, uv[k, 0], uv[k, 1], margin):
            return False
    return True


@njit(cache=True)
def normalize_into(c, uv, out):
    """Normalized coordinates ``x = (u - c_x) / f_x``, ``y = (v - c_y) / f_y`` of the pixels
    ``uv`` (N, 2) into ``out``."""
    for k in range(uv.shape[0]):
        out[k, 0] = (uv[k, 0] - c.cx) / c.fx
        out[k, 1] = (uv[k, 1] - c.cy) / c.fy


@njit(cache=True)
def project_world(c, g_c, p, out_uv):
    """The pixel (into ``out_uv`` (2,)) of the world point ``p`` (3,) in the camera ``c`` at
    the world pose ``g_c``; returns its depth (the camera frame's ``z``)."""
    d0, d1, d2 = p[0] - g_c[0, 3], p[1] - g_c[1, 3], p[2] - g_c[2, 3]
    x = d0 * g_c[0, 0] + d1 * g_c[1, 0] + d2 * g_c[2, 0]
    y = d0 * g_c[0, 1] + d1 * g_c[1, 1] + d2 * g_c[2, 1]
    z = d0 * g_c[0, 2] + d1 * g_c[1, 2] + d2 * g_c[2, 2]
    out_uv[0] = c.fx * x / z + c.cx
    out_uv[1] = c.fy * y / z + c.cy
    return z


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera with intrinsics, resolution and clipping planes.

    Parameters
    ----------
    width, height:
        Resolution in pixels.
    fx, fy:
        Focal lengths in pixels (> 0).
    cx, cy:
        Principal point in pixels (OpenCV convention, pixel centres at integers).
    near, far:
        Clipping planes in metres (``0 < near < far``); points outside are not visible.
    distortion:
        Optional OpenCV distortion coefficients (empty for an ideal pinhole).
    name:
        Label used in reports.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float = 0.01
    far: float = 100.0
    distortion: tuple = field(default=())
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "width", C.positive_int("width", self.width))
        object.__setattr__(self, "height", C.positive_int("height", self.height))
        for key in ("fx", "fy"):
            object.__setattr__(self, key, C.positive(key, getattr(self, key)))
        for key in ("cx", "cy"):
            object.__setattr__(self, key, C.finite_scalar(key, getattr(self, key)))
        near = C.positive("near", self.near)
        far = C.positive("far", self.far)
        if far <= near:
            raise ValueError(f"far must be larger than near, got near={near}, far={far}")
        object.__setattr__(self, "near", near)
        object.__setattr__(self, "far", far)
        dist = tuple(float(d) for d in C.array("distortion", self.distortion, (-1,)))
        if len(dist) not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"distortion must have 0, 4, 5, 8, 12 or 14 entries, got {len(dist)}")
        object.__setattr__(self, "distortion", dist)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_fov(
        cls,
        width: int,
        height: int,
        fov_v_deg: float,
        near: float = 0.01,
        far: float = 100.0,
        name: str = "",
    ) -> PinholeCamera:
        """Square-pixel camera with vertical field of view ``fov_v_deg`` and a centred
        principal point ``(W/2, H/2)`` (as PyBullet's ``computeProjectionMatrixFOV``)."""
        fov = C.positive("fov_v_deg", fov_v_deg)
        if fov >= 180.0:
            raise ValueError(f"fov_v_deg must be below 180, got {fov_v_deg!r}")
        height = C.positive_int("height", height)
        f = 0.5 * height / math.tan(math.radians(fov) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0, near, far, name=name)

    def scaled(self, factor: float) -> PinholeCamera:
        """The same optics sampled at ``factor`` times the resolution (e.g. 0.5 halves it).

        Focal lengths scale by ``factor``; the principal point maps with the pixel-centre
        convention ``c' = (c + 0.5) factor - 0.5``.
        """
        s = C.positive("factor", factor)
        w = max(1, int(round(self.width * s)))
        h = max(1, int(round(self.height * s)))
        sx, sy = w / self.width, h / self.height
        return replace(
            self,
            width=w,
            height=h,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            name=f"{self.name}@{w}x{h}" if self.name else "",
        )

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def resolution(self) -> tuple[int, int]:
        """``(width, height)``."""
        return self.width, self.height

    @property
    def fov_deg(self) -> tuple[float, float]:
        """``(horizontal, vertical)`` field of view in degrees (about the principal point,
        symmetric extent ``W/2``, ``H/2`` as in Table II)."""
        fh = 2.0 * math.degrees(math.atan(0.5 * self.width / self.fx))
        fv = 2.0 * math.degrees(math.atan(0.5 * self.height / self.fy))
        return fh, fv

    def params(self) -> CameraParams:
        """The camera as the compiled steps' record (``ValueError`` with lens distortion: the
        compiled steps project without it)."""
        if self.has_distortion:
            raise ValueError(
                f"camera {self.name or ''}: the compiled steps have no lens distortion"
            )
        return CameraParams(
            float(self.fx), float(self.fy), float(self.cx), float(self.cy), float(self.width),
            float(self.height), float(self.near), float(self.far),
        )  # fmt: skip

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.distortion)

    # ------------------------------------------------------------------ projection
    def project(self, points_cam) -> np.ndarray:
        """Pixel coordinates ``(N, 2)`` of camera-frame points ``(N, 3)`` (or one ``(3,)``).

        Points with ``Z <= 0`` (behind the camera) give NaN rows.
        """
        return self.project_checked(C.points("points_cam", points_cam, 3))

    def project_checked(self, p: np.ndarray) -> np.ndarray:
        """:meth:`project` of a checked float ``(N, 3)`` array (the per-period callers pass
        arrays they computed, validated once where they entered)."""
        out = np.full((p.shape[0], 2), np.nan)
        front = p[:, 2] > 0.0
        if not np.any(front):
            return out
        if self.has_distortion:
            import cv2

            img, _ = cv2.projectPoints(
                p[front].reshape(-1, 1, 3),
                np.zeros(3),
                np.zeros(3),
                self.K,
                np.asarray(self.distortion),
            )
            out[front] = img.reshape(-1, 2)
            return out
        if front.all():  # the usual case: no masked copies
            z = p[:, 2]
            out[:, 0] = self.fx * p[:, 0] / z + self.cx
            out[:, 1] = self.fy * p[:, 1] / z + self.cy
            return out
        z = p[front, 2]
        out[front, 0] = self.fx * p[front, 0] / z + self.cx
        out[front, 1] = self.fy * p[front, 1] / z + self.cy
        return out

    def project_world(self, points_world, camera_pose) -> np.ndarray:
        """Pixels of world points seen from the camera pose ``camera_pose`` (4x4 ``T_wc``,
        the camera frame expressed in the world frame)."""
        return self.project(world_to_camera(points_world, camera_pose))

    def normalize(self, pixels) -> np.ndarray:
        """Normalized coordinates ``(N, 2)`` of pixels ``(N, 2)`` (undistorted if the camera
        has distortion)."""
        return self.normalize_checked(C.points("pixels", pixels, 2))

    def normalize_checked(self, uv: np.ndarray) -> np.ndarray:
        """:meth:`normalize` of a checked float ``(N, 2)`` array."""
        if self.has_distortion:
            import cv2

            xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, np.asarray(self.distortion))
            return xy.reshape(-1, 2).astype(float)
        return np.column_stack(((uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy))

    def denormalize(self, xy) -> np.ndarray:
        """Pixels ``(N, 2)`` of normalized coordinates ``(N, 2)`` (distorted if applicable)."""
        return self.denormalize_checked(C.points("xy", xy, 2))

    def denormalize_checked(self, n: np.ndarray) -> np.ndarray:
        """:meth:`denormalize` of a checked float ``(N, 2)`` array."""
        return self.project_checked(np.column_stack((n, np.ones(n.shape[0]))))

    def ray(self, pixels) -> np.ndarray:
        """Unit viewing rays ``(N, 3)`` in the camera frame through the given pixels."""
        xy = self.normalize(pixels)
        d = np.column_stack((xy, np.ones(xy.shape[0])))
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    # ------------------------------------------------------------------ visibility
    def pixels_in_image(self, pixels, margin: float = 0.0) -> np.ndarray:
        """Boolean ``(N,)``: the pixel lies at least ``margin`` pixels inside the image
        border (``[-0.5, W-0.5] x [-0.5, H-0.5]``). NaN pixels are outside."""
        uv = C.array(
            "pixels", np.atleast_2d(np.asarray(pixels, dtype=float)), (-1, 2), allow_nan=True
        )
        return self.pixels_in_image_checked(uv, C.finite_scalar("margin", margin))

    def pixels_in_image_checked(self, uv: np.ndarray, m: float) -> np.ndarray:
        """:meth:`pixels_in_image` of a checked float ``(N, 2)`` array and margin."""
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= m - 0.5)
                & (uv[:, 0] <= self.width - 0.5 - m)
                & (uv[:, 1] >= m - 0.5)
                & (uv[:, 1] <= self.height - 0.5 - m)
            )

    def in_fov(self, points_cam, margin: float = 0.0) -> np.ndarray:
        """Boolean ``(N,)``: camera-frame points between the clipping planes whose projection
        lies at least ``margin`` pixels inside the image."""
        p = C.points("points_cam", points_cam, 3)
        depth_ok = (p[:, 2] >= self.near) & (p[:, 2] <= self.far)
        return depth_ok & self.pixels_in_image(self.project(p), margin)

    def all_in_fov(self, points_cam, margin: float = 0.0) -> bool:
        """True if every point is in the field of view (see :meth:`in_fov`)."""
        return bool(np.all(self.in_fov(points_cam, margin)))


def world_to_camera(points_world, camera_pose) -> np.ndarray:
    """Camera-frame coordinates ``(N, 3)`` of world points for the camera pose ``T_wc``."""
    return points_in_camera(
        C.points("points_world", points_world, 3), C.transform("camera_pose", camera_pose)
    )


def points_in_camera(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    """:func:`world_to_camera` on checked inputs (``(N, 3)`` points, a rigid ``T_wc``)."""
    return (p - g[:3, 3]) @ g[:3, :3]


#: Paper Table II, local tip camera C_L (1024 x 1024, FoV 60 deg, f = 886.8 px).
LOCAL_CAMERA = PinholeCamera(*PV.LOCAL_CAMERA_INTRINSICS, name="C_L")

#: Paper Table II, global drone camera C_G (500 x 500, FoV 71 deg, f = 350.5 px).
GLOBAL_CAMERA = PinholeCamera(*PV.GLOBAL_CAMERA_INTRINSICS, name="C_G")
