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

from dataclasses import replace
from functools import partial
from typing import NamedTuple

import numpy as np
from numba import njit

from ..vision import TargetDetector
from ..vision.camera import CameraParams, PinholeCamera, in_image, project_world
from ..vision.detect import NOT_DETECTED, Detection
from ..vision.mounts import base_pose_into, mul4, rod_steps, tip_camera_pose_into
from .config import CamerasConfig, SensorModel
from .data import CameraMeasurement, DeferredMeasurement, PlantState, SensorReadings

# ----------------------------------------------------------------------------- compiled step
_NO_CAMERA = CameraParams(1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 1.0)
_NO_ROD = np.zeros(2, np.int64)
_NO_CORNERS = np.zeros((1, 4, 3))


class CameraSensorParams(NamedTuple):
    """A camera sensor's parameters (the record of its compiled step): the true camera
    ``camera`` (:class:`~tdacm.vision.camera.CameraParams`), its carrier (``on_tip``: the tip
    of the rod of Magnus steps ``rod`` (2,), else the drone's body), its mount ``g_C^F``
    (4, 4); the analytic front end's target in the world: every marker's corners ``corners``
    (M, 4, 3) and the feature points ``features`` (4, 3); the imperfections ``pixel_noise``
    (px), ``dropout`` (probability) and ``latency`` (frames)."""

    camera: CameraParams
    on_tip: bool
    rod: np.ndarray
    mount: np.ndarray
    corners: np.ndarray
    features: np.ndarray
    pixel_noise: float
    dropout: float
    latency: int


class CameraSensorState(NamedTuple):
    """A camera sensor's latency buffer: ``latency + 1`` frames (pixels ``uv`` (L, 4, 2),
    markers' corners ``corners`` (L, M, 4, 2), ``found`` (L,), the capture period
    ``capture`` (L,)) as a ring from ``head`` with ``count`` frames."""

    uv: np.ndarray
    corners: np.ndarray
    found: np.ndarray
    capture: np.ndarray
    head: np.ndarray
    count: np.ndarray

    @classmethod
    def empty(cls, p: CameraSensorParams, latency: int | None = None) -> CameraSensorState:
        """An empty buffer for ``latency`` frames (default the record's; larger for a batch
        whose worlds have other latencies)."""
        cap = int(p.latency if latency is None else latency) + 1
        m = p.corners.shape[0]
        return cls(np.zeros((cap, 4, 2)), np.zeros((cap, m, 4, 2)), np.zeros(cap, np.bool_),
                   np.zeros(cap, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64))  # fmt: skip


@njit(cache=True)
def camera_pose_into(p, m, q, out):
    """The camera's world pose at ``q``: ``g_L(q) g_C^L`` on a tip, ``g_b(q) g_C^b`` on the
    drone."""
    if p.on_tip:
        tip_camera_pose_into(q, m, p.rod, p.mount, out)
    else:
        g_b = np.empty((4, 4))
        base_pose_into(q, m, g_b)
        mul4(g_b, p.mount, out)


@njit(cache=True)
def analytic_detect(p, g_c, out_uv, out_corners, out_seen):
    """The analytic front end (:class:`AnalyticFrontEnd`) of the camera at the world pose
    ``g_c``: a marker is seen (``out_seen`` (M,), its corners' pixels in ``out_corners``
    (M, 4, 2)) when its four corners lie between the clipping planes and inside the image (the
    detector needs each marker whole); the target is detected (True, the feature points'
    pixels in ``out_uv`` (4, 2)) when every marker is seen."""
    c = p.camera
    px = np.empty(2)
    every = True
    for mk in range(p.corners.shape[0]):
        ok = True
        for k in range(4):
            z = project_world(c, g_c, p.corners[mk, k], px)
            if not (z > 0.0 and z >= c.near and z <= c.far and in_image(c, px[0], px[1], 0.0)):
                ok = False
            out_corners[mk, k, 0] = px[0]
            out_corners[mk, k, 1] = px[1]
        out_seen[mk] = ok
        every = every and ok
    if not every:
        return False
    for k in range(4):
        project_world(c, g_c, p.features[k], px)
        out_uv[k, 0] = px[0]
        out_uv[k, 1] = px[1]
    return True


@njit(cache=True)
def frame_dropped(p, u_drop):
    """The frame is dropped (a missed frame): the uniform draw ``u_drop`` below ``dropout``."""
    return p.dropout > 0.0 and u_drop < p.dropout


@njit(cache=True)
def add_pixel_noise(p, uv, corners, normals):
    """Gaussian pixel noise of standard deviation ``pixel_noise`` on a detection: its points
    ``uv`` (4, 2) take the first 8 standard ``normals``, each of its markers' corners
    ``corners`` (M, 4, 2) the next 8, in that order."""
    s = p.pixel_noise
    for k in range(4):
        uv[k, 0] += s * normals[2 * k]
        uv[k, 1] += s * normals[2 * k + 1]
    j = 8
    for mk in range(corners.shape[0]):
        for k in range(4):
            corners[mk, k, 0] += s * normals[j]
            corners[mk, k, 1] += s * normals[j + 1]
            j += 2


@njit(cache=True)
def global_offered(k, every, requested):
    """C_G's frame is offered to the servo in period ``k``: every ``every`` periods (0:
    never) and whenever the servo asked for it (``requested``)."""
    return requested or (every > 0 and k % every == 0)


@njit(cache=True)
def latency_slots(st, cap):
    """The ring buffer's slots of a new frame: ``(write, read)``, the slot to store this
    period's frame in and the slot of the frame delivered now (the oldest of the ``cap =
    latency + 1`` kept; the first frame until the buffer has filled), the ring advanced."""
    head, count = st.head[0], st.count[0]
    if count < cap:
        slot = (head + count) % cap
        count += 1
    else:
        slot = head
        head = (head + 1) % cap
    st.head[0], st.count[0] = head, count
    return slot, head


@njit(cache=True)
def latency_push(p, st, found, uv, corners, capture):
    """Store this period's frame and return the slot of the delivered one
    (:func:`latency_slots`, ``latency + 1`` frames kept)."""
    write, read = latency_slots(st, p.latency + 1)
    st.uv[write] = uv
    st.corners[write] = corners
    st.found[write] = found
    st.capture[write] = capture
    return read


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
        #: the target's feature points (4, 3) and its markers' corners (M, 4, 3) in the world
        self.features_world = np.ascontiguousarray(target.feature_points @ g[:3, :3].T + g[:3, 3])
        ids = tuple(getattr(target, "ids", ())) or (target.marker_id,)
        self.ids = ids
        self.corners_world = np.ascontiguousarray(
            [target.corner_points(i) @ g[:3, :3].T + g[:3, 3] for i in ids], dtype=float
        )
        self._params = CameraSensorParams(
            camera.params(), False, np.zeros(2, np.int64), np.eye(4), self.corners_world,
            self.features_world, 0.0, 0.0, 0,
        )  # fmt: skip

    def reset(self) -> None:
        pass

    def detect_at(self, pose: np.ndarray) -> Detection:
        """The detection at the camera pose ``pose`` (:func:`analytic_detect`)."""
        uv = np.empty((4, 2))
        corners = np.empty((len(self.ids), 4, 2))
        seen = np.empty(len(self.ids), np.bool_)
        found = analytic_detect(
            self._params, np.ascontiguousarray(pose, dtype=float), uv, corners, seen
        )
        pix = {i: corners[k] for k, i in enumerate(self.ids) if seen[k]}
        return Detection(bool(found), uv if found else None, tuple(pix), pix)


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
        fe = front_end
        analytic = isinstance(fe, AnalyticFrontEnd)
        m = self.model
        #: the record of the compiled steps (the analytic front end's target, none otherwise)
        self.params = CameraSensorParams(
            fe.camera.params() if analytic or not fe.camera.has_distortion else _NO_CAMERA,
            carrier == "tip", rod_steps(system, self.rod) if carrier == "tip" else _NO_ROD,
            np.ascontiguousarray(self.mount), fe.corners_world if analytic else _NO_CORNERS,
            fe.features_world if analytic else np.zeros((4, 3)), float(m.pixel_noise),
            float(m.dropout), int(m.latency_steps),
        )  # fmt: skip
        self._ring = CameraSensorState.empty(self.params._replace(corners=_NO_CORNERS[:0]))
        self._fifo = [None] * (m.latency_steps + 1)

    @property
    def camera(self) -> PinholeCamera:
        return self.front_end.camera

    def seeing(self, target, target_pose) -> CameraSensor:
        """A copy of this camera with the analytic front end of ``target`` at ``target_pose``
        (the same imperfections and generator, empty buffers): the reference snapshot of a
        world with its own target."""
        fe = AnalyticFrontEnd(self.front_end.camera, target, target_pose)
        return CameraSensor(self.system, self.carrier, self.mount, fe, self.model, self.rng,
                            self.keep_images, self.rod)  # fmt: skip

    def reset(self) -> None:
        self.front_end.reset()
        self._ring.head[0] = 0
        self._ring.count[0] = 0

    def pose(self, q) -> np.ndarray:
        """Inertial pose of the camera at configuration ``q`` (:func:`camera_pose_into`)."""
        out = np.empty((4, 4))
        camera_pose_into(self.params, self.system.model_arrays,
                         np.ascontiguousarray(q, dtype=float), out)  # fmt: skip
        return out

    def ideal(self, q) -> tuple[Detection, np.ndarray | None]:
        """Detection (no imperfections) and image (``None`` for the analytic front end)."""
        pose = self.pose(q)
        fe = self.front_end
        if isinstance(fe, AnalyticFrontEnd):
            return fe.detect_at(pose), None
        return fe.detect_at(pose, self.system, q, self.keep_images)

    def _imperfect(self, det: Detection) -> Detection:
        """The imperfections (:func:`frame_dropped`, :func:`add_pixel_noise`), their draws
        from the sensor's generator: a uniform when frames drop, then, for a detection with
        pixel noise, 8 normals for its points and 8 for each marker seen."""
        p = self.params
        if p.dropout > 0 and frame_dropped(p, self.rng.random()):
            return NOT_DETECTED
        if not det.found or p.pixel_noise == 0:
            return det
        ids = tuple(det.corners)
        points = np.array(det.points, float)
        corners = np.array([det.corners[k] for k in ids], float).reshape(len(ids), 4, 2)
        add_pixel_noise(p, points, corners, self.rng.standard_normal(8 + 8 * len(ids)))
        return Detection(True, points, det.ids, dict(zip(ids, corners, strict=True)))

    def measure(self, state: PlantState) -> CameraMeasurement:
        det, image = self.ideal(state.q)
        det = self._imperfect(det)
        meas = CameraMeasurement(state.t, det, image if self.keep_images else None)
        if self.model.latency_steps == 0:
            return meas
        # the delivered frame: latency_steps old
        write, read = latency_slots(self._ring, self.params.latency + 1)
        self._fifo[write] = meas
        return self._fifo[read]

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
        global_every: int = CamerasConfig().global_every,
        always_global: bool = False,
        other: dict | None = None,
        global_output_every: int = CamerasConfig().global_output_every,
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
            offered = self.always_global or global_offered(k, every, bool(request_global))
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
