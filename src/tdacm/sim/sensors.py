"""Sensor imperfections for robustness studies (scenario section ``[sensors]``).

* ``pixel_noise``: standard deviation (px) of Gaussian noise added to every detected feature
  point (and raw corner) of the local camera;
* ``dropout``: probability that a local-camera frame yields no detection;
* ``latency_steps``: the controller sees the local-camera result of that many control steps ago;
* ``intrinsics_error``: relative standard deviation of the controller's ``fx, fy, cx, cy``
  (the images are rendered with the true camera, normalized with the wrong one).

All randomness comes from one ``numpy.random.Generator`` seeded by the run's seed, so a run is
reproducible from its seed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    pixel_noise: float = 0.0
    dropout: float = 0.0
    latency_steps: int = 0
    intrinsics_error: float = 0.0

    def __post_init__(self):
        if not np.isfinite(self.pixel_noise) or self.pixel_noise < 0:
            raise ValueError(f"sensors.pixel_noise must be >= 0, got {self.pixel_noise!r}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"sensors.dropout must lie in [0, 1), got {self.dropout!r}")
        if int(self.latency_steps) != self.latency_steps or self.latency_steps < 0:
            raise ValueError(
                f"sensors.latency_steps must be an integer >= 0, got {self.latency_steps!r}"
            )
        if not np.isfinite(self.intrinsics_error) or not 0.0 <= self.intrinsics_error < 0.5:
            raise ValueError(
                f"sensors.intrinsics_error must lie in [0, 0.5), got {self.intrinsics_error!r}"
            )

    @property
    def ideal(self) -> bool:
        return (
            self.pixel_noise == 0
            and self.dropout == 0
            and self.latency_steps == 0
            and self.intrinsics_error == 0
        )


def perturbed_camera(camera, relative_error: float, rng: np.random.Generator):
    """A copy of ``camera`` with ``fx, fy, cx, cy`` scaled by ``1 + N(0, relative_error)``."""
    if relative_error == 0:
        return camera
    f = 1.0 + rng.normal(0.0, relative_error, 4)
    return replace(
        camera, fx=camera.fx * f[0], fy=camera.fy * f[1], cx=camera.cx * f[2], cy=camera.cy * f[3]
    )
