"""Scenario keys of the proprioceptive sensors and of the estimator, validated on load."""

import pytest

from tdacm.estimation import EstimatorConfig, SensorSuiteConfig
from tdacm.sim.scenario import ScenarioError, load_scenario


def test_defaults_are_the_true_state_and_the_documented_sensors():
    sc = load_scenario("paper-in-fov")
    assert sc["estimation"]["source"] == "true"
    cfg = SensorSuiteConfig.from_section(sc["sensors"])
    assert cfg == SensorSuiteConfig()
    assert EstimatorConfig.from_section(sc["estimation"]) == EstimatorConfig()


def test_overrides_are_applied():
    sc = load_scenario("paper-in-fov").with_overrides(
        {"estimation": {"source": "estimated", "rk4_steps": 2}, "sensors": {"pose_latency": 0.04}}
    )
    assert sc["estimation"]["source"] == "estimated"
    assert EstimatorConfig.from_section(sc["estimation"]).rk4_steps == 2
    assert SensorSuiteConfig.from_section(sc["sensors"]).pose.latency == 0.04


@pytest.mark.parametrize(
    "data, key",
    [
        ({"estimation": {"source": "kalman"}}, "estimation.source"),
        ({"estimation": {"initial_guess": "zero"}}, "estimation.initial_guess"),
        ({"estimation": {"rk4_steps": 0}}, "estimation.rk4_steps"),
        ({"estimation": {"accel_noise_strain": -1.0}}, "estimation.accel_noise_strain"),
        ({"estimation": {"initial_strain_std": 0.0}}, "estimation.initial_strain_std"),
        ({"estimation": {"filter": "ukf"}}, "estimation.filter"),
        ({"sensors": {"pose_dropout": 1.0}}, "sensors.pose_dropout"),
        ({"sensors": {"pose_rate": 0.0}}, "sensors.pose_rate"),
        ({"sensors": {"encoder_resolution": -1e-5}}, "sensors.encoder_resolution"),
        ({"sensors": {"gyro_bias": "big"}}, "sensors.gyro_bias"),
        ({"sensors": {"pixel_noise": -1.0}}, "sensors.pixel_noise"),
        ({"estimation": {"camera_pixel_sigma": 0.0}}, "estimation.camera_pixel_sigma"),
        (
            {"estimation": {"target_initial_position_std": -1.0}},
            "estimation.target_initial_position_std",
        ),
        (
            {"estimation": {"target_initial_attitude_std": 0.0}},
            "estimation.target_initial_attitude_std",
        ),
        ({"estimation": {"fuse_local_camera": 1}}, "estimation.fuse_local_camera"),
    ],
)
def test_invalid_values_name_the_key(data, key):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        load_scenario("paper-in-fov").with_overrides(data)
