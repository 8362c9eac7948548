"""Proprioceptive sensors of a TD-ACM: drone pose, IMU, tendon encoders.

Each sensor samples the *plant* state ``(t, q, qd, qdd)`` when polled (the loop polls every
control period), on its own schedule (``rate_hz``; a capture happens at the first poll at or
after each scheduled time, so in a 50 Hz loop the effective rate is at most 50 Hz), delays the
result by ``latency`` seconds (delivered at the first poll at or after ``t_capture +
latency``) and loses a captured sample with probability ``dropout``. ``sample`` returns a small
frozen measurement carrying its capture time ``t``, or ``None`` when nothing new is delivered.
Every sensor draws from its own ``numpy.random.Generator`` seeded by ``(seed, stream)``, so a
run is reproducible from its seed and adding one sensor does not change another's noise.

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

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..system.tdacm import TDACM
from .config import EncoderConfig, ImuConfig, SensorSuiteConfig
from .kernels import body_rate, specific_force, tendon_lengths_and_jacobian

_EPS_T = 1e-9


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
def _rotvec_exp(w):
    th = float(np.linalg.norm(w))
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(th) / th * k + (1 - math.cos(th)) / th**2 * (k @ k)


class _Sensor:
    """Schedule, latency and dropout shared by every sensor (see module docstring)."""

    def __init__(self, config, rng: np.random.Generator, t0: float = 0.0):
        self.config = config
        self.rng = rng
        self.period = 1.0 / config.rate_hz
        self.reset(t0)

    def reset(self, t0: float = 0.0) -> None:
        self._next = float(t0)
        self._queue: deque = deque()

    def _capture(self, t, q, qd, qdd):  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, t: float, q, qd, qdd=None):
        """Poll at time ``t`` with the plant state; the delivered measurement or ``None``."""
        c = self.config
        if not c.enabled:
            return None
        if t >= self._next - _EPS_T:
            # one capture per poll at most; the schedule stays on its grid
            while self._next <= t + _EPS_T:
                self._next += self.period
            meas = self._capture(float(t), q, qd, qdd)
            lost = c.dropout > 0 and self.rng.random() < c.dropout
            if meas is not None and not lost:
                self._queue.append((t + c.latency, meas))
        out = None
        while self._queue and self._queue[0][0] <= t + _EPS_T:
            out = self._queue.popleft()[1]  # the newest delivered one
        return out

    def measure(self, state):
        """The closed loop's sensor protocol (:class:`tdacm.loop.sensors.Sensors` ``other``):
        poll with a :class:`~tdacm.loop.data.PlantState`."""
        return self.sample(state.t, state.q, state.qd, getattr(state, "qdd", None))


class DronePoseSensor(_Sensor):
    """Position with isotropic Gaussian noise; attitude ``R exp([n]x)`` with a body-frame
    Gaussian rotation vector ``n``."""

    def _capture(self, t, q, qd, qdd):
        c = self.config
        from ..lie.euler import rot_zyx

        r = rot_zyx(q[0], q[1], q[2])
        p = np.asarray(q[3:6], float) + c.position_noise * self.rng.standard_normal(3)
        r_m = r @ _rotvec_exp(c.attitude_noise * self.rng.standard_normal(3))
        return PoseMeasurement(t, p, r_m)


class Imu(_Sensor):
    """Gyro ``T(phi, theta) Phi_dot + b_g + n_g``; accelerometer ``R^T (p_ddot - g) + b_a +
    n_a`` (needs ``qdd``). Turn-on biases are drawn at construction (per run)."""

    def __init__(self, config: ImuConfig, gravity, rng, t0=0.0):
        self.gravity = np.asarray(gravity, float).copy()
        self.gyro_bias = config.gyro_bias * rng.standard_normal(3)
        self.accel_bias = config.accel_bias * rng.standard_normal(3)
        self._t_last = None
        super().__init__(config, rng, t0)

    def _capture(self, t, q, qd, qdd):
        if qdd is None:  # no input applied yet (first period): no sample
            return None
        c = self.config
        if self._t_last is not None and (c.gyro_bias_walk > 0 or c.accel_bias_walk > 0):
            h = math.sqrt(max(t - self._t_last, 0.0))
            self.gyro_bias = self.gyro_bias + c.gyro_bias_walk * h * self.rng.standard_normal(3)
            self.accel_bias = self.accel_bias + c.accel_bias_walk * h * self.rng.standard_normal(3)
        self._t_last = t
        q = np.asarray(q, float)
        w = body_rate(q, np.asarray(qd, float)) + self.gyro_bias
        f = specific_force(q, np.asarray(qdd, float), self.gravity) + self.accel_bias
        return ImuMeasurement(
            t,
            w + c.gyro_noise * self.rng.standard_normal(3),
            f + c.accel_noise * self.rng.standard_normal(3),
        )


class TendonEncoders(_Sensor):
    """``round((l(q_s) - l(q_ref) + bias + noise) / resolution) * resolution`` per tendon
    (lengths from the model's ``l(q)``, the same quadrature as ``B_s``)."""

    def __init__(self, config: EncoderConfig, system: TDACM, rng, q_ref=None, t0=0.0):
        self.model = system.model_arrays
        self.n_s = system.n_s
        qs_ref = np.zeros(system.n_s) if q_ref is None else np.asarray(q_ref, float)
        if qs_ref.shape != (system.n_s,):
            raise ValueError(f"q_ref must hold the {system.n_s} strains, got {qs_ref.shape}")
        self.q_ref = qs_ref
        self.l_ref = tendon_lengths_and_jacobian(qs_ref, self.model)[0]
        self.bias = config.bias * rng.standard_normal(system.n_a)
        super().__init__(config, rng, t0)

    def _capture(self, t, q, qd, qdd):
        c = self.config
        qs = np.asarray(q, float)[-self.n_s :]
        dl = tendon_lengths_and_jacobian(qs, self.model)[0] - self.l_ref + self.bias
        dl = dl + c.noise * self.rng.standard_normal(dl.shape)
        if c.resolution > 0:
            dl = np.round(dl / c.resolution) * c.resolution
        return EncoderMeasurement(t, dl)


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
