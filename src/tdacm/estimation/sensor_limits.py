"""What a sensor suite allows: the steady-state errors of a hovering drone's horizontal
estimate from its pose sensor and IMU (docs/estimation.md, "What the sensors allow").

One horizontal axis, linearized about hover (position ``p``, velocity ``v``, tilt ``theta``)::

    p' = v,    v' = g theta + w_a,    theta' = omega_gyro - n_g

A quadrotor's accelerometer does not see its tilt (the thrust is along the body z axis): its
body-x/y reading is the drag and the arm's pull, the known input of ``v'`` with the
accelerometer's noise ``w_a``, and the tilt turns into horizontal acceleration through
``g theta``. The gyro's rate is the input of the tilt (its noise ``n_g``); the pose sensor
measures ``p`` and ``theta``. The steady state of the continuous Kalman filter of this model
(the algebraic Riccati equation; white-noise densities ``sigma / sqrt(rate)`` from the
per-sample noises of :class:`~.config.SensorSuiteConfig`) is the error an optimal filter
reaches with these sensors alone. The EKF has more to go on (the tip camera's view of the static
target, the model's commanded torques), so in the closed loop it can do somewhat better; it
cannot do much better, and a filter far above these figures is mis-tuned.

With a :class:`PinnedView` the axis has one more measurement: a camera on the arm, ``lever``
below the drone's centre of mass, that sees a static point at a fixed place in its image (the
tip camera's view of the marker while the probe presses it, docs/contact.md) measures the
drone's position plus the lever times its tilt, ``p + lever theta``. Such a view pins the sum,
not the tilt: the tilt is then known as well as the pose sensor's position over the lever, which
is what bounds contact on estimates.

Uses: choosing a pose sensor for a wanted velocity accuracy; checking a filter's tuning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are

from ..system.tdacm import Loads
from .config import SensorSuiteConfig


@dataclass(frozen=True)
class PinnedView:
    """A camera ``lever`` m below the drone's centre of mass (along the body z axis in hover)
    seeing a static point: per frame it measures ``p + lever theta`` on each horizontal axis
    with the standard deviation ``noise`` (m), at ``rate_hz`` frames per second. For a camera
    of focal length ``f`` px with ``k`` corners of ``sigma`` px at depth ``d``:
    ``noise = sigma / f * d / sqrt(k)`` (the centroid's line of sight)."""

    lever: float  # m
    noise: float  # m, per frame and axis
    rate_hz: float  # frames per second

    def __post_init__(self):
        for name in ("lever", "noise", "rate_hz"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")


@dataclass(frozen=True)
class HoverEstimateLimits:
    """Steady-state standard deviations per horizontal axis of an optimal hover estimate."""

    position: float  # m
    velocity: float  # m/s
    attitude: float  # rad (roll or pitch)


def hover_estimate_limits(
    sensors: SensorSuiteConfig | None = None,
    gravity: float | None = None,
    view: PinnedView | None = None,
) -> HoverEstimateLimits:
    """Steady-state errors of the drone's horizontal position, velocity and tilt estimated
    from the pose sensor and the IMU of ``sensors`` (default: the project's sensor suite) in
    hover (module docstring). ``gravity``: m/s^2 (default: that of :class:`~tdacm.system.Loads`).
    ``view``: a :class:`PinnedView` fused as well (default: none).

    Raises ``ValueError`` naming the scenario key when the pose sensor or the IMU is off or a
    noise the model needs is zero (the filter would know that quantity exactly)."""
    s = sensors or SensorSuiteConfig()
    g = float(np.linalg.norm(Loads().gravity)) if gravity is None else float(gravity)
    if not np.isfinite(g) or g <= 0:
        raise ValueError(f"gravity must be > 0, got {gravity!r}")
    if not s.pose.enabled:
        raise ValueError("sensors.pose_enabled: the hover limits need the pose sensor")
    if not s.imu.enabled:
        raise ValueError("sensors.imu_enabled: the hover limits need the IMU")
    for key, value in (
        ("pose_position_noise", s.pose.position_noise),
        ("pose_attitude_noise", s.pose.attitude_noise),
    ):
        if value <= 0:
            raise ValueError(f"sensors.{key}: must be > 0 for the hover limits, got {value!r}")
    # per-sample noise sigma at rate f -> white-noise density sigma / sqrt(f)
    pose_rate, imu_rate = s.pose.rate_hz, s.imu.rate_hz
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, g], [0.0, 0.0, 0.0]])
    process = np.diag([0.0, s.imu.accel_noise**2, s.imu.gyro_noise**2]) / imu_rate
    # an ideal IMU leaves the Riccati equation singular; a floor far below any real sensor
    process += np.diag([0.0, 1e-16, 1e-16])
    h = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    meas = np.diag([s.pose.position_noise**2, s.pose.attitude_noise**2]) / pose_rate
    if view is not None:
        if not isinstance(view, PinnedView):
            raise ValueError(f"view must be a PinnedView or None, got {view!r}")
        h = np.vstack([h, [1.0, 0.0, view.lever]])
        meas = np.diag([*np.diag(meas), view.noise**2 / view.rate_hz])
    p = solve_continuous_are(a.T, h.T, process, meas)
    sd = np.sqrt(np.diag(p))
    return HoverEstimateLimits(position=float(sd[0]), velocity=float(sd[1]), attitude=float(sd[2]))
