"""Proprioceptive sensors of a TD-ACM: drone pose, IMU, tendon encoders.

Each sensor samples the *plant* state ``(t, q, qd, qdd)`` when polled (the loop polls every
control period), on its own schedule (``rate_hz``; a capture happens at the first poll at or
after each scheduled time, so in a 50 Hz loop the effective rate is at most 50 Hz), delays the
result by ``latency`` seconds (delivered at the first poll at or after ``t_capture +
latency``) and loses a captured sample with probability ``dropout``. ``sample`` returns a small
frozen measurement carrying its capture time ``t``, or ``None`` when nothing new is delivered.
Every sensor draws from its own ``numpy.random.Generator`` seeded by ``(seed, stream)``, so a
run is reproducible from its seed and adding one sensor does not change another's noise. Each
sensor is a Python block over its compiled poll (:mod:`~tdacm.estimation.sensor_steps`, the
records and steps the batched engine calls too): the block draws the capture's random numbers
in the order that module states and passes them in.

Defaults, typical of the hardware class (a 0.7 kg quadrotor with a PX4/ArduPilot-class flight
controller, a motion-capture or good visual-inertial pose, tendon motors with encoders); the
reasons are in ``docs/estimation.md``:

* drone pose: 50 Hz (what a flight controller typically receives as external vision/mocap
  input), 20 ms latency (mocap + radio link), position noise 3 mm, attitude noise 0.3 deg
  (5 mrad) as a body-frame rotation vector;
* IMU at the drone's centre of mass, delivered at the loop rate: the sample is the plant's
  body rate and specific force at the capture time, with the noise of a flight controller's
  average of its 1 kHz samples (for the specific force, the period's mean differs from the
  instantaneous value by 0.002-0.003 m/s^2 in flight, far below the noise): gyro noise
  5 mrad/s and a turn-on bias of std 5 mrad/s (after the usual stationary calibration);
  accelerometer = specific force ``R_b^T (p_ddot - g)`` in the body frame, noise 0.05 m/s^2
  (vibration-dominated in flight), turn-on bias std 0.05 m/s^2; optional bias random walks;
* tendon encoders: the change of each tendon's path length ``l_i(q) - l_i(q_ref)`` (encoders
  zeroed with the rod straight, ``q_ref = 0``), quantized at 10 um (a 4096-count encoder on a
  6.5 mm spool radius), noise 5 um; ``bias`` draws a constant offset per tendon (slack or
  friction in the routing) of that standard deviation, off by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..system.tdacm import TDACM
from . import sensor_steps as SS
from .config import EncoderConfig, ImuConfig, SensorSuiteConfig
from .kernels import tendon_lengths_and_jacobian


# ----------------------------------------------------------------------------- measurements
@dataclass(frozen=True)
class PoseMeasurement:
    """Drone pose captured at ``t``: inertial position (3,) and attitude ``R_b`` (3, 3)."""

    t: float
    position: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True)
class ImuMeasurement:
    """Body angular velocity (3,) and specific force in the body frame (3,) at ``t``."""

    t: float
    gyro: np.ndarray
    accel: np.ndarray


@dataclass(frozen=True)
class EncoderMeasurement:
    """Change of each tendon's length from the zeroing configuration (n_a,), metres."""

    t: float
    delta_length: np.ndarray


# ----------------------------------------------------------------------------- sensors
class _Sensor:
    """Schedule, latency and dropout shared by every sensor (see module docstring): a Python
    block over the compiled poll of :mod:`~tdacm.estimation.sensor_steps` (its records
    ``params`` and ``state``); the random numbers come from ``rng``, drawn here in the order
    that module states."""

    def __init__(self, config, rng: np.random.Generator, t0: float = 0.0):
        self.config = config
        self.rng = rng
        self.period = 1.0 / config.rate_hz
        self.reset(t0)

    def _base_state(self) -> SS.SensorState:  # pragma: no cover - abstract
        raise NotImplementedError

    def reset(self, t0: float = 0.0) -> None:
        """The schedule starts at ``t0`` with nothing in flight (drawn biases are kept)."""
        SS.sensor_reset(self._base_state(), float(t0))

    def _draw(self, due: bool, normals: int):
        """The capture's standard normals and dropout uniform (module docstring's order)."""
        if not due:
            return _NO_NORMALS, 0.0
        z = self.rng.standard_normal(normals) if normals else _NO_NORMALS
        u01 = self.rng.random() if self.config.dropout > 0 else 0.0
        return z, u01

    def measure(self, state):
        """The closed loop's sensor protocol (:class:`tdacm.loop.sensors.Sensors` ``other``):
        poll with a :class:`~tdacm.loop.data.PlantState`."""
        return self.sample(state.t, state.q, state.qd, getattr(state, "qdd", None))


_NO_NORMALS = np.zeros(0)


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


class DronePoseSensor(_Sensor):
    """Position with isotropic Gaussian noise; attitude ``R exp([n]x)`` with a body-frame
    Gaussian rotation vector ``n`` (:func:`~.sensor_steps.pose_sample`)."""

    def __init__(self, config, rng: np.random.Generator, t0: float = 0.0):
        c = config
        self.params = SS.PoseParams(
            SS.SensorParams.from_config(c), float(c.position_noise), float(c.attitude_noise)
        )
        self.state = SS.SensorState.empty(12, SS.queue_capacity(c), t0)
        self._out = np.empty(12)
        super().__init__(config, rng, t0)

    def _base_state(self):
        return self.state

    def sample(self, t: float, q, qd, qdd=None):
        """Poll at time ``t`` with the plant state; the delivered measurement or ``None``."""
        t = float(t)
        p = self.params
        z, u01 = self._draw(SS.sensor_due(p.base, self.state, t), SS.pose_normals(p))
        tc = SS.pose_sample(p, self.state, t, _f(q), z, u01, self._out)
        if tc != tc:  # NaN: nothing delivered
            return None
        o = self._out
        return PoseMeasurement(float(tc), o[:3].copy(), o[3:12].reshape(3, 3).copy())


class Imu(_Sensor):
    """Gyro ``T(phi, theta) Phi_dot + b_g + n_g``; accelerometer ``R^T (p_ddot - g) + b_a +
    n_a`` (needs ``qdd``; :func:`~.sensor_steps.imu_sample`). Turn-on biases are drawn at
    construction (per run)."""

    def __init__(self, config: ImuConfig, gravity, rng, t0=0.0):
        c = config
        self.params = SS.ImuParams(
            SS.SensorParams.from_config(c), float(c.gyro_noise), float(c.accel_noise),
            float(c.gyro_bias_walk), float(c.accel_bias_walk), _f(gravity).copy(),
            float(c.gyro_bias), float(c.accel_bias),
        )  # fmt: skip
        self.state = SS.ImuState(
            SS.SensorState.empty(6, SS.queue_capacity(c), t0), np.zeros(3), np.zeros(3),
            np.full(1, np.nan),
        )  # fmt: skip
        SS.imu_turn_on(self.params, self.state, rng.standard_normal(6))
        self._out = np.empty(6)
        super().__init__(config, rng, t0)

    @property
    def gravity(self) -> np.ndarray:
        return self.params.gravity

    @property
    def gyro_bias(self) -> np.ndarray:
        return self.state.gyro_bias

    @property
    def accel_bias(self) -> np.ndarray:
        return self.state.accel_bias

    def _base_state(self):
        return self.state.base

    def sample(self, t: float, q, qd, qdd=None):
        """Poll at time ``t`` with the plant state; the delivered measurement or ``None``."""
        t = float(t)
        p, st = self.params, self.state
        has_qdd = qdd is not None
        due = SS.sensor_due(p.base, st.base, t)
        z, u01 = self._draw(due, SS.imu_normals(p, st, has_qdd) if due else 0)
        qdd = _f(qdd) if has_qdd else _NO_NORMALS
        tc = SS.imu_sample(p, st, t, _f(q), _f(qd), qdd, has_qdd, z, u01, self._out)
        if tc != tc:
            return None
        return ImuMeasurement(float(tc), self._out[:3].copy(), self._out[3:6].copy())


class TendonEncoders(_Sensor):
    """``round((l(q_s) - l(q_ref) + bias + noise) / resolution) * resolution`` per tendon
    (lengths from the model's ``l(q)``, the same quadrature as ``B_s``;
    :func:`~.sensor_steps.encoder_sample`)."""

    def __init__(self, config: EncoderConfig, system: TDACM, rng, q_ref=None, t0=0.0):
        self.model = system.model_arrays
        self.n_s = system.n_s
        qs_ref = np.zeros(system.n_s) if q_ref is None else np.asarray(q_ref, float)
        if qs_ref.shape != (system.n_s,):
            raise ValueError(f"q_ref must hold the {system.n_s} strains, got {qs_ref.shape}")
        self.q_ref = qs_ref
        c = config
        l_ref = tendon_lengths_and_jacobian(qs_ref, self.model)[0]
        self.params = SS.EncoderParams(
            SS.SensorParams.from_config(c), float(c.noise), float(c.resolution), l_ref,
            int(system.n_s), float(c.bias),
        )  # fmt: skip
        self.state = SS.EncoderState(
            SS.SensorState.empty(system.n_a, SS.queue_capacity(c), t0), np.zeros(system.n_a)
        )
        SS.encoder_turn_on(self.params, self.state, rng.standard_normal(system.n_a))
        self._out = np.empty(system.n_a)
        super().__init__(config, rng, t0)

    @property
    def l_ref(self) -> np.ndarray:
        return self.params.l_ref

    @property
    def bias(self) -> np.ndarray:
        return self.state.bias

    def _base_state(self):
        return self.state.base

    def sample(self, t: float, q, qd, qdd=None):
        """Poll at time ``t`` with the plant state; the delivered measurement or ``None``."""
        t = float(t)
        p, st = self.params, self.state
        due = SS.sensor_due(p.base, st.base, t)
        z, u01 = self._draw(due, SS.encoder_normals(p))
        tc = SS.encoder_sample(p, st, self.model, t, _f(q), z, u01, self._out)
        if tc != tc:
            return None
        return EncoderMeasurement(float(tc), self._out.copy())


class SensorSuite:
    """The proprioceptive sensors of one run (pose and IMU only for a floating base).

    ``sample(t, q, qd, qdd)`` polls each and returns the list of delivered measurements;
    ``named`` maps ``"pose"``, ``"imu"``, ``"encoders"`` to the sensors (closed-loop ``other``
    sensors). ``stream_offset`` shifts the random streams (an independent copy of the suite)."""

    #: random streams (independent of the camera's stream 1 in the runner)
    STREAMS = {"pose": 11, "imu": 12, "encoders": 13}

    def __init__(self, system: TDACM, config: SensorSuiteConfig | None = None, seed: int = 0,
                 t0: float = 0.0, stream_offset: int = 0):  # fmt: skip
        self.config = SensorSuiteConfig() if config is None else config
        self.system = system
        self.sensors = []
        mk = lambda s: np.random.default_rng([int(seed), self.STREAMS[s] + int(stream_offset)])  # noqa: E731
        if system.floating:
            self.pose = DronePoseSensor(self.config.pose, mk("pose"), t0)
            self.imu = Imu(self.config.imu, system.loads.gravity, mk("imu"), t0)
            self.sensors += [self.pose, self.imu]
        else:
            self.pose = self.imu = None
        self.encoders = TendonEncoders(self.config.encoders, system, mk("encoders"), t0=t0)
        self.sensors.append(self.encoders)

    @property
    def named(self) -> dict:
        out = {"pose": self.pose, "imu": self.imu, "encoders": self.encoders}
        return {k: v for k, v in out.items() if v is not None}

    def reset(self, t0: float = 0.0) -> None:
        for s in self.sensors:
            s.reset(t0)

    def sample(self, t, q, qd, qdd=None) -> list:
        out = []
        for s in self.sensors:
            m = s.sample(t, q, qd, qdd)
            if m is not None:
                out.append(m)
        return out


def config_fields(cls) -> list[str]:
    return list(cls.model_fields)
