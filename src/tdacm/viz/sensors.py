"""Sensor-sizing chart: the hover errors a drone pose sensor and an IMU allow.

:func:`sensor_limits_figure` draws, against the pose sensor's position noise, the horizontal
velocity and tilt errors of an optimal hover estimate
(:func:`tdacm.estimation.hover_estimate_limits`) for several pose attitude noises, the IMU and
rates of the given suite held fixed, and marks the suite itself. The quadrotor's accelerometer
does not see its tilt, so the tilt error becomes a slow velocity error: this is the estimate that
decides flight test C on estimates (docs/estimation.md, "What the sensors allow").

Regenerate docs/figures/sensor_limits.png with
``python -m tdacm.viz.sensors docs/figures/sensor_limits.png``.
"""

from __future__ import annotations

import numpy as np

from ._main import figure_main

#: pose attitude noises drawn (rad per sample): motion capture to visual-inertial odometry
DEFAULT_ATTITUDE_NOISES = (0.875e-3, 1.75e-3, 5e-3, 10e-3)


def sensor_limits_figure(
    path=None, sensors=None, attitude_noises=DEFAULT_ATTITUDE_NOISES, points: int = 41
):
    """The figure (matplotlib ``Figure``), saved to ``path`` when given. ``sensors``: the
    :class:`~tdacm.estimation.SensorSuiteConfig` whose IMU and rates are used and which is
    marked (default: the project's suite); ``attitude_noises``: rad, one curve each;
    ``points``: position noises from 0.1 to 10 mm."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..estimation import SensorSuiteConfig, hover_estimate_limits

    base = SensorSuiteConfig() if sensors is None else sensors
    if points < 2:
        raise ValueError(f"points must be >= 2, got {points!r}")
    noises = np.geomspace(1e-4, 1e-2, points)
    fig, (vax, tax) = plt.subplots(1, 2, figsize=(10.5, 4.2))
    for att in attitude_noises:
        vel, tilt = [], []
        for pos in noises:
            pose = base.pose.model_copy(update={"position_noise": pos, "attitude_noise": att})
            lim = hover_estimate_limits(base.model_copy(update={"pose": pose}))
            vel.append(lim.velocity)
            tilt.append(lim.attitude)
        label = f"attitude {att * 1e3:g} mrad ({np.degrees(att):.2g} deg)"
        vax.loglog(noises * 1e3, np.array(vel) * 1e3, label=label)
        tax.loglog(noises * 1e3, np.array(tilt) * 1e3, label=label)
    own = hover_estimate_limits(base)
    for ax, value in ((vax, own.velocity), (tax, own.attitude)):
        ax.plot(base.pose.position_noise * 1e3, value * 1e3, "k*", ms=11, label="this suite")
        ax.set_xlabel("pose position noise per sample (mm)")
        ax.grid(alpha=0.3, which="both")
    vax.set_ylabel("horizontal velocity error (mm/s, 1 sigma)")
    tax.set_ylabel("tilt error (mrad, 1 sigma)")
    vax.legend(fontsize=7)
    imu = base.imu
    fig.suptitle(
        f"Optimal hover estimate from the pose sensor ({base.pose.rate_hz:g} Hz) and the IMU "
        f"({imu.rate_hz:g} Hz, gyro {imu.gyro_noise * 1e3:g} mrad/s, "
        f"accelerometer {imu.accel_noise:g} m/s^2)"
    )
    if path is not None:
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
    return fig


def main(argv=None) -> int:
    return figure_main(sensor_limits_figure, "sensor_limits.png", argv)


if __name__ == "__main__":
    raise SystemExit(main())
