"""PyBullet scene renderer (headless ``DIRECT`` client, TinyRenderer or the EGL plugin).

Scene: a ground plane, the ``cube_small`` box scaled to ``SceneConfig.box_size``, the target
as a textured quad mesh on its top, and optionally the TD-ACM: the drone as a ``+`` frame
(body box, two arms, four rotor discs) and the rod as a chain of capsules. All bodies are
created once; :meth:`PyBulletRenderer.set_arm` only moves them with
``resetBasePositionAndOrientation``.

Projection built exactly from the intrinsics (``docs/vision.md``): row-major

    P = [[2fx/W, 0, 1 - 2cx'/W, 0], [0, 2fy/H, 2cy'/H - 1, 0],
         [0, 0, -(f+n)/(f-n), -2fn/(f-n)], [0, 0, -1, 0]]

passed column-major (``P.T.ravel()``), view matrix ``inv(T_wc @ diag(1, -1, -1, 1))``. OpenGL
puts pixel centres at half-integers and OpenCV at integers, hence ``cx' = cx + 0.5`` and
``cy' = cy + 0.5`` for the EGL plugin (measured exact to 0.02 px). TinyRenderer samples at
integer pixel positions and puts rows one pixel low (rendered row = v - 1, measured), so it
takes ``cx' = cx``, ``cy' = cy + 1`` (measured: area centroids of rasterized polygons within
0.03 px of the analytic ones; the tests check rendered marker corners at sub-pixel level).

TinyRenderer has no anti-aliasing: an edge aligned with the pixel grid is quantized to a pixel
boundary (up to half a pixel off); edges at other angles are recovered to ~0.1 px by the
detector's edge fit. The :class:`~.planar.PlanarRenderer` is anti-aliased.

Textures: TinyRenderer takes the texture from ``changeVisualShape(textureUniqueId=...)``; the
EGL plugin reads it from the mesh's ``.mtl`` file, so both are provided (files written once
to a private temporary directory, removed by :meth:`close`).
"""

from __future__ import annotations

import os
import shutil
import tempfile

import cv2
import numpy as np

from .. import _checks as C
from ..camera import PinholeCamera
from ..scene import CUBE_SMALL_SIZE, ArmStyle, SceneConfig
from .base import Renderer, backbone_positions, check_render_args, resample_polyline

#: Default drawing of the TD-ACM.
DEFAULT_ARM = ArmStyle()

#: Backends: TinyRenderer (CPU rasterizer inside pybullet) and the bundled EGL plugin.
BACKENDS = ("tiny", "egl")

# Extra pixel offsets (du, dv) added to the principal point for each backend so that the
# rendered image follows the OpenCV pixel convention (measured, see module docstring).
_BACKEND_OFFSETS = {"tiny": (0.0, 1.0), "egl": (0.5, 0.5)}

_HIDDEN = (0.0, 0.0, -1000.0)

#: Largest image the EGL plugin renders without resampling (its framebuffer), (W, H).
EGL_MAX_TILE = (1024, 768)

#: The EGL plugin's depth buffer has 16 bits here: its near plane is raised to this value (m)
#: so that the target (``SceneConfig.target_lift`` above the box) does not z-fight with the
#: box top at the global camera's distances (Table II's 0.01 m would give ~3 cm depth steps
#: at 4.5 m). Nothing the cameras look at is closer than this.
EGL_MIN_NEAR = 0.1

#: Light direction (towards the light), shared with the planar renderer.
LIGHT_DIRECTION = (0.3, 0.2, 1.0)


#: The process that loaded the EGL plugin (a forked child sees its parent's id here).
_egl_pid: int | None = None


def projection_matrix(camera: PinholeCamera, du: float = 0.5, dv: float = 0.5) -> np.ndarray:
    """4x4 OpenGL projection (row-major) of ``camera``, principal point shifted by
    ``(du, dv)`` pixels (0.5 converts OpenCV to OpenGL pixel centres)."""
    w, h, n, f = camera.width, camera.height, camera.near, camera.far
    cx, cy = camera.cx + du, camera.cy + dv
    return np.array(
        [
            [2 * camera.fx / w, 0.0, 1.0 - 2 * cx / w, 0.0],
            [0.0, 2 * camera.fy / h, 2 * cy / h - 1.0, 0.0],
            [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def view_matrix(camera_pose: np.ndarray) -> np.ndarray:
    """4x4 OpenGL view matrix (row-major) of a camera pose ``T_wc`` (x right, y down)."""
    return np.linalg.inv(camera_pose @ np.diag([1.0, -1.0, -1.0, 1.0]))


def _flush_c_stdio() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


class _quiet_stdout:
    """Keep pybullet's C-level writes (its build time at import, the EGL plugin's 12-line GL
    banner, ``Destroy EGL OpenGL window.``) off the program's output for a while: dropped
    (file descriptors 1 and 2 on ``/dev/null``), or sent to stderr when the ``tdacm`` logger
    shows debug messages (``tdacm -v``). So stdout carries only the program's own output
    (``tdacm run ... | python -m json.tool``) and ``tdacm -q`` prints no banner."""

    def __enter__(self):
        import logging
        import sys

        sys.stdout.flush()
        sys.stderr.flush()
        self._saved = []
        verbose = logging.getLogger("tdacm").isEnabledFor(logging.DEBUG)
        try:
            null = None if verbose else os.open(os.devnull, os.O_WRONLY)
            for fd, target in ((1, 2),) if verbose else ((1, null), (2, null)):
                self._saved.append((fd, os.dup(fd)))
                os.dup2(target, fd)
            if null is not None:
                os.close(null)
        except OSError:
            self.__exit__()
        return self

    def __exit__(self, *exc):
        if self._saved:
            _flush_c_stdio()  # C's stdout buffer (a pipe is block-buffered) goes along
        for fd, saved in reversed(self._saved):
            os.dup2(saved, fd)
            os.close(saved)
        self._saved = []


def _quat(r: np.ndarray) -> list:
    """Quaternion ``[x, y, z, w]`` (pybullet's order) of a rotation matrix."""
    r = np.asarray(r, dtype=float)
    tr = np.trace(r)
    if tr > 0.0:
        k = 2.0 * np.sqrt(1.0 + tr)
        q = [(r[2, 1] - r[1, 2]) / k, (r[0, 2] - r[2, 0]) / k, (r[1, 0] - r[0, 1]) / k, k / 4]
    else:
        i = int(np.argmax(np.diag(r)))
        j, m = (i + 1) % 3, (i + 2) % 3
        k = 2.0 * np.sqrt(max(1.0 + r[i, i] - r[j, j] - r[m, m], 1e-300))
        q = [0.0, 0.0, 0.0, (r[m, j] - r[j, m]) / k]
        q[i] = k / 4
        q[j] = (r[j, i] + r[i, j]) / k
        q[m] = (r[m, i] + r[i, m]) / k
    q = np.asarray(q)
    return list(q / np.linalg.norm(q))


def _z_to(d: np.ndarray) -> np.ndarray:
    """Quaternions ``(n, 4)`` (x, y, z, w) of the shortest rotations taking +z to the unit
    directions ``d`` (n, 3)."""
    # q = [z x d, 1 + z.d] normalized (half-angle form); d = -z handled by a 180 deg turn
    q = np.column_stack((-d[:, 1], d[:, 0], np.zeros(len(d)), 1.0 + d[:, 2]))
    back = q[:, 3] < 1e-9
    q[back] = [1.0, 0.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


class PyBulletRenderer(Renderer):
    """Renders :class:`SceneConfig` (and the TD-ACM) with PyBullet.

    Parameters
    ----------
    scene:
        Static scene (default :class:`SceneConfig()`).
    arm:
        Drawing style of the TD-ACM, or ``None`` not to create it.
    backend:
        ``"tiny"`` (TinyRenderer, default: deterministic, no GL needed), ``"egl"`` (the
        bundled EGL plugin, software GL here; faster at high resolution) or ``"auto"``
        (EGL if it loads and is free, else tiny). Only one renderer per process may hold
        the EGL plugin at a time: with two live EGL clients pybullet segfaults as soon as
        one disconnects, so a second ``"egl"`` renderer raises ``RuntimeError``.
    light:
        TinyRenderer lighting ``(ambient, diffuse, specular)`` coefficients.
    """

    draws_arm = True

    #: id of the renderer holding the EGL plugin (one per process, see ``__init__``)
    _egl_owner = None

    def __init__(
        self,
        scene: SceneConfig | None = None,
        arm: ArmStyle | None = DEFAULT_ARM,
        backend: str = "tiny",
        light=(0.65, 0.35, 0.0),
    ):
        with _quiet_stdout():  # pybullet prints its build time when first imported
            import pybullet as p

        self._p = p
        self.scene = SceneConfig() if scene is None else scene
        if not isinstance(self.scene, SceneConfig):
            raise ValueError(f"scene must be a SceneConfig, got {scene!r}")
        if arm is not None and not isinstance(arm, ArmStyle):
            raise ValueError(f"arm must be an ArmStyle or None, got {arm!r}")
        if backend not in (*BACKENDS, "auto"):
            raise ValueError(f"backend must be one of {(*BACKENDS, 'auto')}, got {backend!r}")
        self.arm = arm
        self.light = tuple(C.array("light", light, (3,)))
        self._tmp = tempfile.mkdtemp(prefix="tdacm_vision_")
        with _quiet_stdout():
            self._cid = p.connect(p.DIRECT)
        self._plugin = None
        self.backend = "tiny"
        if backend in ("egl", "auto") and PyBulletRenderer._egl_owner is not None:
            if backend == "egl":
                self.close()
                raise RuntimeError(
                    "another PyBulletRenderer uses the EGL plugin in this process; close it "
                    "first (two live EGL clients crash pybullet when one disconnects)"
                )
            backend = "tiny"
        if backend in ("egl", "auto") and _egl_pid not in (None, os.getpid()):
            # EGL (Mesa) was loaded by a parent of this forked process: Mesa's state crossed
            # the fork without its threads, and loading it again here can deadlock
            if backend == "egl":
                self.close()
                raise RuntimeError(
                    "the EGL renderer was loaded before this process was forked; use the "
                    "'tiny' backend or the 'spawn' start method (e.g. AsyncVectorEnv(..., "
                    "context='spawn'))"
                )
            backend = "tiny"
        if backend in ("egl", "auto"):
            ok = self._load_egl()
            if not ok and backend == "egl":
                self.close()
                raise RuntimeError("the pybullet EGL renderer plugin could not be loaded")
            self.backend = "egl" if ok else "tiny"
        self._build_static()
        self._drone = None
        self._rod = []
        if arm is not None:
            self._build_arm(arm)
        self.set_arm(None, None)

    # ------------------------------------------------------------------ construction
    def _load_egl(self) -> bool:
        p = self._p
        import importlib.util

        spec = importlib.util.find_spec("eglRenderer")  # bundled with the pybullet wheel
        if spec is None or spec.origin is None:
            return False
        with _quiet_stdout():  # the plugin prints its GL banner from C
            plugin = p.loadPlugin(spec.origin, "_eglRendererPlugin", physicsClientId=self._cid)
        if plugin < 0:
            return False
        self._plugin = plugin
        PyBulletRenderer._egl_owner = id(self)
        global _egl_pid
        _egl_pid = os.getpid()
        return True

    def _build_static(self):
        p, cid, sc = self._p, self._cid, self.scene
        import pybullet_data

        g = 0.5 * sc.ground_size
        vs = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=[g, g, 0.005],
            rgbaColor=list(sc.ground_rgba),
            physicsClientId=cid,
        )
        p.createMultiBody(0, -1, vs, [0.0, 0.0, -0.005], physicsClientId=cid)
        # the paper's box: pybullet_data's cube_small.urdf, scaled
        urdf = os.path.join(pybullet_data.getDataPath(), "cube_small.urdf")
        box = p.loadURDF(
            urdf,
            list(sc.box_pose[:3, 3]),
            useFixedBase=True,
            globalScaling=sc.box_size / CUBE_SMALL_SIZE,
            physicsClientId=cid,
        )
        p.changeVisualShape(box, -1, rgbaColor=list(sc.box_rgba), physicsClientId=cid)
        self._box = box
        self._target = self._make_textured_quad("target", sc.target.texture(), sc.target.board_size)
        tp = sc.target_pose
        p.resetBasePositionAndOrientation(
            self._target, list(tp[:3, 3]), _quat(tp[:3, :3]), physicsClientId=cid
        )

    def _make_textured_quad(self, name: str, texture: np.ndarray, size) -> int:
        """A quad in the local xy plane (x right, y down as the texture is read), visible
        from -z, with the texture mapped on it exactly (corners to corners)."""
        p, cid = self._p, self._cid
        w, h = size
        png = os.path.join(self._tmp, f"{name}.png")
        rgb = cv2.cvtColor(texture, cv2.COLOR_GRAY2BGR) if texture.ndim == 2 else texture
        cv2.imwrite(png, rgb)
        with open(os.path.join(self._tmp, f"{name}.mtl"), "w") as fh:
            fh.write(f"newmtl {name}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {name}.png\n")
        # vt: v = 1 at the texture's top row (OBJ convention)
        obj = (
            f"mtllib {name}.mtl\no {name}\n"
            f"v {-w / 2} {-h / 2} 0\nv {w / 2} {-h / 2} 0\nv {w / 2} {h / 2} 0\n"
            f"v {-w / 2} {h / 2} 0\n"
            "vt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\nvn 0 0 -1\n"
            f"usemtl {name}\nf 1/1/1 3/3/1 2/2/1\nf 1/1/1 4/4/1 3/3/1\n"
        )
        path = os.path.join(self._tmp, f"{name}.obj")
        with open(path, "w") as fh:
            fh.write(obj)
        vs = p.createVisualShape(
            p.GEOM_MESH, fileName=path, meshScale=[1, 1, 1], physicsClientId=cid
        )
        body = p.createMultiBody(0, -1, vs, [0.0, 0.0, 0.0], physicsClientId=cid)
        tex = p.loadTexture(png, physicsClientId=cid)
        p.changeVisualShape(
            body, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid
        )
        return body

    def _build_arm(self, arm: ArmStyle):
        p, cid = self._p, self._cid
        bx, by, bz = arm.body_size
        half = 0.5 * arm.span
        shapes = [p.GEOM_BOX, p.GEOM_BOX, p.GEOM_BOX]
        kw = {
            "halfExtents": [[bx / 2, by / 2, bz / 2], [half, 0.015, 0.01], [0.015, half, 0.01]],
            "radii": [0, 0, 0],
            "lengths": [0, 0, 0],
            "visualFramePositions": [[0, 0, 0], [0, 0, 0], [0, 0, 0]],
            "rgbaColors": [list(arm.drone_rgba)] * 3,
        }
        for x, y in ((half, 0.0), (0.0, half), (-half, 0.0), (0.0, -half)):
            shapes.append(p.GEOM_CYLINDER)
            kw["halfExtents"].append([0, 0, 0])
            kw["radii"].append(arm.rotor_disc_radius)
            kw["lengths"].append(0.01)
            kw["visualFramePositions"].append([x, y, 0.03])
            kw["rgbaColors"].append(list(arm.rotor_rgba))
        vs = p.createVisualShapeArray(shapeTypes=shapes, physicsClientId=cid, **kw)
        self._drone = p.createMultiBody(0, -1, vs, list(_HIDDEN), physicsClientId=cid)
        # per-shape colours are not always honoured by createVisualShapeArray: set them
        p.changeVisualShape(self._drone, -1, rgbaColor=list(arm.drone_rgba), physicsClientId=cid)
        # the capsules are created at the first set_arm call, when the segment length is known
        self._rod = []
        self._rod_length = None

    # ------------------------------------------------------------------ Renderer API
    def set_arm(self, base_pose=None, backbone=None) -> None:
        p, cid = self._p, self._cid
        if self.arm is None:
            return
        if base_pose is None:
            p.resetBasePositionAndOrientation(
                self._drone, _HIDDEN, [0, 0, 0, 1], physicsClientId=cid
            )
        else:
            g = C.transform("base_pose", base_pose)
            p.resetBasePositionAndOrientation(
                self._drone, list(g[:3, 3]), _quat(g[:3, :3]), physicsClientId=cid
            )
        if backbone is None:
            for b in self._rod:
                p.resetBasePositionAndOrientation(b, _HIDDEN, [0, 0, 0, 1], physicsClientId=cid)
            return
        pts = resample_polyline(backbone_positions(backbone), self.arm.segments + 1)
        d = np.diff(pts, axis=0)
        seg = np.linalg.norm(d, axis=1)
        # a capsule's length is fixed at creation: the shapes are (re)built only when the
        # segment length changes (once for an inextensible rod), otherwise only moved
        self._ensure_rod_length(float(np.mean(seg)))
        dirs = d / np.maximum(seg, 1e-12)[:, None]
        quats = _z_to(dirs)
        mids = 0.5 * (pts[1:] + pts[:-1])
        for b, m, q in zip(self._rod, mids, quats, strict=True):
            p.resetBasePositionAndOrientation(b, list(m), list(q), physicsClientId=cid)

    def _ensure_rod_length(self, length: float):
        if self._rod_length is not None and abs(length - self._rod_length) < 1e-3 * length:
            return
        p, cid = self._p, self._cid
        for b in self._rod:
            p.removeBody(b, physicsClientId=cid)
        self._rod = []
        cyl = max(length, 1e-4)  # cylinder part; the hemispherical caps overlap the joints
        for _ in range(self.arm.segments):
            cs = p.createVisualShape(
                p.GEOM_CAPSULE,
                radius=self.arm.rod_radius,
                length=cyl,
                rgbaColor=list(self.arm.rod_rgba),
                physicsClientId=cid,
            )
            self._rod.append(p.createMultiBody(0, -1, cs, list(_HIDDEN), physicsClientId=cid))
        self._rod_length = length

    def render(self, camera: PinholeCamera, camera_pose: np.ndarray, depth: bool = False):
        """RGB image (and metric depth ``(H, W)`` in metres if ``depth``)."""
        g = check_render_args(camera, camera_pose)
        if camera.has_distortion:
            raise ValueError("PyBulletRenderer renders ideal pinhole cameras (no distortion)")
        view = list(view_matrix(g).T.ravel())
        if self.backend == "tiny":
            return self._render_tile(camera, view, 0, 0, camera.width, camera.height, depth)
        with _quiet_stdout():  # the EGL plugin prints "ven = Mesa/X.org" from C on stdout
            return self._render_egl(camera, view, depth)

    def _render_egl(self, camera, view, depth):
        # EGL: its framebuffer is 1024 x 768; larger images come back resampled (measured
        # offsets of 0.3-0.5 px), so they are rendered in tiles that fit and stitched.
        rgb = np.empty((camera.height, camera.width, 3), np.uint8)
        z = np.empty((camera.height, camera.width)) if depth else None
        for y0 in range(0, camera.height, EGL_MAX_TILE[1]):
            for x0 in range(0, camera.width, EGL_MAX_TILE[0]):
                tw = min(EGL_MAX_TILE[0], camera.width - x0)
                th = min(EGL_MAX_TILE[1], camera.height - y0)
                out = self._render_tile(camera, view, x0, y0, tw, th, depth)
                if depth:
                    rgb[y0 : y0 + th, x0 : x0 + tw] = out[0]
                    z[y0 : y0 + th, x0 : x0 + tw] = out[1]
                else:
                    rgb[y0 : y0 + th, x0 : x0 + tw] = out
        return (rgb, z) if depth else rgb

    def _render_tile(self, camera, view, x0, y0, tw, th, depth):
        """Render the window ``[x0, x0+tw) x [y0, y0+th)`` of ``camera``'s image."""
        p = self._p
        du, dv = _BACKEND_OFFSETS[self.backend]
        near = camera.near if self.backend == "tiny" else max(camera.near, EGL_MIN_NEAR)
        tile = PinholeCamera(
            tw, th, camera.fx, camera.fy, camera.cx - x0, camera.cy - y0, near, camera.far
        )
        proj = projection_matrix(tile, du, dv)
        renderer = p.ER_TINY_RENDERER if self.backend == "tiny" else p.ER_BULLET_HARDWARE_OPENGL
        amb, dif, spec = self.light
        out = p.getCameraImage(
            tw,
            th,
            viewMatrix=view,
            projectionMatrix=list(proj.T.ravel()),
            renderer=renderer,
            shadow=0,
            lightDirection=list(LIGHT_DIRECTION),
            lightAmbientCoeff=amb,
            lightDiffuseCoeff=dif,
            lightSpecularCoeff=spec,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._cid,
        )
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(th, tw, 4)
        rgb = np.ascontiguousarray(rgba[:, :, :3])
        if not depth:
            return rgb
        zb = np.asarray(out[3], dtype=float).reshape(th, tw)
        n, f = near, camera.far
        return rgb, f * n / (f - (f - n) * zb)

    def close(self) -> None:
        p = self._p
        if getattr(self, "_cid", None) is not None:
            try:
                with _quiet_stdout():
                    if self._plugin is not None:
                        p.unloadPlugin(self._plugin, physicsClientId=self._cid)
                        PyBulletRenderer._egl_owner = None
                        self._plugin = None
                    p.disconnect(physicsClientId=self._cid)
            except p.error:
                pass
            self._cid = None
        if getattr(self, "_tmp", None):
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
