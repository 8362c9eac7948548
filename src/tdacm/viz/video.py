"""Video frames of a run: C_L and C_G side by side."""

from __future__ import annotations

import numpy as np


def side_by_side(img_l, img_g, pix) -> np.ndarray:
    """C_L (detected points in red) | C_G, 500 x 500 each."""
    import cv2

    if img_l.ndim == 2:
        img_l = cv2.cvtColor(img_l, cv2.COLOR_GRAY2RGB)
    left = cv2.resize(img_l, (500, 500), interpolation=cv2.INTER_AREA)
    if pix is not None:
        for p in np.asarray(pix) * 500 / img_l.shape[1]:
            cv2.circle(left, (int(p[0]), int(p[1])), 4, (255, 0, 0), -1)
    right = img_g if img_g is not None else np.zeros((500, 500, 3), np.uint8)
    if right.shape[:2] != (500, 500):
        right = cv2.resize(right, (500, 500))
    return np.concatenate((left[:, :, :3], right[:, :, :3]), axis=1)


def caption_frame_composer(readings, view, command, t) -> np.ndarray:
    """The logger's per-period frame (``RunLog(frame_composer=...)``)."""
    img_l = readings.local.image
    if img_l is None:
        img_l = np.zeros((500, 500, 3), np.uint8)
    img_g = readings.global_.image if readings.global_ is not None else None
    return side_by_side(img_l, img_g, view.pixels if view.found else None)
