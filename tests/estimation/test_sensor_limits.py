"""The hover limits of a sensor suite (:mod:`tdacm.estimation.sensor_limits`) against the
closed-form steady states of the Kalman filters they reduce to."""

import numpy as np
import pytest

from tdacm.estimation import (
    HoverEstimateLimits,
    ImuConfig,
    PinnedView,
    PoseSensorConfig,
    SensorSuiteConfig,
    hover_estimate_limits,
)


def suite(pose=None, imu=None):
    return SensorSuiteConfig(pose=PoseSensorConfig(**(pose or {})), imu=ImuConfig(**(imu or {})))


def test_a_noise_free_gyro_leaves_the_double_integrator():
    # Tilt known exactly: p'' = w_a with p measured. Steady state of that filter (white
    # acceleration density q, position density r): P_pp = sqrt(2) q^(1/4) r^(3/4),
    # P_vv = sqrt(2) q^(3/4) r^(1/4).
    s = suite(pose={"position_noise": 0.002}, imu={"gyro_noise": 0.0, "accel_noise": 0.04})
    q = 0.04**2 / s.imu.rate_hz
    r = 0.002**2 / s.pose.rate_hz
    lim = hover_estimate_limits(s)
    np.testing.assert_allclose(lim.position**2, np.sqrt(2) * q**0.25 * r**0.75, rtol=1e-4)
    np.testing.assert_allclose(lim.velocity**2, np.sqrt(2) * q**0.75 * r**0.25, rtol=1e-4)


def test_without_a_position_the_tilt_is_a_random_walk_seen_through_noise():
    # A position sensor too poor to matter: theta' = n_g with theta measured, whose steady
    # state is P = sqrt(q r) (q the gyro's density, r the attitude sensor's).
    s = suite(pose={"position_noise": 1e4, "attitude_noise": 0.004}, imu={"gyro_noise": 0.003})
    q = 0.003**2 / s.imu.rate_hz
    r = 0.004**2 / s.pose.rate_hz
    lim = hover_estimate_limits(s)
    np.testing.assert_allclose(lim.attitude**2, np.sqrt(q * r), rtol=1e-4)


def test_the_default_suite_and_a_motion_capture_pose():
    default = hover_estimate_limits()
    assert isinstance(default, HoverEstimateLimits)
    # the figures docs/estimation.md quotes (3 mm / 5 mrad pose, 50 Hz)
    assert default.velocity == pytest.approx(4.58e-3, rel=0.01)
    assert default.attitude == pytest.approx(0.649e-3, rel=0.01)
    mocap = hover_estimate_limits(suite(pose={"position_noise": 0.001, "attitude_noise": 0.00175}))
    assert mocap.position < default.position
    assert mocap.velocity < default.velocity
    assert mocap.attitude < default.attitude
    # the gravity scales the tilt's effect: on the Moon the same tilt error costs less velocity
    moon = hover_estimate_limits(gravity=1.62)
    assert moon.velocity < default.velocity


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"pose": {"enabled": False}}, "sensors.pose_enabled"),
        ({"imu": {"enabled": False}}, "sensors.imu_enabled"),
        ({"pose": {"position_noise": 0.0}}, "sensors.pose_position_noise"),
        ({"pose": {"attitude_noise": 0.0}}, "sensors.pose_attitude_noise"),
    ],
)
def test_a_suite_the_model_cannot_use_names_its_key(kwargs, key):
    with pytest.raises(ValueError, match=key):
        hover_estimate_limits(suite(**kwargs))


def test_gravity_must_be_positive():
    with pytest.raises(ValueError, match="gravity"):
        hover_estimate_limits(gravity=0.0)


def test_a_view_without_lever_is_one_more_position_sensor():
    # lever -> 0: the view measures p, and two independent position sensors at one rate are
    # one of variance 1 / (1 / r1 + 1 / r2)
    view = PinnedView(lever=1e-9, noise=0.002, rate_hz=50.0)
    both = hover_estimate_limits(view=view)
    r = 1.0 / (1.0 / 0.003**2 + 1.0 / 0.002**2)
    one = hover_estimate_limits(suite(pose={"position_noise": float(np.sqrt(r))}))
    np.testing.assert_allclose(
        [both.position, both.velocity, both.attitude],
        [one.position, one.velocity, one.attitude],
        rtol=1e-6,
    )


def test_a_pinned_view_bounds_the_tilt_by_the_position_over_the_lever():
    # the tip camera pressed on the marker (touch-target): 1.1 m below the centre of mass,
    # 1 px of 886.8 px at 0.305 m over 4 corners, 50 Hz; the figures docs/contact.md quotes
    view = PinnedView(lever=1.1, noise=0.305 / 886.8 / 2.0, rate_hz=50.0)
    free = hover_estimate_limits()
    pinned = hover_estimate_limits(view=view)
    assert pinned.attitude == pytest.approx(0.456e-3, rel=0.01)
    assert pinned.velocity == pytest.approx(2.54e-3, rel=0.01)
    assert pinned.attitude < free.attitude and pinned.velocity < free.velocity
    # a nearly exact view (0.01 mm) and an attitude sensor of 1 rad: the tilt is known only
    # through theta = (view - p) / lever, its error the position's over the lever
    s = suite(pose={"attitude_noise": 1.0})
    exact = hover_estimate_limits(s, view=PinnedView(1.1, 1e-5, 50.0))
    assert exact.attitude == pytest.approx(exact.position / 1.1, rel=1e-3)


@pytest.mark.parametrize("field", ["lever", "noise", "rate_hz"])
def test_a_pinned_view_needs_positive_values(field):
    kw = {"lever": 1.0, "noise": 1e-4, "rate_hz": 50.0, field: 0.0}
    with pytest.raises(ValueError, match=field):
        PinnedView(**kw)
