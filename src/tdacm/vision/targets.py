"""Planar fiducial targets: the paper's simulation marker and its experimental tag pattern.

Target frame (both targets): origin at the centre of the board, ``x`` to the right and ``y``
down as the printed pattern is read, ``z = x cross y`` into the board (away from a viewer who
reads it). A camera that sees the pattern upright and head-on therefore has the same
orientation as the target frame, and the target's outward normal is ``-z``.

Feature points (:attr:`FiducialTarget.feature_points`) are given in the corner order the
paper's advanced features assume (section "IBVS in Local Camera with Advanced Features"):
1 = top-left, 2 = bottom-left, 3 = bottom-right, 4 = top-right.

* :class:`ArucoMarker` - the simulation target: a 20 x 20 cm marker with ID 65 from
  ``DICT_4X4_100`` (configurable). Its feature points are the four outer corners.
* :class:`AprilTagPattern` - the experimental target: four 3 cm AprilTag 36h11 tags whose
  centres sit at the corners of an 18 x 12 cm rectangle. Its feature points are the four tag
  centres; tag ``ids[k]`` sits at feature position ``k`` (TL, BL, BR, TR).

Both generate the texture the renderers paste on the scene; the texture's marker cells lie
exactly on its pixel grid, so the rendered geometry matches :meth:`corner_points`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from . import _checks as C

#: Paper order of the four feature points: top-left, bottom-left, bottom-right, top-right.
PAPER_ORDER = ("top-left", "bottom-left", "bottom-right", "top-right")

#: Index map from OpenCV's corner order (TL, TR, BR, BL) to the paper's (TL, BL, BR, TR).
#: This is the one place where the reordering is defined.
OPENCV_TO_PAPER = (0, 3, 2, 1)


def _square_corners(center, size) -> np.ndarray:
    """Corners of an axis-aligned square in the target frame, OpenCV order TL, TR, BR, BL."""
    cx, cy = center
    h = 0.5 * size
    return np.array(
        [[cx - h, cy - h, 0.0], [cx + h, cy - h, 0.0], [cx + h, cy + h, 0.0], [cx - h, cy + h, 0.0]]
    )


def _check_ids(key: str, dictionary, ids) -> None:
    """``dictionary`` is an OpenCV aruco dictionary id and every id in ``ids`` one of its
    markers (``ValueError`` naming ``key`` otherwise)."""
    try:
        d = cv2.aruco.getPredefinedDictionary(int(dictionary))
    except cv2.error:
        raise ValueError(
            f"dictionary must be an OpenCV aruco dictionary id, got {dictionary!r}"
        ) from None
    n = d.bytesList.shape[0]
    for i in ids:
        if not 0 <= int(i) < n:
            raise ValueError(f"{key} must lie in [0, {n}) for this dictionary, got {i!r}")


def _dictionary_cells(dictionary: int) -> int:
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    return int(d.markerSize)


class FiducialTarget:
    """Common interface of the planar targets (see module docstring for the frame)."""

    dictionary: int
    ids: tuple

    #: physical ``(width, height)`` of the white board carrying the pattern, metres
    board_size: tuple

    @property
    def feature_points(self) -> np.ndarray:  # pragma: no cover - abstract
        """``(4, 3)`` feature points in the target frame, paper order (TL, BL, BR, TR)."""
        raise NotImplementedError

    def corner_points(self, marker_id: int) -> np.ndarray:  # pragma: no cover - abstract
        """``(4, 3)`` outer corners of marker ``marker_id``, OpenCV order (TL, TR, BR, BL)."""
        raise NotImplementedError

    def texture(self) -> np.ndarray:  # pragma: no cover - abstract
        """Grayscale ``uint8`` texture of the whole board (row 0 = top edge, ``y = -h/2``)."""
        raise NotImplementedError

    #: white border of the board beyond the pattern (m) and texture pixels per marker cell
    margin: float
    pixels_per_cell: int

    def _check(self, **sizes) -> None:
        """``sizes`` (name -> metres) positive, ``margin`` non-negative, ``pixels_per_cell`` a
        positive integer (``ValueError`` naming the first that is not)."""
        for key, value in sizes.items():
            C.positive(key, value)
        C.nonnegative("margin", self.margin)
        C.positive_int("pixels_per_cell", self.pixels_per_cell)

    @property
    def _marker_side(self) -> float:  # pragma: no cover - abstract
        """Side of one marker's black square (m)."""
        raise NotImplementedError

    @property
    def _cells(self) -> int:
        """Cells along a marker's side: its data bits and one black border cell each side."""
        return _dictionary_cells(self.dictionary) + 2

    @property
    def _px_per_m(self) -> float:
        """Texture pixels per metre (a marker's cells lie on the pixel grid)."""
        return self._cells * self.pixels_per_cell / self._marker_side

    @property
    def aruco_dictionary(self):
        return cv2.aruco.getPredefinedDictionary(self.dictionary)

    def board_corners(self) -> np.ndarray:
        """``(4, 3)`` corners of the board (OpenCV order TL, TR, BR, BL), target frame."""
        w, h = self.board_size
        return np.array(
            [[-w / 2, -h / 2, 0.0], [w / 2, -h / 2, 0.0], [w / 2, h / 2, 0.0], [-w / 2, h / 2, 0.0]]
        )

    def all_corner_points(self) -> np.ndarray:
        """``(4 n_markers, 3)`` corners of every marker, in ``ids`` order, OpenCV order each."""
        return np.vstack([self.corner_points(i) for i in self.ids])

    @property
    def feature_scale(self) -> float:
        """Perimeter of the feature polygon (metres); with the perimeter feature ``p_z`` it
        gives a depth estimate ``Z ~ perimeter / p_z`` for a head-on view."""
        p = self.feature_points
        return float(sum(np.linalg.norm(p[(k + 1) % 4] - p[k]) for k in range(4)))


@dataclass(frozen=True)
class ArucoMarker(FiducialTarget):
    """Single square ArUco marker (paper: 20 x 20 cm, ID 65, OpenCV ``DICT_4X4_100``).

    ``size`` is the side of the black square (the detected outer corners); ``margin`` the white
    quiet zone drawn around it on the board; ``pixels_per_cell`` the texture resolution.
    """

    marker_id: int = 65
    size: float = 0.20
    dictionary: int = cv2.aruco.DICT_4X4_100
    margin: float = 0.05
    pixels_per_cell: int = 40

    def __post_init__(self):
        self._check(size=self.size)
        _check_ids("marker_id", self.dictionary, (self.marker_id,))

    @property
    def ids(self) -> tuple:
        return (int(self.marker_id),)

    @property
    def _marker_side(self) -> float:
        return self.size

    @property
    def _margin_px(self) -> int:
        return int(round(self.margin * self._px_per_m))

    @property
    def board_size(self) -> tuple:
        side = self.size + 2.0 * self._margin_px / self._px_per_m
        return (side, side)

    @property
    def feature_points(self) -> np.ndarray:
        return self.corner_points(self.marker_id)[list(OPENCV_TO_PAPER)]

    def corner_points(self, marker_id: int) -> np.ndarray:
        if int(marker_id) != int(self.marker_id):
            raise ValueError(f"marker_id {marker_id!r} is not part of this target")
        return _square_corners((0.0, 0.0), self.size)

    def texture(self) -> np.ndarray:
        side = self._cells * self.pixels_per_cell
        marker = cv2.aruco.generateImageMarker(self.aruco_dictionary, int(self.marker_id), side)
        m = self._margin_px
        img = np.full((side + 2 * m, side + 2 * m), 255, np.uint8)
        img[m : m + side, m : m + side] = marker
        return img


@dataclass(frozen=True)
class AprilTagPattern(FiducialTarget):
    """Four AprilTag 36h11 tags at the corners of a rectangle (paper, experiments).

    ``tag_size`` is the side of each tag's black square (3 cm); ``width`` x ``height`` the
    rectangle of the tag centres (18 x 12 cm); ``ids`` the tag ids at the TL, BL, BR, TR
    positions; ``margin`` the white border beyond the tags' outer edges.
    """

    tag_size: float = 0.03
    width: float = 0.18
    height: float = 0.12
    ids: tuple = (0, 1, 2, 3)
    dictionary: int = cv2.aruco.DICT_APRILTAG_36h11
    margin: float = 0.03
    pixels_per_cell: int = 12

    def __post_init__(self):
        self._check(tag_size=self.tag_size, width=self.width, height=self.height)
        ids = tuple(int(i) for i in self.ids)
        if len(ids) != 4 or len(set(ids)) != 4:
            raise ValueError(f"ids must be 4 distinct tag ids, got {self.ids!r}")
        _check_ids("ids", self.dictionary, ids)
        object.__setattr__(self, "ids", ids)
        if self.width <= self.tag_size or self.height <= self.tag_size:
            raise ValueError("width and height must exceed tag_size (tags would overlap)")

    @property
    def _marker_side(self) -> float:
        return self.tag_size

    def _centers(self) -> np.ndarray:
        """Tag centres (x, y) in the target frame, paper order TL, BL, BR, TR."""
        w, h = self.width / 2, self.height / 2
        return np.array([[-w, -h], [-w, h], [w, h], [w, -h]])

    def _layout(self):
        """Texture size and top-left pixel of each tag (on the pixel grid)."""
        ppm = self._px_per_m
        tag_px = self._cells * self.pixels_per_cell
        m = int(round(self.margin * ppm))
        half_w = int(round((self.width / 2 + self.tag_size / 2) * ppm)) + m
        half_h = int(round((self.height / 2 + self.tag_size / 2) * ppm)) + m
        origins = []
        for cx, cy in self._centers():
            col = int(round(cx * ppm - tag_px / 2)) + half_w
            row = int(round(cy * ppm - tag_px / 2)) + half_h
            origins.append((row, col))
        return (2 * half_h, 2 * half_w), origins, tag_px

    @property
    def board_size(self) -> tuple:
        (h, w), _, _ = self._layout()
        return (w / self._px_per_m, h / self._px_per_m)

    @property
    def feature_points(self) -> np.ndarray:
        return np.vstack([self.corner_points(i).mean(axis=0) for i in self.ids])

    def corner_points(self, marker_id: int) -> np.ndarray:
        if int(marker_id) not in self.ids:
            raise ValueError(f"marker_id {marker_id!r} is not part of this target")
        # geometry exactly as drawn in the texture (tag positions snapped to its pixel grid)
        (h, w), origins, tag_px = self._layout()
        row, col = origins[self.ids.index(int(marker_id))]
        ppm = self._px_per_m
        cx = (col + tag_px / 2 - w / 2) / ppm
        cy = (row + tag_px / 2 - h / 2) / ppm
        return _square_corners((cx, cy), tag_px / ppm)

    def texture(self) -> np.ndarray:
        (h, w), origins, tag_px = self._layout()
        img = np.full((h, w), 255, np.uint8)
        for tag_id, (row, col) in zip(self.ids, origins, strict=True):
            img[row : row + tag_px, col : col + tag_px] = cv2.aruco.generateImageMarker(
                self.aruco_dictionary, tag_id, tag_px
            )
        return img


#: The paper's simulation marker (20 cm, ID 65, DICT_4X4_100).
PAPER_MARKER = ArucoMarker()

#: The paper's experimental pattern (four 3 cm AprilTag 36h11 tags, 18 x 12 cm rectangle).
PAPER_PATTERN = AprilTagPattern()
