"""The proprioceptive sensors' compiled steps: their records and one poll of each for one world.

The sensors of :mod:`tdacm.estimation.proprioception` (drone pose, IMU, tendon encoders) are
Python blocks over these functions; the batched engine holds one state per world and calls the
same ones. A poll at time ``t`` (module :mod:`~tdacm.estimation.proprioception` has the
schedule, latency and dropout rules) is:

1. :func:`sensor_due`: whether the sensor captures at this poll;
2. if it does, the caller draws the random numbers of the capture, in this order: the
   sensor's standard normals (:func:`pose_normals`, :func:`imu_normals`,
   :func:`encoder_normals` of them) and then, when ``dropout > 0``, one uniform in ``[0, 1)``
   (the block loop from the sensor's ``numpy.random.Generator``, the engine from its world's
   stream);
3. ``*_sample``: the capture (from the true state and those numbers) queued for delivery
   ``latency`` s later, and the newest measurement delivered by ``t`` written into ``out``;
   returns its capture time, NaN when nothing new is delivered.

A measurement's data is the row of :class:`~tdacm.estimation.ekf_step.EkfMeasurements`:
position (3) and rotation row by row (9) for the pose, gyro (3) and specific force (3) for the
IMU, the tendon-length changes (n_a) for the encoders. The queue holds
:func:`queue_capacity` captures in flight.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..lie.euler import rot_zyx
from ..system.kernels import tendon_lengths_and_matrix
from .kernels import body_rate, specific_force

#: two times closer than this are the same poll (s)
EPS_T = 1e-9


class SensorParams(NamedTuple):
    """What every sensor has: ``enabled``, its ``period`` (s, ``1 / rate_hz``), ``latency``
    (s) and ``dropout`` probability."""

    enabled: bool
    period: float
    latency: float
    dropout: float

    @classmethod
    def from_config(cls, c) -> SensorParams:
        return cls(bool(c.enabled), 1.0 / float(c.rate_hz), float(c.latency), float(c.dropout))


class SensorState(NamedTuple):
    """The schedule and the queue of a sensor: ``next`` (1,) the next scheduled capture time,
    the captures in flight ``q_deliver`` (delivery times), ``q_t`` (capture times), ``q_data``
    (rows of data), a ring of ``queue`` entries from ``q_head`` (1,) with ``q_count`` (1,)."""

    next: np.ndarray
    q_deliver: np.ndarray
    q_t: np.ndarray
    q_data: np.ndarray
    q_head: np.ndarray
    q_count: np.ndarray

    @classmethod
    def empty(cls, size: int, queue: int, t0: float = 0.0) -> SensorState:
        return cls(np.full(1, float(t0)), np.zeros(queue), np.zeros(queue),
                   np.zeros((queue, size)), np.zeros(1, np.int64), np.zeros(1, np.int64))  # fmt: skip


class PoseParams(NamedTuple):
    """The drone pose sensor: its schedule ``base``, ``position_noise`` (m) and
    ``attitude_noise`` (rad, a body-frame rotation vector)."""

    base: SensorParams
    position_noise: float
    attitude_noise: float


class ImuParams(NamedTuple):
    """The IMU: its schedule ``base``, ``gyro_noise``, ``accel_noise`` per sample, the bias
    random walks ``gyro_bias_walk``, ``accel_bias_walk`` (per sqrt(s)), the model's
    ``gravity`` (3,) and the turn-on biases' standard deviations ``gyro_bias``,
    ``accel_bias`` (:func:`imu_turn_on`)."""

    base: SensorParams
    gyro_noise: float
    accel_noise: float
    gyro_bias_walk: float
    accel_bias_walk: float
    gravity: np.ndarray
    gyro_bias: float
    accel_bias: float


class ImuState(NamedTuple):
    """The IMU's schedule and queue ``base`` and its biases ``gyro_bias``, ``accel_bias`` (3,)
    (their turn-on values drawn at construction, then walking) and ``t_last`` (1,) the last
    capture time (NaN: none yet)."""

    base: SensorState
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    t_last: np.ndarray


class EncoderParams(NamedTuple):
    """The tendon encoders: their schedule ``base``, ``noise`` (m), ``resolution`` (m per
    count, 0: none), the lengths ``l_ref`` (n_a,) at their zero, the strains ``n_s`` and the
    standard deviation ``bias`` of their constant offsets (:func:`encoder_turn_on`)."""

    base: SensorParams
    noise: float
    resolution: float
    l_ref: np.ndarray
    n_s: int
    bias: float = 0.0


class EncoderState(NamedTuple):
    """The encoders' schedule and queue ``base`` and their constant ``bias`` (n_a,)."""

    base: SensorState
    bias: np.ndarray


def queue_capacity(c) -> int:
    """Captures a sensor of config ``c`` can have in flight: each takes a scheduled capture
    time, so at most those within ``latency`` plus the one being queued and one for
    rounding."""
    return int(math.ceil(float(c.latency) * float(c.rate_hz) - 1e-9)) + 3


@njit(cache=True)
def imu_turn_on(p, st, normals):
    """The IMU's turn-on biases (a run's) from 6 standard ``normals``: the gyro's 3, then the
    accelerometer's 3."""
    for i in range(3):
        st.gyro_bias[i] = p.gyro_bias * normals[i]
        st.accel_bias[i] = p.accel_bias * normals[3 + i]


@njit(cache=True)
def encoder_turn_on(p, st, normals):
    """The encoders' constant offsets (a run's) from ``n_a`` standard ``normals``."""
    for i in range(st.bias.shape[0]):
        st.bias[i] = p.bias * normals[i]


# ----------------------------------------------------------------------------- schedule
@njit(cache=True)
def sensor_due(p, st, t):
    """Whether a sensor with ``p`` (:class:`SensorParams`) and ``st`` (:class:`SensorState`)
    captures at a poll at ``t``."""
    return p.enabled and t >= st.next[0] - EPS_T


@njit(cache=True)
def sensor_reset(st, t0):
    """The schedule starts at ``t0`` with nothing in flight."""
    st.next[0] = t0
    st.q_head[0] = 0
    st.q_count[0] = 0


@njit(cache=True)
def _advance(p, st, t):
    """One capture per poll at most; the schedule stays on its grid."""
    while st.next[0] <= t + EPS_T:
        st.next[0] += p.period


@njit(cache=True)
def _queue_slot(p, st, t):
    """The queue row of a capture at ``t`` (delivered ``latency`` later); the oldest capture
    in flight makes room if the queue is full (never with :func:`queue_capacity`)."""
    size = st.q_t.shape[0]
    if st.q_count[0] == size:
        st.q_head[0] = (st.q_head[0] + 1) % size
        st.q_count[0] -= 1
    i = (st.q_head[0] + st.q_count[0]) % size
    st.q_deliver[i] = t + p.latency
    st.q_t[i] = t
    st.q_count[0] += 1
    return i


@njit(cache=True)
def _lost(p, u01):
    return p.dropout > 0.0 and u01 < p.dropout


@njit(cache=True)
def sensor_deliver(st, t, out):
    """The newest capture delivered by ``t`` (the older ones delivered with it are dropped)
    into ``out``; its capture time, NaN when none."""
    size = st.q_t.shape[0]
    got = -1
    while st.q_count[0] > 0 and st.q_deliver[st.q_head[0]] <= t + EPS_T:
        got = st.q_head[0]
        st.q_head[0] = (got + 1) % size
        st.q_count[0] -= 1
    if got < 0:
        return np.nan
    for j in range(st.q_data.shape[1]):
        out[j] = st.q_data[got, j]
    return st.q_t[got]


# ----------------------------------------------------------------------------- the sensors
@njit(cache=True)
def pose_normals(p):
    """Standard normals of a pose capture: the position's 3, then the attitude's 3."""
    return 6


@njit(cache=True)
def pose_sample(p, st, t, q, normals, u01, out):
    """Poll the pose sensor at ``t`` with the true ``q`` (module docstring): position ``q[3:6] +
    position_noise n[0:3]``, attitude ``R(q) exp([attitude_noise n[3:6]]x)``."""
    b = p.base
    if not b.enabled:
        return np.nan
    if sensor_due(b, st, t):
        _advance(b, st, t)
        if not _lost(b, u01):
            i = _queue_slot(b, st, t)
            row = st.q_data[i]
            for j in range(3):
                row[j] = q[3 + j] + p.position_noise * normals[j]
            r = rot_zyx(q[0], q[1], q[2]) @ _rotvec_exp(p.attitude_noise * normals[3:6])
            for a in range(3):
                for c in range(3):
                    row[3 + 3 * a + c] = r[a, c]
    return sensor_deliver(st, t, out)


@njit(cache=True)
def _rotvec_exp(w):
    """``exp([w]x)`` by Rodrigues' formula (first order below 1e-12 rad)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * (k @ k)


@njit(cache=True)
def imu_normals(p, st, has_qdd):
    """Standard normals of an IMU capture: none without ``qdd`` (no input applied yet: no
    sample), the bias walks' 6 (gyro, accel) after the first capture when they walk, then the
    noises' 6 (gyro, accel)."""
    if not has_qdd:
        return 0
    walks = p.gyro_bias_walk > 0.0 or p.accel_bias_walk > 0.0
    return 12 if walks and not np.isnan(st.t_last[0]) else 6


@njit(cache=True)
def imu_sample(p, st, t, q, qd, qdd, has_qdd, normals, u01, out):
    """Poll the IMU at ``t`` with the true ``q``, ``qd`` and ``qdd`` (``has_qdd`` False: none
    yet, no sample): the biases walk by ``walk sqrt(t - t_last)`` times normals, then gyro
    ``T(phi, theta) Phi_dot + b_g + gyro_noise n``, specific force ``R^T (p_ddot - g) + b_a +
    accel_noise n`` (module docstring)."""
    b = p.base
    if not b.enabled:
        return np.nan
    sb = st.base
    if sensor_due(b, sb, t):
        _advance(b, sb, t)
        if has_qdd:
            k = 0
            if imu_normals(p, st, has_qdd) == 12:
                h = np.sqrt(max(t - st.t_last[0], 0.0))
                st.gyro_bias[:] = st.gyro_bias + p.gyro_bias_walk * h * normals[0:3]
                st.accel_bias[:] = st.accel_bias + p.accel_bias_walk * h * normals[3:6]
                k = 6
            st.t_last[0] = t
            w = body_rate(q, qd) + st.gyro_bias
            f = specific_force(q, qdd, p.gravity) + st.accel_bias
            if not _lost(b, u01):
                i = _queue_slot(b, sb, t)
                row = sb.q_data[i]
                for j in range(3):
                    row[j] = w[j] + p.gyro_noise * normals[k + j]
                    row[3 + j] = f[j] + p.accel_noise * normals[k + 3 + j]
    return sensor_deliver(sb, t, out)


@njit(cache=True)
def encoder_normals(p):
    """Standard normals of an encoder capture: one per tendon."""
    return p.l_ref.shape[0]


@njit(cache=True)
def encoder_sample(p, st, m, t, q, normals, u01, out):
    """Poll the encoders at ``t`` with the true ``q`` on the model arrays ``m`` of the true
    system: ``round((l(q_s) - l(q_ref) + bias + noise n) / resolution) * resolution`` per
    tendon (module docstring)."""
    b = p.base
    if not b.enabled:
        return np.nan
    sb = st.base
    if sensor_due(b, sb, t):
        _advance(b, sb, t)
        if not _lost(b, u01):
            qs = q[q.shape[0] - p.n_s :]
            dl = tendon_lengths_and_matrix(qs, m)[0] - p.l_ref + st.bias
            dl = dl + p.noise * normals[: dl.shape[0]]
            if p.resolution > 0:
                dl = np.round(dl / p.resolution) * p.resolution
            i = _queue_slot(b, sb, t)
            sb.q_data[i, : dl.shape[0]] = dl
    return sensor_deliver(sb, t, out)
