"""Parameter records of the estimation layer: the proprioceptive sensors (scenario keys
``sensors.pose_*``, ``sensors.imu_*``/``gyro_*``/``accel_*``, ``sensors.encoder_*``), the
filter's tuning (:class:`EstimatorConfig`) and the scenario section ``[estimation]``
(:class:`EstimationConfig`: the filter's tuning plus how the run uses it).

Every default and range is written here once; the scenario model (:mod:`tdacm.sim.config`)
composes these records, so the filter, the sensors and the scenario file cannot disagree.
The reasons for the default values are in ``docs/estimation.md``.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import ValidationError, create_model

from .._config import ConfigModel, Field

_RATE = "Hz, sampling rate (a capture at the first control period at or after each tick)"
_LAT = "s, delay between capture and delivery"
_DROP = "probability that a captured sample is lost, in [0, 1)"


class PoseSensorConfig(ConfigModel):
    """Drone pose (motion capture or VIO); scenario keys ``sensors.pose_*``."""

    enabled: bool = Field(True, description="drone pose sensor present")
    rate_hz: float = Field(50.0, gt=0, description=_RATE)
    latency: float = Field(0.02, ge=0, description=_LAT + " (mocap + radio link)")
    position_noise: float = Field(0.003, ge=0, description="m, noise std per axis")
    attitude_noise: float = Field(
        0.005, ge=0, description="rad, noise std per body axis (rotation vector)"
    )
    dropout: float = Field(0.0, ge=0, lt=1, description=_DROP)


class ImuConfig(ConfigModel):
    """IMU at the drone's centre of mass; scenario keys ``sensors.imu_*``, ``gyro_*``,
    ``accel_*``. Noises are per delivered sample; bias = std of the constant turn-on bias;
    ``*_bias_walk`` = random-walk density (unit/s/sqrt(s))."""

    enabled: bool = Field(True, description="IMU present")
    rate_hz: float = Field(50.0, gt=0, description=_RATE)
    latency: float = Field(0.0, ge=0, description=_LAT)
    gyro_noise: float = Field(0.005, ge=0, description="rad/s, gyro noise std per sample")
    gyro_bias: float = Field(0.005, ge=0, description="rad/s, std of the gyro turn-on bias")
    gyro_bias_walk: float = Field(0.0, ge=0, description="rad/s/sqrt(s), gyro bias random walk")
    accel_noise: float = Field(0.05, ge=0, description="m/s^2, accelerometer noise std per sample")
    accel_bias: float = Field(
        0.05, ge=0, description="m/s^2, std of the accelerometer turn-on bias"
    )
    accel_bias_walk: float = Field(
        0.0, ge=0, description="m/s^2/sqrt(s), accelerometer bias random walk"
    )
    dropout: float = Field(0.0, ge=0, lt=1, description=_DROP)


class EncoderConfig(ConfigModel):
    """Tendon-motor encoders; scenario keys ``sensors.encoder_*``."""

    enabled: bool = Field(True, description="tendon encoders present")
    rate_hz: float = Field(50.0, gt=0, description=_RATE)
    latency: float = Field(0.0, ge=0, description=_LAT)
    resolution: float = Field(1e-5, ge=0, description="m of tendon per count (0: no quantization)")
    noise: float = Field(5e-6, ge=0, description="m, noise std of a tendon length change")
    bias: float = Field(
        0.0, ge=0, description="m, std of a constant per-tendon offset (slack, friction)"
    )
    dropout: float = Field(0.0, ge=0, lt=1, description=_DROP)

    @property
    def variance(self) -> float:
        """Noise variance seen by a filter: white noise plus uniform quantization ``res^2/12``."""
        return self.noise**2 + self.resolution**2 / 12.0


_SUB = {"pose": PoseSensorConfig, "imu": ImuConfig, "encoders": EncoderConfig}


def _flat_key(sub: str, name: str) -> str:
    """A sub-record's field under its ``[sensors]`` name: ``<sensor>_<field>`` with ``rate``
    for ``rate_hz`` (``pose_rate``, ``encoder_noise``), the IMU's ``gyro_*`` and ``accel_*``
    as they are."""
    if name.startswith(("gyro_", "accel_")):
        return name
    prefix = {"pose": "pose", "imu": "imu", "encoders": "encoder"}[sub]
    return f"{prefix}_{'rate' if name == 'rate_hz' else name}"


#: flat scenario key (section ``[sensors]``) -> (sub-record, field)
SENSOR_KEYS = {
    _flat_key(sub, name): (sub, name) for sub, rec in _SUB.items() for name in rec.model_fields
}

#: The proprioceptive keys of ``[sensors]`` as one flat record: each field is the sub-record's
#: field (same default, range and description) under its scenario name.
ProprioceptiveSensors = create_model(
    "ProprioceptiveSensors",
    __base__=ConfigModel,
    __doc__="Proprioceptive sensors (used when ``estimation.source = 'estimated'``).",
    **{
        key: (_SUB[sub].model_fields[name].annotation, _SUB[sub].model_fields[name])
        for key, (sub, name) in SENSOR_KEYS.items()
    },
)


class SensorSuiteConfig(ConfigModel):
    """The three proprioceptive sensors' specifications."""

    pose: PoseSensorConfig = PoseSensorConfig()
    imu: ImuConfig = ImuConfig()
    encoders: EncoderConfig = EncoderConfig()

    KEYS: ClassVar[dict] = SENSOR_KEYS

    @classmethod
    def from_section(cls, section: dict) -> SensorSuiteConfig:
        """From a scenario's ``[sensors]`` dict (camera keys are ignored here); a ``ValueError``
        names the key (``sensors.<key>``)."""
        flat = {k: v for k, v in section.items() if k in SENSOR_KEYS}
        try:
            rec = ProprioceptiveSensors(**flat)
        except ValidationError as exc:
            err = exc.errors()[0]
            raise ValueError(
                f"sensors.{err['loc'][0]}: {err['msg']}, got {err['input']!r}"
            ) from None
        return cls.from_config(rec)

    @classmethod
    def from_config(cls, sensors) -> SensorSuiteConfig:
        """From a record with the flat ``[sensors]`` keys (:data:`ProprioceptiveSensors`, or
        the scenario's ``[sensors]`` record)."""
        parts = {"pose": {}, "imu": {}, "encoders": {}}
        for key, (sub, name) in SENSOR_KEYS.items():
            parts[sub][name] = getattr(sensors, key)
        return cls(pose=PoseSensorConfig(**parts["pose"]), imu=ImuConfig(**parts["imu"]),
                   encoders=EncoderConfig(**parts["encoders"]))  # fmt: skip


class EstimatorConfig(ConfigModel):
    """Filter tuning (the EKF's part of ``[estimation]``, same names). Units: rad, m, rad/m
    for the strains; noise densities per sqrt(Hz). See ``docs/estimation.md``."""

    model_config = {"title": "estimation"}

    rk4_steps: int = Field(1, ge=1, description="RK4 steps of the filter's prediction per period")
    accel_noise_angular: float = Field(
        0.1, ge=0, description="rad/s^2/sqrt(Hz), process noise of the drone's Euler angles"
    )
    accel_noise_linear: float = Field(
        0.005, ge=0, description="m/s^2/sqrt(Hz), process noise of the drone's position"
    )
    accel_noise_strain: float = Field(
        0.2, ge=0, description="rad/m/s^2/sqrt(Hz), process noise of the strains"
    )
    disturbance_walk_angular: float = Field(
        1.0, ge=0, description="rad/s^3/sqrt(Hz), random walk of the angular disturbance"
    )
    disturbance_walk_linear: float = Field(
        0.02, ge=0, description="m/s^3/sqrt(Hz), random walk of the linear disturbance"
    )
    disturbance_walk_strain: float = Field(
        0.3, ge=0, description="rad/m/s^3/sqrt(Hz), random walk of the strain disturbance"
    )
    accel_model_error: float = Field(
        0.03, ge=0, description="m/s^2, added in quadrature to the accelerometer's noise"
    )
    model_error_fraction: float = Field(
        0.1, ge=0, description="relative error of the predicted acceleration"
    )
    initial_attitude_std: float = Field(0.02, gt=0, description="rad, initial attitude std")
    initial_position_std: float = Field(0.02, gt=0, description="m, initial position std")
    initial_strain_std: float = Field(0.3, gt=0, description="rad/m, initial strain std")
    initial_velocity_std: float = Field(
        0.1, gt=0, description="rad/s, m/s, rad/m/s, initial velocity std"
    )
    initial_disturbance_angular_std: float = Field(
        2.0, ge=0, description="rad/s^2, initial std of the angular disturbance"
    )
    initial_disturbance_linear_std: float = Field(
        1.5, ge=0, description="m/s^2, initial std of the linear disturbance (gravity error)"
    )
    initial_disturbance_strain_std: float = Field(
        5.0, ge=0, description="rad/m/s^2, initial std of the strain disturbance"
    )
    max_delay: float = Field(
        0.2, ge=0, description="s of filter history kept for late measurements"
    )

    @classmethod
    def from_section(cls, section: dict) -> EstimatorConfig:
        return cls(**{k: v for k, v in section.items() if k in cls.model_fields})

    @classmethod
    def from_config(cls, estimation) -> EstimatorConfig:
        """The filter's part of an ``[estimation]`` record."""
        return cls(**{k: getattr(estimation, k) for k in cls.model_fields})


class EstimationConfig(EstimatorConfig):
    """Section ``[estimation]``: the state source of everything downstream of the sensors,
    the filter's tuning and its start."""

    model_config = {"title": "estimation"}

    source: Literal["true", "estimated"] = Field(
        "true", description="'true': the plant state; 'estimated': the EKF's estimate"
    )
    initial_guess: Literal["measured", "true"] = Field(
        "measured",
        description="'measured': pose + tendon-length inversion; 'true': the plant state",
    )
    initial_strain_error: float = Field(
        0.0, description="rad/m added to every strain of the initial guess"
    )
    initial_position_error: float = Field(
        0.0, description="m added to every drone position coordinate of the initial guess"
    )
    fuse_local_camera: bool = Field(
        True, description="fuse the tip camera's view of the static target (target pose states)"
    )
    camera_pixel_sigma: float = Field(1.0, gt=0, description="px, corner noise the filter assumes")
    target_initial_position_std: float = Field(
        0.05, gt=0, description="m, target position prior at its first view"
    )
    target_initial_attitude_std: float = Field(
        0.05, gt=0, description="rad, target attitude prior at its first view"
    )
    controller_truth: str = Field(
        "",
        description="ablation (a diagnostic, off): coordinates the low-level controller reads "
        "from the plant instead of the estimate, e.g. 'qd[3:5]'",
    )
