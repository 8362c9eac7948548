"""Fast renderer for the planar scene (OpenCV homographies), for the local camera loop.

Everything the tip camera C_L looks at in :class:`~tdacm.vision.scene.SceneConfig` is planar:
the ground, the box faces and the target on the box top. This renderer draws them exactly
from the pinhole model:

* ground and box faces: polygons clipped at the near plane (Sutherland-Hodgman), projected
  and filled with anti-aliased edges (``cv2.fillPoly``, 1/16 px vertex precision), flat
  Lambert shading with the same light direction as the PyBullet renderer;
* the target: its texture warped with the plane-induced homography
  ``H = K [r1 r2 t] A`` (``A`` maps texel centres to target-plane metres) into the bounding
  box of its projection only, with bilinear interpolation from a pre-filtered texture level
  (area-averaged "mipmaps") whose texels are about one image pixel, so the marker is neither
  aliased nor blurred.

It does not draw the TD-ACM (:attr:`draws_arm` is ``False``): the tip camera looks along the
backbone, away from the arm, so for C_L nothing is lost; use
:class:`~tdacm.vision.render.pybullet_renderer.PyBulletRenderer` for the global camera C_G,
which must see the arm. The far clipping plane is not applied (the ground is drawn to its
edge). At Table II's 1024 x 1024 it renders in a few milliseconds, which is what lets the
local camera loop fit the paper's 20 ms control period (see ``docs/vision.md``).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..scene import SceneConfig
from .base import Renderer, check_render_args

_LIGHT = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
_SHIFT = 4  # fixed-point bits for cv2.fillPoly


def clip_near(poly: np.ndarray, near: float) -> np.ndarray:
    """Clip a camera-frame polygon ``(n, 3)`` to the half-space ``Z >= near``."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            out.append(a)
        if ina != inb:
            t = (near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out) if out else np.zeros((0, 3))


class PlanarRenderer(Renderer):
    """Homography renderer of the planar scene (ground, box, target); see module docstring.

    Parameters
    ----------
    scene:
        Static scene (default :class:`SceneConfig()`).
    light:
        ``(ambient, diffuse)`` shading coefficients.
    sky_rgb:
        Colour above the horizon.
    grayscale:
        Render 8-bit grey images ``(H, W)`` (the luma of the colours; the detector works on grey
        images anyway, and a third of the pixels to write makes the closed loop faster).
    """

    draws_arm = False

    def __init__(
        self,
        scene: SceneConfig | None = None,
        light=(0.65, 0.35),
        sky_rgb=(170, 190, 215),
        grayscale: bool = False,
    ):
        self.grayscale = bool(grayscale)
        self.scene = SceneConfig() if scene is None else scene
        if not isinstance(self.scene, SceneConfig):
            raise ValueError(f"scene must be a SceneConfig, got {scene!r}")
        self.ambient, self.diffuse = (float(v) for v in light)
        self.sky = self._colour(tuple(int(c) for c in sky_rgb))
        self._bg = {}
        sc = self.scene
        g = sc.ground_size / 2
        self._ground = np.array([[-g, -g, 0.0], [g, -g, 0.0], [g, g, 0.0], [-g, g, 0.0]])
        self._faces = self._box_faces()
        tex = sc.target.texture()
        self._board = sc.target.board_size
        self._target_pose = sc.target_pose
        # target faces up: its outward normal is -z of the target frame
        n_t = -self._target_pose[:3, 2]
        shade = self.ambient + self.diffuse * max(0.0, float(n_t @ _LIGHT))
        self._levels = []
        level = tex
        while True:
            rgb = np.clip(level.astype(np.float32) * shade, 0, 255).astype(np.uint8)
            self._levels.append(rgb if self.grayscale else cv2.cvtColor(rgb, cv2.COLOR_GRAY2RGB))
            if min(level.shape) < 16:
                break
            h, w = level.shape
            level = cv2.resize(
                level, (max(1, round(w / 2)), max(1, round(h / 2))), interpolation=cv2.INTER_AREA
            )

    def _background(self, h: int, w: int) -> np.ndarray:
        """A sky-coloured image (cached per size: copying is 30x faster than filling)."""
        bg = self._bg.get((h, w))
        if bg is None:
            bg = np.empty((h, w) if self.grayscale else (h, w, 3), np.uint8)
            cv2.rectangle(bg, (0, 0), (w - 1, h - 1), self.sky, -1)
            self._bg = {(h, w): bg}
        return bg.copy()

    def _colour(self, rgb: tuple) -> tuple:
        """An RGB colour, or its luma (ITU-R BT.601, as ``cv2.cvtColor``) when grey."""
        if not self.grayscale:
            return rgb
        return (int(round(0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2])),)

    def _shade(self, rgba, normal) -> tuple:
        k = self.ambient + self.diffuse * max(0.0, float(normal @ _LIGHT))
        return self._colour(tuple(int(round(min(255.0, 255.0 * c * k))) for c in rgba[:3]))

    def _box_faces(self):
        sc = self.scene
        c = sc.box_pose[:3, 3]
        h = sc.box_size / 2
        faces = []
        for axis in range(3):
            for sign in (1.0, -1.0):
                if axis == 2 and sign < 0:
                    continue  # bottom face rests on the ground
                n = np.zeros(3)
                n[axis] = sign
                u = np.zeros(3)
                u[(axis + 1) % 3] = h
                v = np.zeros(3)
                v[(axis + 2) % 3] = h
                fc = c + sign * h * n
                poly = np.array([fc - u - v, fc + u - v, fc + u + v, fc - u + v])
                faces.append((poly, n, self._shade(sc.box_rgba, n)))
        return faces

    # ------------------------------------------------------------------ drawing
    @staticmethod
    def _to_cam(points, g_cw):
        return points @ g_cw[:3, :3].T + g_cw[:3, 3]

    @staticmethod
    def _clip_project(camera, poly_cam):
        """A camera-frame polygon clipped at the near plane and its pixels; ``(poly, None)`` if
        fewer than three vertices are left."""
        poly = clip_near(poly_cam, camera.near)
        if len(poly) < 3:
            return poly, None
        uv = np.column_stack(
            (
                camera.fx * poly[:, 0] / poly[:, 2] + camera.cx,
                camera.fy * poly[:, 1] / poly[:, 2] + camera.cy,
            )
        )
        return poly, uv

    def _fill(self, img, camera, poly_cam, color):
        _, uv = self._clip_project(camera, poly_cam)
        if uv is None:
            return
        lim = 1e6  # keep fixed-point coordinates inside int32
        pts = np.round(np.clip(uv, -lim, lim) * (1 << _SHIFT)).astype(np.int32)
        cv2.fillPoly(img, [pts], color, lineType=cv2.LINE_AA, shift=_SHIFT)

    def render(self, camera: PinholeCamera, camera_pose: np.ndarray) -> np.ndarray:
        g_wc = check_render_args(camera, camera_pose)
        if camera.has_distortion:
            raise ValueError("PlanarRenderer renders ideal pinhole cameras (no distortion)")
        g_cw = np.linalg.inv(g_wc)
        eye = g_wc[:3, 3]
        img = self._background(camera.height, camera.width)
        sc = self.scene
        if eye[2] > 0.0:
            self._fill(
                img,
                camera,
                self._to_cam(self._ground, g_cw),
                self._shade(sc.ground_rgba, np.array([0.0, 0.0, 1.0])),
            )
        for poly, n, color in self._faces:
            if n @ (eye - poly.mean(axis=0)) > 0.0:
                self._fill(img, camera, self._to_cam(poly, g_cw), color)
        self._draw_target(img, camera, g_cw)
        return img

    def _draw_target(self, img, camera, g_cw):
        g_ct = g_cw @ self._target_pose  # target frame in the camera frame
        normal_cam = -g_ct[:3, 2]  # outward normal
        if normal_cam @ (-g_ct[:3, 3]) <= 0.0:
            return  # seen from behind
        w, h = self._board
        corners = np.array(
            [[-w / 2, -h / 2, 0.0], [w / 2, -h / 2, 0.0], [w / 2, h / 2, 0.0], [-w / 2, h / 2, 0.0]]
        )
        cam_pts = corners @ g_ct[:3, :3].T + g_ct[:3, 3]
        poly, uv = self._clip_project(camera, cam_pts)
        if uv is None:
            return
        x0 = int(max(0, np.floor(uv[:, 0].min()) - 1))
        y0 = int(max(0, np.floor(uv[:, 1].min()) - 1))
        x1 = int(min(camera.width, np.ceil(uv[:, 0].max()) + 2))
        y1 = int(min(camera.height, np.ceil(uv[:, 1].max()) + 2))
        if x1 <= x0 or y1 <= y0:
            return
        # texture level with texels of about one image pixel at the nearest corner
        z_min = max(float(poly[:, 2].min()), camera.near)
        level = 0
        for k in range(len(self._levels)):
            texel = w / self._levels[k].shape[1]
            if camera.fx * texel / z_min <= 1.0 or k == 0:
                level = k
            else:
                break
        tex = self._levels[level]
        th, tw = tex.shape[:2]
        # A: texel (col, row) centre -> target-plane metres
        a = np.array(
            [
                [w / tw, 0.0, -w / 2 + 0.5 * w / tw],
                [0.0, h / th, -h / 2 + 0.5 * h / th],
                [0.0, 0.0, 1.0],
            ]
        )
        rt = np.column_stack((g_ct[:3, 0], g_ct[:3, 1], g_ct[:3, 3]))
        k_roi = camera.K.copy()
        k_roi[0, 2] -= x0
        k_roi[1, 2] -= y0
        hom = k_roi @ rt @ a
        roi = img[y0:y1, x0:x1]
        whole = len(poly) == 4 and np.all(cam_pts[:, 2] >= camera.near)
        # partly behind the near plane: warp into a copy, then keep only the clipped polygon
        warped = roi if whole else roi.copy()
        cv2.warpPerspective(
            tex,
            hom,
            (x1 - x0, y1 - y0),
            dst=warped,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )
        if whole:
            return
        mask = np.zeros(roi.shape[:2], np.uint8)
        pts = np.round((uv - [x0, y0]) * (1 << _SHIFT)).astype(np.int32)
        cv2.fillPoly(mask, [pts], 255, shift=_SHIFT)
        np.copyto(roi, warped, where=(mask > 0) if roi.ndim == 2 else (mask[:, :, None] > 0))
