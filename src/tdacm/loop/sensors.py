"""The sensors block: the two cameras of the TD-ACM and their imperfection models.

A :class:`CameraSensor` is a camera on a carrier frame (C_L on the rod's tip, C_G on the
drone's body) together with its front end: either a renderer and the fiducial detector
(``"planar"``/``"pybullet"``: an image, then ArUco/AprilTag detection, as on the robot) or the
``"analytic"`` front end (the target's points projected from the 3-D target: no image, no
detector; campaigns). The same imperfection models (:class:`~tdacm.loop.config.SensorModel`, the scenario's
``[sensors]`` camera keys: pixel noise, dropped frames, latency, intrinsics error) then apply to
either, so the two front ends differ only by the renderer's corner error (tested). All their
randomness comes from one ``numpy.random.Generator`` seeded by the run's seed.

Sensors read the true :class:`~.data.PlantState`; nothing after them does.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from functools import partial

import numpy as np

from ..vision import TargetDetector
from ..vision.camera import PinholeCamera, points_in_camera
from ..vision.detect import NOT_DETECTED, Detection
from ..vision.mounts import tip_camera_pose
from .config import SensorModel
from .data import CameraMeasurement, DeferredMeasurement, PlantState, SensorReadings


def perturbed_camera(camera, relative_error: float, rng: np.random.Generator):
    """A copy of ``camera`` with ``fx, fy, cx, cy`` scaled by ``1 + N(0, relative_error)``."""
    if relative_error == 0:
        return camera
    f = 1.0 + rng.normal(0.0, relative_error, 4)
    return replace(
        camera, fx=camera.fx * f[0], fy=camera.fy * f[1], cx=camera.cx * f[2], cy=camera.cy * f[3]
    )


class AnalyticFrontEnd:
    """Projects the target into the camera (ideal corners, paper order). The target counts as
    detected when all its markers' corners are in front of the camera, inside its clipping
    range and inside the image - what the detector needs to decode every marker."""

    keeps_images = False

    def __init__(self, camera: PinholeCamera, target, target_pose):
        self.camera = camera
        self.target = target
        g = np.asarray(target_pose, float)
        self._features_w = target.feature_points @ g[:3, :3].T + g[:3, 3]
        ids = tuple(getattr(target, "ids", ())) or (target.marker_id,)
        self._ids = ids
        self._corners_w = [target.corner_points(i) @ g[:3, :3].T + g[:3, 3] for i in ids]

    def reset(self) -> None:
        pass

    def detect_at(self, pose: np.ndarray) -> Detection:
        cam = self.camera
        corners = {}
        for i, pw in zip(self._ids, self._corners_w, strict=True):
            pc = points_in_camera(pw, pose)
            # cam.in_fov(pc), with the projection kept for the detection
            pix = cam.project_checked(pc)
            z = pc[:, 2]
            if np.all((z >= cam.near) & (z <= cam.far) & cam.pixels_in_image_checked(pix, 0.0)):
                corners[i] = pix
        if len(corners) < len(self._ids):
            return Detection(False, None, tuple(corners), corners)
        points = cam.project_checked(points_in_camera(self._features_w, pose))
        return Detection(True, points, tuple(corners), corners)


class RenderedFrontEnd:
    """A renderer (planar or PyBullet) and the fiducial detector, as on the real robot."""

    keeps_images = True

    def __init__(self, camera: PinholeCamera, renderer, target, track: bool = True):
        self.camera = camera
        self._renderer = renderer  # a renderer, or a callable that makes one on first use
        self.detector = TargetDetector(target, track=track)
        self._win_cam = None  # (window, camera, the camera of that window)

    @property
    def renderer(self):
        if callable(self._renderer) and not hasattr(self._renderer, "render"):
            self._renderer = self._renderer()  # e.g. PyBullet: started only when C_G is read
        return self._renderer

    def reset(self) -> None:
        self.detector.reset()

    def render(self, pose: np.ndarray, system=None, q=None, camera=None) -> np.ndarray:
        r = self.renderer
        if getattr(r, "draws_arm", False) and system is not None:
            r.set_arm(system.base_pose(q), system.backbone(q, 21))
        return r.render(self.camera if camera is None else camera, pose)

    def _window_camera(self, win) -> PinholeCamera:
        """The camera whose image is the window ``(x0, y0, x1, y1)`` of this one (same
        focal lengths, shifted principal point), kept while the window stays the same (the
        tracking window moves in steps of whole pixels, often not at all)."""
        cam = self.camera
        if self._win_cam is None or self._win_cam[0] != win or self._win_cam[1] is not cam:
            x0, y0, x1, y1 = win
            crop = replace(cam, width=x1 - x0, height=y1 - y0, cx=cam.cx - x0, cy=cam.cy - y0)
            self._win_cam = (win, cam, crop)
        return self._win_cam[2]

    def detect_at(self, pose, system, q, need_image: bool) -> tuple:
        """``(detection, image)``. While the detector tracks the target and no full image is
        needed, only its tracking window is rendered (a camera with the window's size and
        shifted principal point gives the same pixels) and searched; otherwise, or if the
        window misses, the whole image, as :meth:`TargetDetector.detect` does."""
        cam = self.camera
        win = None if need_image else self.detector.tracking_window((cam.height, cam.width))
        if win is not None and not getattr(self.renderer, "draws_arm", False):
            det = self.detector.detect_in_window(
                self.render(pose, camera=self._window_camera(win)), win
            )
            if det.found:
                return det, None
        image = self.render(pose, system, q)
        return self.detector.detect(image), image

    def close(self) -> None:
        if hasattr(self._renderer, "close"):
            self._renderer.close()


class CameraSensor:
    """One camera: carrier frame (``"tip"`` of arm ``rod``, or ``"base"``), mount ``g_C^F``,
    front end and imperfections (noise and dropouts drawn from ``rng``; latency as a FIFO of measurements).

    :meth:`measure` returns the :class:`~.data.CameraMeasurement` the controller receives now
    (captured ``latency_steps`` periods ago when the camera has latency)."""

    def __init__(
        self,
        system,
        carrier: str,
        mount: np.ndarray,
        front_end,
        imperfections: SensorModel | None = None,
        rng: np.random.Generator | None = None,
        keep_images: bool = False,
        rod: int = 0,
    ):
        if carrier not in ("tip", "base"):
            raise ValueError(f"carrier must be 'tip' or 'base', got {carrier!r}")
        self.system = system
        self.carrier = carrier
        self.mount = np.asarray(mount, float)
        self.front_end = front_end
        self.model = imperfections or SensorModel()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.keep_images = bool(keep_images)
        self.rod = int(rod)  # the arm carrying a tip camera (robots with several arms)
        self._fifo = deque(maxlen=self.model.latency_steps + 1)

    @property
    def camera(self) -> PinholeCamera:
        return self.front_end.camera

    def reset(self) -> None:
        self.front_end.reset()
        self._fifo.clear()

    def pose(self, q) -> np.ndarray:
        """Inertial pose of the camera at configuration ``q``."""
        if self.carrier == "tip":
            return tip_camera_pose(self.system, q, self.mount, self.rod)
        return self.system.base_pose(q) @ self.mount

    def ideal(self, q) -> tuple[Detection, np.ndarray | None]:
        """Detection (no imperfections) and image (``None`` for the analytic front end)."""
        pose = self.pose(q)
        fe = self.front_end
        if isinstance(fe, AnalyticFrontEnd):
            return fe.detect_at(pose), None
        return fe.detect_at(pose, self.system, q, self.keep_images)

    def _imperfect(self, det: Detection) -> Detection:
        m = self.model
        if m.dropout > 0 and self.rng.random() < m.dropout:
            return NOT_DETECTED
        if not det.found or m.pixel_noise == 0:
            return det
        s = m.pixel_noise
        points = det.points + self.rng.normal(0.0, s, det.points.shape)
        corners = {k: v + self.rng.normal(0.0, s, np.shape(v)) for k, v in det.corners.items()}
        return Detection(True, points, det.ids, corners)

    def measure(self, state: PlantState) -> CameraMeasurement:
        det, image = self.ideal(state.q)
        det = self._imperfect(det)
        meas = CameraMeasurement(state.t, det, image if self.keep_images else None)
        if self.model.latency_steps == 0:
            return meas
        self._fifo.append(meas)
        return self._fifo[0]

    def close(self) -> None:
        close = getattr(self.front_end, "close", None)
        if close is not None:
            close()


class Sensors:
    """The sensors block: C_L every period; C_G offered to the servo every ``global_every``
    periods (0: never) and whenever the servo asks for it (``request_global``), rendered only if
    the servo reads it (:class:`~.data.DeferredMeasurement`); C_G rendered for the outputs every
    ``global_output_every`` periods (0: never), or every period when ``always_global`` (video).
    ``other`` sensors (name -> object with ``measure(state)``) are read every period."""

    def __init__(
        self,
        local: CameraSensor,
        global_: CameraSensor | None = None,
        global_every: int = 1,
        always_global: bool = False,
        other: dict | None = None,
        global_output_every: int = 0,
    ):
        self.local = local
        self.global_ = global_
        self.global_every = int(global_every)
        self.global_output_every = int(global_output_every)
        self.always_global = bool(always_global)
        self.other = dict(other or {})
        self._k = 0

    def reset(self) -> None:
        self._k = 0
        self.local.reset()
        if self.global_ is not None:
            self.global_.reset()
        for s in self.other.values():
            getattr(s, "reset", lambda: None)()

    def first_look(self, t: float, q) -> CameraMeasurement:
        """An ideal C_L measurement at configuration ``q`` (no imperfections, no noise drawn),
        leaving C_L as it was reset: the view a run starts from (initial mode) or the
        reference snapshot is taken from."""
        det, _ = self.local.ideal(q)
        self.local.reset()
        return CameraMeasurement(t, det)

    def read(self, state: PlantState, request_global: bool = False) -> SensorReadings:
        k = self._k
        self._k += 1
        local = self.local.measure(state)
        glob = out = None
        g = self.global_
        if g is not None:
            every, out_every = self.global_every, self.global_output_every
            offered = (
                self.always_global or request_global or (every > 0 and k % every == 0)
            )  # fmt: skip
            if offered:
                glob = DeferredMeasurement(state.t, partial(g.measure, state))
            if self.always_global or (out_every > 0 and k % out_every == 0):
                out = glob.value() if glob is not None else g.measure(state)
        other = {name: s.measure(state) for name, s in self.other.items()}
        return SensorReadings(state.t, local, glob, other, out)

    def close(self) -> None:
        self.local.close()
        if self.global_ is not None:
            self.global_.close()
