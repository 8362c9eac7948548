"""The estimator as the closed loop's estimation block (``estimation.source = "estimated"``).

:class:`FilterBlock` adapts :class:`~tdacm.estimation.ekf.ExtendedKalmanFilter` to the loop's
protocol (:class:`tdacm.loop.protocols.Estimator`): ``reset(t)`` starts the filter from an initial
guess, ``step(readings, u_applied, dt)`` fuses the proprioceptive measurements of
``readings.other`` (drone pose, IMU, encoders) with the input applied over the last period.
It never sees the plant: the initial guess comes either from one reading of the sensors at the
start (``initial_guess = "measured"``: drone pose from the pose sensor, strains from the
tendon lengths by least squares) or from the scenario's nominal initial configuration
(``"true"``: what a take-off procedure would know), plus the configured initial errors.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numba import njit

from .camera import TargetViewMeasurement
from .ekf import EstimatorDiverged, ExtendedKalmanFilter
from .ekf_step import DIVERGENCE, OK, ekf_reset, ekf_step, initial_estimate, view_is_new
from .estimate import StateEstimate
from .proprioception import EncoderMeasurement, ImuMeasurement, PoseMeasurement

#: what the filter fuses (other sensors in ``readings.other`` are left to their consumers)
_KNOWN = (PoseMeasurement, ImuMeasurement, EncoderMeasurement)


@njit(cache=True)
def filter_start(p, st, m, meas, nominal, q_ref, strain_error, position_error, t0, u, measured,
                 x0):  # fmt: skip
    """The estimator's start at ``t0`` (:meth:`FilterBlock.reset`, and the batched engine's
    for each world): the configuration from the start-up reading ``meas``
    (:func:`~.ekf_step.initial_estimate`: the nominal one plus the configured errors for what
    no reading measures), the filter reset there (zero velocities, disturbances and biases;
    the covariance ``p.p0``) and, with a start-up reading (``measured``), fused at once
    (:func:`~.ekf_step.ekf_step` at ``t0``, no input applied: ``u`` unused). ``x0`` (nx,)
    receives the filter's state before the update; returns the step's status
    (:data:`~.ekf_step.OK` without a reading)."""
    q0 = np.empty(p.n)
    initial_estimate(p, m, meas, nominal, q_ref, strain_error, position_error, q0)
    x0[:] = 0.0
    x0[: p.n] = q0
    ekf_reset(p, st, t0, x0, p.p0)
    if not measured:
        return OK
    applied = not measured  # False, a variable: one signature of ekf_step for every caller
    return ekf_step(p, st, m, t0, u, applied, meas)


class FilterBlock:
    """Loop adapter of an :class:`ExtendedKalmanFilter` (module docstring).

    Parameters
    ----------
    estimator:
        The filter.
    initial_measurements:
        ``f(t) -> list`` of measurements for the initial guess (``None``: use ``nominal_q``).
    nominal_q:
        Prior configuration (the scenario's ``initial.q``); also the fallback for coordinates
        no sensor measures.
    strain_error, position_error:
        Offsets added to the guess's strains and drone position (convergence studies).
    normalize:
        ``pixels (k, 2) -> normalized (k, 2)`` with the controller's model of C_L; given (and
        the filter has a :class:`~tdacm.estimation.camera.TargetCamera`), each new C_L
        detection of ``readings.local`` is fused as a
        :class:`~tdacm.estimation.camera.TargetViewMeasurement` at its capture time.

    A filter that diverges (:class:`~tdacm.estimation.ekf.EstimatorDiverged`) gives its last
    estimate with ``failure`` set: the closed loop ends the run (``estimator failed``).
    """

    def __init__(
        self,
        estimator: ExtendedKalmanFilter,
        initial_measurements=None,
        nominal_q=None,
        strain_error: float = 0.0,
        position_error: float = 0.0,
        normalize=None,
    ):
        self.filter = estimator
        self.initial_measurements = initial_measurements
        n = estimator.n
        self.nominal_q = np.zeros(n) if nominal_q is None else np.asarray(nominal_q, float)
        self.strain_error = float(strain_error)
        self.position_error = float(position_error)

        self.prior = None  # the filter's state before the start-up update (tests, logs)
        self.normalize = normalize if estimator.camera is not None else None

    def reset(self, t: float = 0.0):
        """Start the filter at the guess (plus the configured errors); with a start-up reading,
        fuse it at once, so that the blocks initialized from this estimate (the servo's first
        reference, the controller) start from a measured state, as on a robot that reads its
        sensors before engaging the controller (:func:`filter_start`)."""
        f = self.filter
        measured = self.initial_measurements is not None
        meas = list(self.initial_measurements(t)) if measured else []
        f.renew()
        f.fit_slots(len(meas))
        x0 = np.empty(f.nx)
        w0 = time.perf_counter()
        status = filter_start(f.params, f.state, f.model_arrays, f.pack(meas), self.nominal_q,
                              f.q_ref, self.strain_error, self.position_error, float(t),
                              np.zeros(f.system.n_u), measured, x0)  # fmt: skip
        f.timings = [time.perf_counter() - w0] if measured else []  # the start-up update
        n = f.n
        self.prior = StateEstimate(float(t), x0[:n].copy(), x0[n : 2 * n].copy(),
                                   f.params.p0[: 2 * n, : 2 * n].copy())  # fmt: skip
        if status != OK:
            raise EstimatorDiverged(DIVERGENCE.get(status, f"estimator: start-up status {status}"))
        return f.estimate

    def step(self, readings, u_applied, dt: float):
        meas = [m for m in readings.other.values() if isinstance(m, _KNOWN)]
        local = readings.local
        if (
            self.normalize is not None
            and local.found
            and view_is_new(self.filter.state, float(local.t_capture))
        ):
            pts = self.normalize(local.detection.points)
            meas.append(TargetViewMeasurement(local.t_capture, pts))
        try:
            return self.filter.step(readings.t, u_applied, meas)
        except EstimatorDiverged as exc:  # an outcome of the run, not a bug: the loop ends it
            last = self.filter.estimate
            return StateEstimate(readings.t, last.q, last.qd, last.P, failure=str(exc))

    @property
    def timings(self):
        return self.filter.timings


class Estimation(NamedTuple):
    """The estimation of a batch's worlds (the engine's records, stacked over the worlds): whether the
    worlds run on the EKF's estimates (``on``; else on the true state, the records below
    unused), the filter's :class:`~tdacm.estimation.ekf_step.EkfParams` ``ekf``, the
    proprioceptive sensors' (``pose``, ``imu``, ``encoders``,
    :mod:`tdacm.estimation.sensor_steps`; disabled where the robot has none) and the start-up
    reading's (``start_pose``, ``start_encoders``: no latency, no dropout), whether the start
    is measured (``measured``: else the nominal configuration) from ``nominal`` (n,) with the
    encoders' zero ``q_ref`` (n_s,), the configured start errors ``strain_error``,
    ``position_error`` and whether the filter fuses C_L's view of the target (``fuse_view``)."""

    on: bool
    ekf: object
    pose: object
    imu: object
    encoders: object
    start_pose: object
    start_encoders: object
    measured: bool
    nominal: np.ndarray
    q_ref: np.ndarray
    strain_error: float
    position_error: float
    fuse_view: bool


class EstimationData(NamedTuple):
    """The estimation's state of a batch's worlds (stacked): the filter's
    :class:`~tdacm.estimation.ekf_step.EkfState` ``ekf`` and its period's measurements
    ``meas``, the sensors' states (``pose``, ``imu``, ``encoders``, ``start_pose``,
    ``start_encoders``), the estimate ``q_hat``, ``qd_hat`` (n,) and its ``p_qq`` (n, n), the
    filter's status of the period ``status`` (1,), the plant's accelerations at the period's
    start ``qdd`` (n,) with ``has_qdd`` (1,) (what the IMU senses) and a sensor's reading
    ``out`` (scratch)."""

    ekf: object
    meas: object
    pose: object
    imu: object
    encoders: object
    start_pose: object
    start_encoders: object
    q_hat: np.ndarray
    qd_hat: np.ndarray
    p_qq: np.ndarray
    status: np.ndarray
    qdd: np.ndarray
    has_qdd: np.ndarray
    out: np.ndarray
