"""Fiducial detection with OpenCV 5's ``cv2.aruco.ArucoDetector``.

:func:`detect_target` (or a reusable :class:`TargetDetector`) finds the target in an image -
rendered or from a real camera, grayscale or colour - and returns the four image points the
advanced features need, in the paper's order (1 = top-left, 2 = bottom-left,
3 = bottom-right, 4 = top-right, see :mod:`.targets`):

* :class:`~.targets.ArucoMarker`: the marker's outer corners, refined to sub-pixel accuracy
  (``CORNER_REFINE_SUBPIX``) and reordered from OpenCV's TL, TR, BR, BL with
  :data:`~.targets.OPENCV_TO_PAPER`. The corner labels come from the decoded marker, so they
  follow the physical marker through any in-plane rotation (this is what makes the yaw
  feature well defined over 360 degrees).
* :class:`~.targets.AprilTagPattern`: the centres of the four tags (intersection of each tag's
  diagonals, the projective image of its centre), tag ``ids[k]`` giving point ``k``.

If the target is not fully seen (marker missing, or any of the four tags missing) the result
is :data:`NOT_DETECTED`-like: ``found`` is False and ``points`` is ``None``; ``ids`` still
lists what was seen.

OpenCV 5 removed the module-level ``cv2.aruco.detectMarkers``: ``detectMarkers`` is a method of ``ArucoDetector``, ``ids``
is ``(N,)`` in 5.x and ``(N, 1)`` in 4.x (both handled).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit

from .targets import OPENCV_TO_PAPER, AprilTagPattern, ArucoMarker, FiducialTarget


@dataclass(frozen=True)
class Detection:
    """Result of a detection.

    Attributes
    ----------
    found:
        True if all four feature points were found.
    points:
        ``(4, 2)`` pixel coordinates in the paper's order, or ``None``.
    ids:
        Ids of the target's markers seen in the image (possibly incomplete).
    corners:
        Raw corners ``(4, 2)`` per seen id, OpenCV order (TL, TR, BR, BL), pixels.
    """

    found: bool
    points: np.ndarray | None = None
    ids: tuple = ()
    corners: dict = field(default_factory=dict)

    def __bool__(self) -> bool:
        return self.found


#: The "not detected" result.
NOT_DETECTED = Detection(False)


def to_gray(image) -> np.ndarray:
    """8-bit grayscale view of an image: ``(H, W)``, ``(H, W, 1)``, ``(H, W, 3)`` (RGB or BGR,
    the weights differ by a few grey levels, irrelevant for black-and-white fiducials) or
    ``(H, W, 4)``; ``uint8``, ``uint16`` or float (``[0, 1]`` if its maximum is <= 1)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        raise ValueError(f"image must have shape (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")
    if img.shape[0] < 8 or img.shape[1] < 8:
        raise ValueError(f"image is too small: {img.shape}")
    if img.dtype != np.uint8:
        if img.dtype == np.uint16:
            img = (img >> 8).astype(np.uint8)
        elif np.issubdtype(img.dtype, np.floating):
            if not np.all(np.isfinite(img)):
                raise ValueError("image must be finite")
            scale = 255.0 if img.max(initial=0.0) <= 1.0 else 1.0
            img = np.clip(img * scale, 0, 255).astype(np.uint8)
        else:
            raise ValueError(f"image must be uint8, uint16 or float, got {img.dtype}")
    if img.ndim == 3:
        code = cv2.COLOR_RGB2GRAY if img.shape[2] == 3 else cv2.COLOR_RGBA2GRAY
        img = cv2.cvtColor(img, code)
    return np.ascontiguousarray(img)


def default_parameters() -> cv2.aruco.DetectorParameters:
    """Detector parameters used by default: sub-pixel corner refinement."""
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    p.cornerRefinementWinSize = 5
    p.cornerRefinementMaxIterations = 50
    p.cornerRefinementMinAccuracy = 0.01
    return p


def refine_corners_edges(
    gray: np.ndarray, corners: np.ndarray, cells: int, max_shift: float | None = None
) -> np.ndarray:
    """Refine a square marker's outer corners ``(4, 2)`` (cyclic order) from its four edges.

    Along each side, intensity profiles across the edge (between the black border cell and
    the white surround) are sampled with bilinear interpolation; the edge position on each
    profile is found by the area method, ``e = w - int (I - I_in)/(I_out - I_in) do``, which
    is unbiased for any symmetric blur and averages noise; a line is fitted to the edge
    points (total least squares, one pass of outlier rejection) and adjacent lines are
    intersected. ``cells`` is the number of cells across the marker (data bits + 2 border)
    and bounds the profile half-width. Corners whose refinement fails or moves more than
    ``max_shift`` pixels (default: one cell, at least 2 px) keep their input value.
    All four sides are processed at once (one ``cv2.remap``, vectorized fits).
    """
    c = np.asarray(corners, dtype=float).reshape(4, 2)
    a, b = c, np.roll(c, -1, axis=0)  # side i runs from corner i to corner i+1
    length = np.linalg.norm(b - a, axis=1)
    cell = float(length.mean()) / cells
    if cell < 2.5 or np.any(length < 1e-6):
        return c  # too small to gain anything over the detector's corners
    if max_shift is None:
        max_shift = max(2.0, cell)
    half = float(np.clip(0.7 * cell, 1.0, 4.0))
    offsets = np.arange(-half, half + 1e-9, 0.25)
    t = (b - a) / length[:, None]
    n = np.column_stack((t[:, 1], -t[:, 0]))
    flip = np.einsum("ij,ij->i", n, 0.5 * (a + b) - c.mean(axis=0)) < 0
    n[flip] *= -1.0  # outward normals
    m = int(np.clip(length.mean() / 2, 6, 60))
    s = np.linspace(0.15, 0.85, m)
    base = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]  # (4, m, 2)
    pts = base[:, :, None, :] + offsets[None, None, :, None] * n[:, None, None, :]
    k = len(offsets)
    maps = pts.reshape(4 * m, k, 2).astype(np.float32)
    prof = (
        cv2.remap(
            gray, maps[:, :, 0], maps[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        .astype(float)
        .reshape(4, m, k)
    )
    return _fit_edges(prof, base, n, half, c, float(max_shift))


@njit(cache=True)
def _median(x):
    return np.median(x)


@njit(cache=True)
def _fit_edges(prof, base, n, half, c, max_shift):
    """The fit of :func:`refine_corners_edges` after the profiles are sampled: edge points by
    the area method, one total-least-squares line per side with one pass of MAD outlier
    rejection, adjacent lines intersected (corners that fail or move too far are kept)."""
    sides, m, k = prof.shape
    q = max(1, k // 5)
    edge = np.empty((4, m, 2))
    good = np.zeros((4, m), np.bool_)
    for i in range(4):
        cnt = 0
        for j in range(m):
            i_in = prof[i, j, :q].mean()
            i_out = prof[i, j, k - q :].mean()
            contrast = i_out - i_in
            good[i, j] = contrast > 20.0
            cnt += good[i, j]
            area = 0.0
            for l in range(k):
                f = (prof[i, j, l] - i_in) / max(contrast, 1e-9)
                f = min(max(f, 0.0), 1.0)
                area += f if (l != 0 and l != k - 1) else 0.5 * f
            area *= 0.25
            edge[i, j, 0] = base[i, j, 0] + (half - area) * n[i, 0]
            edge[i, j, 1] = base[i, j, 1] + (half - area) * n[i, 1]
        if cnt < 4:
            return c.copy()
    mean = np.zeros((4, 2))
    direction = np.zeros((4, 2))
    for i in range(4):
        w = good[i].copy()
        for _ in range(2):  # total least squares, then once more without the outliers
            cnt = w.sum()
            if cnt < 4:
                return c.copy()
            mx = 0.0
            my = 0.0
            for j in range(m):
                if w[j]:
                    mx += edge[i, j, 0]
                    my += edge[i, j, 1]
            mx /= cnt
            my /= cnt
            sxx = 0.0
            syy = 0.0
            sxy = 0.0
            for j in range(m):
                if w[j]:
                    dx = edge[i, j, 0] - mx
                    dy = edge[i, j, 1] - my
                    sxx += dx * dx
                    syy += dy * dy
                    sxy += dx * dy
            ang = 0.5 * np.arctan2(2 * sxy, sxx - syy)
            ux, uy = np.cos(ang), np.sin(ang)
            r = np.empty(m)
            rw = np.empty(cnt)
            p = 0
            for j in range(m):
                r[j] = abs((edge[i, j, 0] - mx) * (-uy) + (edge[i, j, 1] - my) * ux)
                if w[j]:
                    rw[p] = r[j]
                    p += 1
            lim = max(0.3, 4.45 * _median(rw))
            keep = (r <= lim) & good[i]
            mean[i, 0], mean[i, 1] = mx, my
            direction[i, 0], direction[i, 1] = ux, uy
            if np.all(keep == w):
                break
            w = keep
    out = c.copy()
    for i in range(4):
        p = (i + 3) % 4  # corner i joins side i-1 and side i
        d1x, d1y = direction[p, 0], direction[p, 1]
        d2x, d2y = direction[i, 0], direction[i, 1]
        det = d1x * (-d2y) - d1y * (-d2x)
        if abs(det) <= 1e-9:
            continue
        rx = mean[i, 0] - mean[p, 0]
        ry = mean[i, 1] - mean[p, 1]
        u = (rx * (-d2y) - ry * (-d2x)) / det
        nx = mean[p, 0] + u * d1x
        ny = mean[p, 1] + u * d1y
        if np.hypot(nx - c[i, 0], ny - c[i, 1]) <= max_shift:
            out[i, 0], out[i, 1] = nx, ny
    return out


def tag_center(corners: np.ndarray) -> np.ndarray:
    """Image of a square's centre: intersection of its diagonals (corners ``(4, 2)`` in
    cyclic order). Exact under perspective, unlike the mean of the corners."""
    p0, p1, p2, p3 = (np.append(c, 1.0) for c in np.asarray(corners, dtype=float))
    x = np.cross(np.cross(p0, p2), np.cross(p1, p3))
    if abs(x[2]) < 1e-12:
        return np.asarray(corners, dtype=float).mean(axis=0)
    return x[:2] / x[2]


class TargetDetector:
    """Reusable detector for one target (keeps the ``ArucoDetector`` between frames).

    Parameters
    ----------
    target:
        :class:`ArucoMarker` or :class:`AprilTagPattern`.
    parameters:
        ``cv2.aruco.DetectorParameters`` (default :func:`default_parameters`).
    track:
        If True, search first in a window around the previous detection (the target moves
        little between 20 ms frames), with a single adaptive-threshold pass, and fall back
        to the full detector on the whole image. Same points, a fraction of the time on
        large images.
    refine:
        ``"edges"`` (default): OpenCV's sub-pixel corners (``CORNER_REFINE_SUBPIX``) further
        refined by fitting lines to the marker's four edges (:func:`refine_corners_edges`);
        about twice as accurate on small or blurred markers, where ``cornerSubPix`` is
        pulled into the marker by the L-shaped corner. ``"subpix"``: OpenCV's corners only.
    """

    def __init__(
        self, target: FiducialTarget, parameters=None, track: bool = False, refine: str = "edges"
    ):
        if refine not in ("edges", "subpix"):
            raise ValueError(f"refine must be 'edges' or 'subpix', got {refine!r}")
        self.refine = refine
        if not isinstance(target, (ArucoMarker, AprilTagPattern)):
            raise ValueError(f"target must be an ArucoMarker or AprilTagPattern, got {target!r}")
        self.target = target
        self.parameters = default_parameters() if parameters is None else parameters
        self._detector = cv2.aruco.ArucoDetector(target.aruco_dictionary, self.parameters)
        # inside the tracking window one adaptive-threshold pass (instead of three) suffices;
        # if it misses, the full detector runs on the whole image
        fast = _copy_parameters(self.parameters)
        fast.adaptiveThreshWinSizeMin = TRACK_THRESHOLD_WINDOW
        fast.adaptiveThreshWinSizeMax = TRACK_THRESHOLD_WINDOW
        self._track_detector = cv2.aruco.ArucoDetector(target.aruco_dictionary, fast)
        self._cells = int(target.aruco_dictionary.markerSize) + 2
        self.track = bool(track)
        self._last_box = None
        self._last_shape = None

    def reset(self) -> None:
        """Forget the tracking window."""
        self._last_box = None

    def tracking_window(self, shape) -> tuple | None:
        """``(x0, y0, x1, y1)``: the window searched first in the next frame of ``shape``
        (``None`` when not tracking or nothing was tracked)."""
        if self.track and self._last_box is not None and self._last_shape == tuple(shape):
            return self._last_box
        return None

    def detect_in_window(self, crop, window) -> Detection:
        """Detect in the tracking window's pixels only (``crop = image[y0:y1, x0:x1]``, e.g.
        rendered or read out as a region of interest); the window follows a detection."""
        det = self._detect_in(to_gray(crop), window[:2], self._track_detector)
        if det.found:
            self._update_box(det, self._last_shape)
        return det

    def detect(self, image) -> Detection:
        """Detect the target in ``image`` (see :func:`to_gray` for accepted formats)."""
        shape = np.shape(image)[:2]
        win = self.tracking_window(shape)
        if win is not None:
            x0, y0, x1, y1 = win
            det = self.detect_in_window(np.asarray(image)[y0:y1, x0:x1], win)
            if det.found:
                return det
        gray = to_gray(image)
        det = self._detect_in(gray, (0, 0))
        if self.track:
            if det.found:
                self._update_box(det, gray.shape)
            else:
                self._last_box = None
        return det

    __call__ = detect

    def _update_box(self, det: Detection, shape) -> None:
        pts = np.vstack(list(det.corners.values()))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.6 * (hi - lo).max() + 16
        x0, y0 = (int(max(0, v)) for v in np.floor(lo - pad))
        x1 = int(min(shape[1], np.ceil(hi[0] + pad)))
        y1 = int(min(shape[0], np.ceil(hi[1] + pad)))
        self._last_box = (x0, y0, x1, y1)
        self._last_shape = tuple(shape)

    def _detect_in(self, gray: np.ndarray, offset, detector=None) -> Detection:
        corners, ids, _ = (detector or self._detector).detectMarkers(gray)
        if ids is None or len(ids) == 0:
            return NOT_DETECTED
        ids = np.asarray(ids).reshape(-1)
        wanted = set(self.target.ids)
        seen = {}
        for c, i in zip(corners, ids, strict=True):
            i = int(i)
            if i not in wanted:
                continue
            c = np.asarray(c, dtype=float).reshape(4, 2)
            if self.refine == "edges":
                c = refine_corners_edges(gray, c, self._cells)
            c = c + offset
            # keep the largest instance if an id appears twice
            if i not in seen or _perimeter(c) > _perimeter(seen[i]):
                seen[i] = c
        found_ids = tuple(sorted(seen))
        if isinstance(self.target, ArucoMarker):
            if self.target.marker_id not in seen:
                return Detection(False, None, found_ids, seen)
            pts = seen[self.target.marker_id][list(OPENCV_TO_PAPER)]
            return Detection(True, pts, found_ids, seen)
        if len(seen) < 4:
            return Detection(False, None, found_ids, seen)
        pts = np.array([tag_center(seen[i]) for i in self.target.ids])
        return Detection(True, pts, found_ids, seen)


#: Adaptive-threshold window (px) used inside the tracking window.
TRACK_THRESHOLD_WINDOW = 13


def _copy_parameters(p) -> cv2.aruco.DetectorParameters:
    out = cv2.aruco.DetectorParameters()
    for name in dir(p):
        if name.startswith("_"):
            continue
        value = getattr(p, name)
        if callable(value):
            continue
        try:
            setattr(out, name, value)
        except (AttributeError, TypeError):
            pass
    return out


def _perimeter(c: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1)))


def detect_target(
    image, target: FiducialTarget, detector: TargetDetector | None = None
) -> Detection:
    """Detect ``target`` in ``image``; pass a :class:`TargetDetector` to reuse it across
    frames. Returns a :class:`Detection` (falsy when not detected)."""
    if detector is None:
        detector = TargetDetector(target)
    elif detector.target != target:
        raise ValueError("detector was built for a different target")
    return detector.detect(image)
