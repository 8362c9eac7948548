"""The sensor-sizing chart of docs/estimation.md is drawn from hover_estimate_limits."""

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tdacm.estimation import hover_estimate_limits  # noqa: E402
from tdacm.viz.sensors import DEFAULT_ATTITUDE_NOISES, sensor_limits_figure  # noqa: E402


def test_sensor_limits_figure_is_written_from_the_limits(tmp_path):
    path = tmp_path / "sensors.png"
    fig = sensor_limits_figure(path, points=9)
    assert path.stat().st_size > 10_000
    vax, tax = fig.axes
    curves = [line for line in vax.get_lines() if line.get_label().startswith("attitude")]
    assert len(curves) == len(DEFAULT_ATTITUDE_NOISES)
    # the star is the default suite, in mm and mm/s
    star = next(line for line in vax.get_lines() if line.get_label() == "this suite")
    lim = hover_estimate_limits()
    np.testing.assert_allclose(star.get_xdata(), [3.0])
    np.testing.assert_allclose(star.get_ydata(), [lim.velocity * 1e3])
    # over the drawn decade pair the velocity error grows as the fourth root of the position
    # noise once the tilt is known well (double integrator: P_vv ~ r^(1/4), r ~ sigma_p^2)
    x, y = curves[0].get_xdata(), curves[0].get_ydata()
    slope = np.log(y[-1] / y[0]) / np.log(x[-1] / x[0])
    assert 0.2 < slope < 0.3, slope


def test_sensor_limits_figure_needs_two_points():
    with pytest.raises(ValueError, match="points"):
        sensor_limits_figure(None, points=1)
