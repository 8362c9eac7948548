"""Sensor imperfections for robustness studies (scenario section ``[sensors]``).

* ``pixel_noise``: standard deviation (px) of Gaussian noise added to every detected feature
  point (and raw corner) of the local camera;
* ``dropout``: probability that a local-camera frame yields no detection;
* ``latency_steps``: the controller sees the local-camera result of that many control steps ago;
* ``intrinsics_error``: relative standard deviation of the controller's ``fx, fy, cx, cy``
  (the images are rendered with the true camera, normalized with the wrong one).

All randomness comes from one ``numpy.random.Generator`` seeded by the run's seed, so a run is
reproducible from its seed. The record :class:`SensorModel` (defaults, ranges) lives with the
camera block, in :mod:`tdacm.loop.config`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from ..loop.config import SensorModel
from ..vision.detect import NOT_DETECTED, Detection

__all__ = ["Delay", "NoisyDetector", "SensorModel", "perturbed_camera"]


class NoisyDetector:
    """Wraps a detector (``detect(image)``, ``reset()``) with pixel noise and dropouts."""

    def __init__(self, detector, model: SensorModel, rng: np.random.Generator):
        self.inner = detector
        self.model = model
        self.rng = rng

    def reset(self):
        self.inner.reset()

    def detect(self, image) -> Detection:
        det = self.inner.detect(image)
        if self.model.dropout > 0 and self.rng.random() < self.model.dropout:
            return NOT_DETECTED
        if not det.found or self.model.pixel_noise == 0:
            return det
        s = self.model.pixel_noise
        points = det.points + self.rng.normal(0.0, s, det.points.shape)
        corners = {k: v + self.rng.normal(0.0, s, np.shape(v)) for k, v in det.corners.items()}
        return Detection(True, points, det.ids, corners)


class Delay:
    """A FIFO that returns the value pushed ``steps`` calls ago (the first value until full)."""

    def __init__(self, steps: int):
        self.buf = deque(maxlen=int(steps) + 1)

    def __call__(self, value):
        self.buf.append(value)
        return self.buf[0]


def perturbed_camera(camera, relative_error: float, rng: np.random.Generator):
    """A copy of ``camera`` with ``fx, fy, cx, cy`` scaled by ``1 + N(0, relative_error)``."""
    if relative_error == 0:
        return camera
    f = 1.0 + rng.normal(0.0, relative_error, 4)
    return replace(
        camera, fx=camera.fx * f[0], fy=camera.fy * f[1], cx=camera.cx * f[2], cy=camera.cy * f[3]
    )
