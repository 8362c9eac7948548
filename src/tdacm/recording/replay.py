"""Offline replay of a recording through the closed loop's perception and estimation blocks.

A recorded flight (signals of :func:`~tdacm.recording.read_mcap`, a tdacm export or a lab's
recording through a topic map) is re-run, period by period at the scenario's ``dt`` over the
recording's time base, through the blocks :func:`tdacm.sim.assemble.build_loop` assembles for
the scenario - no plant, no sensors, no controller:

* the C_L detection of each period (the newest recorded image points, in pixels, as a
  :class:`~tdacm.vision.detect.Detection` in a :class:`~tdacm.loop.data.CameraMeasurement`)
  goes through the loop's :class:`~tdacm.loop.perception.Perception` (normalized points with
  the controller's model of C_L, depths by planar PnP);
* the drone pose, IMU and tendon-encoder samples that arrived since the last period become
  :class:`~tdacm.estimation.PoseMeasurement`, :class:`~tdacm.estimation.ImuMeasurement` and
  :class:`~tdacm.estimation.EncoderMeasurement` for the EKF :class:`~tdacm.estimation.FilterBlock`
  (with the recorded input ``u`` of the previous period, as the loop passes it);
* the servo's perception half (:meth:`~tdacm.loop.servo.VisualServo.perceive`: the mode switch,
  the view in the virtual camera C_V, eq. (18), the advanced features and their error,
  eqs. (19)-(20), and for ``ibvs.features = "predicted"`` the target filter) runs on the view
  and the configuration: the EKF's estimate, or the recorded state (drone pose and strains)
  when no estimator runs.

Signals read (names of :data:`~tdacm.recording.DEFAULT_TOPIC_MAP`; a lab maps its topics to
them): ``pixels_local`` (pixels, ``(T, 4, 2)`` or ``(T, 8)``) or else ``points_local``
(normalized, turned into pixels with the controller's model of C_L, which perception inverts);
``strains``, ``strain_rates``, ``drone_pose`` (the recorded state); ``tendon_lengths`` (path
lengths ``l_i(q)``, encoders zeroed at the straight rod) or ``encoders`` (length changes);
``gyro`` and ``accel`` (IMU, body frame); ``thrusts`` and ``tensions`` (the input ``u``).
A NaN sample of the image points is a period without detection.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .ingest import RecordingError, Signal, pose_matrices

log = logging.getLogger(__name__)

_EPS_T = 1e-9


@dataclass(frozen=True)
class ReplayResult:
    """The replayed series, one row per period at ``t``: the configuration the servo used
    (``q_hat``, ``qd_hat``: the EKF's estimate, or the recorded state), the features, their
    error, the points in C_V and the normalized RMSE of the servo (NaN when nothing was seen),
    ``detected`` (a C_L detection this period) and ``estimated`` (whether the EKF ran)."""

    t: np.ndarray
    q_hat: np.ndarray
    qd_hat: np.ndarray
    features: np.ndarray
    feature_error: np.ndarray
    points: np.ndarray
    rmse: np.ndarray
    detected: np.ndarray
    estimated: bool

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def save(self, out) -> Path:
        """Write ``replay.npz`` in folder ``out``; returns its path."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        p = out / "replay.npz"
        np.savez_compressed(p, **self.arrays())
        return p


class _Held:
    """Zero-order hold of a signal on the replay's periods: the newest sample at or before
    ``t``, and whether it is new since the last query."""

    def __init__(self, sig: Signal):
        self.t = np.asarray(sig.t, float)
        self.values = np.asarray(sig.values)
        self._last = -1

    def at(self, t: float):
        """``(index, new)`` of the newest sample at or before ``t`` (index -1: none yet)."""
        k = int(np.searchsorted(self.t, t + _EPS_T, side="right")) - 1
        new = k > self._last
        self._last = max(self._last, k)
        return k, new


def _image_pixels(signals, camera) -> np.ndarray | None:
    """(T, 4, 2) pixels of the recorded C_L points (NaN rows: not detected)."""
    if "pixels_local" in signals:
        v = np.asarray(signals["pixels_local"].values, float)
        return v.reshape(len(v), 4, 2)
    if "points_local" not in signals:
        return None
    v = np.asarray(signals["points_local"].values, float)
    v = v.reshape(len(v), 4, 2)
    out = np.full_like(v, np.nan)
    for k, xy in enumerate(v):
        if np.all(np.isfinite(xy)):
            out[k] = camera.denormalize(xy)
    return out


def _check(signals: dict, name: str, width: int | None) -> None:
    if name in signals and width is not None:
        v = np.asarray(signals[name].values)
        if v.ndim != 2 or v.shape[1] != width:
            raise RecordingError(f"{name}: expected (T, {width}) values, got {v.shape}")


def _recorded_state(signals, system, q_default):
    """``t -> (q, qd)`` of the recorded state (drone pose and strains; the scenario's held or
    initial coordinates for what is not recorded), or ``None`` without strains."""
    from scipy.spatial.transform import Rotation

    if "strains" not in signals:
        return None
    strains, n_s, n = _Held(signals["strains"]), system.n_s, system.n
    rates = _Held(signals["strain_rates"]) if "strain_rates" in signals else None
    pose = None
    if system.floating and "drone_pose" in signals:
        pose = _Held(signals["drone_pose"])
        g = pose_matrices(signals["drone_pose"])
        # ZYX Euler angles [phi, theta, psi] (eq. (1)): roll about x, pitch about y, yaw about z
        eul = Rotation.from_matrix(g[:, :3, :3]).as_euler("ZYX")[:, ::-1]
        base = np.column_stack((eul, g[:, :3, 3]))

    def state(t):
        q = np.array(q_default, float)
        qd = np.zeros(n)
        k, _ = strains.at(t)
        if k >= 0:
            q[n - n_s :] = strains.values[k]
        if rates is not None:
            j, _ = rates.at(t)
            if j >= 0:
                qd[n - n_s :] = rates.values[j]
        if pose is not None:
            j, _ = pose.at(t)
            if j >= 0:
                q[:6] = base[j]
        return q, qd

    return state


def _measurements(signals, system):
    """``t -> {name: measurement}`` of the proprioceptive samples that arrived since the last
    call (the sensors block's ``other``), or ``None`` when the recording has none."""
    from ..estimation import EncoderMeasurement, ImuMeasurement, PoseMeasurement
    from ..estimation.kernels import tendon_lengths_and_jacobian

    srcs = {}
    if system.floating and "drone_pose" in signals:
        g = pose_matrices(signals["drone_pose"])
        srcs["pose"] = (_Held(signals["drone_pose"]),
                        lambda t, k: PoseMeasurement(t, g[k, :3, 3].copy(), g[k, :3, :3].copy()))  # fmt: skip
    if system.floating and "gyro" in signals and "accel" in signals:
        gy, ac = _Held(signals["gyro"]), _Held(signals["accel"])
        srcs["imu"] = (gy, lambda t, k: ImuMeasurement(t, gy.values[k].astype(float),
                                                       ac.values[ac.at(t)[0]].astype(float)))  # fmt: skip
    if "encoders" in signals or "tendon_lengths" in signals:
        if "encoders" in signals:
            enc, ref = _Held(signals["encoders"]), 0.0
        else:  # path lengths: encoders zeroed with the rod straight (q_s = 0)
            enc = _Held(signals["tendon_lengths"])
            ref = tendon_lengths_and_jacobian(np.zeros(system.n_s), system.model_arrays)[0]
        srcs["encoders"] = (enc, lambda t, k: EncoderMeasurement(
            t, np.asarray(enc.values[k], float) - ref))  # fmt: skip
    if not srcs:
        return None

    def poll(t):
        out = {}
        for name, (held, make) in srcs.items():
            k, new = held.at(t)
            if k >= 0 and new:
                out[name] = make(float(held.t[k]), k)
        return out

    return poll


def replay(signals: dict, scenario, *, estimate: bool | None = None, seed: int | None = None,
           t_start: float | None = None, t_end: float | None = None) -> ReplayResult:  # fmt: skip
    """Re-run ``signals`` (name -> :class:`~tdacm.recording.Signal`) through the perception,
    estimation and servo-perception blocks of ``scenario`` (a name, a path or a
    :class:`~tdacm.sim.Scenario`; module docstring).

    ``estimate``: run the EKF on the recorded proprioception (default: when the recording has
    any; the filter of ``[estimation]``, seeded by ``seed``); otherwise the servo uses the
    recorded state. ``t_start``, ``t_end``: the replayed span (default: the recording's
    image points, or its strains). Periods are ``t_start + k dt``."""
    from ..estimation import FilterBlock
    from ..loop.data import CameraMeasurement, SensorReadings, StateEstimate
    from ..sim import load_scenario
    from ..sim.assemble import build_loop, estimation_block, proprioceptive_sensors
    from ..vision.detect import NOT_DETECTED, Detection

    sc = load_scenario(scenario)
    if sc.config.robot.arms:
        raise RecordingError(
            "robot.arms: the offline replay re-runs one arm's perception and servo (the "
            "recording's image points are one C_L's), not a robot with several arms"
        )
    asm = build_loop(sc, seed=seed)
    loop, world = asm.loop, asm.world
    s = world.robot.system
    cfg = asm.scenario.config
    dt = loop.dt
    _check(signals, "strains", s.n_s)
    _check(signals, "tendon_lengths", s.n_a)
    _check(signals, "encoders", s.n_a)
    perception, servo = loop.perception, loop.servo
    pixels = _image_pixels(signals, perception.local_camera)
    cam = signals.get("pixels_local", signals.get("points_local"))
    if pixels is None and "strains" not in signals:
        raise RecordingError("the recording has neither image points (pixels_local, "
                             "points_local) nor strains: nothing to replay")  # fmt: skip
    base = cam if cam is not None else signals["strains"]
    t0 = float(base.t[0]) if t_start is None else float(t_start)
    t1 = float(base.t[-1]) if t_end is None else float(t_end)
    if not t1 >= t0:
        raise RecordingError(f"empty replay span [{t0}, {t1}]")
    times = t0 + dt * np.arange(int(np.floor((t1 - t0) / dt + 1e-9)) + 1)

    q_default = np.asarray(world.q0, float)
    recorded = _recorded_state(signals, s, q_default)
    poll = _measurements(signals, s)
    use_ekf = poll is not None if estimate is None else bool(estimate)
    if use_ekf and poll is None:
        raise RecordingError("estimate: the recording has no drone_pose, gyro/accel, "
                             "encoders or tendon_lengths for the estimator")  # fmt: skip
    if not use_ekf and recorded is None:
        raise RecordingError("the recording has no strains (and no estimator runs): no "
                             "configuration for the servo")  # fmt: skip
    camera_pts = _Held(Signal("c", base.t, pixels, (), "", "")) if pixels is not None else None
    u_parts = [signals[k] for k in ("thrusts", "tensions") if k in signals and (
        k == "tensions" or s.floating)]  # fmt: skip
    u_held = [_Held(x) for x in u_parts]

    def u_at(t):
        if not u_held:
            return np.zeros(s.n_u)
        parts = []
        for h in u_held:
            k, _ = h.at(t)
            parts.append(np.asarray(h.values[max(k, 0)], float))
        u = np.concatenate(parts)
        if u.shape != (s.n_u,):
            raise RecordingError(f"thrusts/tensions: the input u needs {s.n_u} entries, "
                                 f"got {u.shape[0]}")  # fmt: skip
        return u

    def detection(t):
        if camera_pts is None:
            return CameraMeasurement(t, NOT_DETECTED)
        k, _ = camera_pts.at(t)
        if k < 0 or not np.all(np.isfinite(pixels[k])):
            return CameraMeasurement(t, NOT_DETECTED)
        return CameraMeasurement(float(camera_pts.t[k]), Detection(True, pixels[k].copy()))

    block = None
    if use_ekf:
        block = loop.estimator if isinstance(loop.estimator, FilterBlock) else None
        if block is None:
            suite = proprioceptive_sensors(cfg.sensors, s, asm.seed)
            block = estimation_block(
                cfg.estimation, cfg.ibvs.target_level_normal, s, asm.seed, loop.plant, suite,
                world.q0, asm.model, world.robot.tip_mount, world.target,
                perception.local_camera,
            )  # fmt: skip
        first = poll(times[0])
        # the start-up reading is the recording's first samples (the filter never sees a plant)
        block.initial_measurements = (lambda t: list(first.values())) if first else None
        est = block.reset(times[0])
    else:
        q, qd = recorded(times[0])
        est = StateEstimate(times[0], q, qd)
    perception.reset()
    servo.reset(est.q, perception.local(detection(times[0])))

    T, n = len(times), s.n
    out = {k: np.full(sh, np.nan) for k, sh in (
        ("q_hat", (T, n)), ("qd_hat", (T, n)), ("features", (T, 6)),
        ("feature_error", (T, 6)), ("points", (T, 4, 2)), ("rmse", (T,)))}  # fmt: skip
    detected = np.zeros(T, bool)
    for k, t in enumerate(times):
        local = detection(t)
        if use_ekf:  # as the loop: no input before the first period
            readings = SensorReadings(t, local, None, poll(t))
            est = block.step(readings, u_at(times[k - 1]) if k else None, dt)
        else:
            q, qd = recorded(t)
            est = StateEstimate(t, q, qd)
        view = perception.local(local)
        *_, points, features, error, rmse, _extra = servo.perceive(t, dt, view, est)
        out["q_hat"][k], out["qd_hat"][k] = est.q, est.qd
        if features is not None:
            out["features"][k], out["feature_error"][k] = features, error
            out["points"][k] = points
        out["rmse"][k] = rmse
        detected[k] = view.found
    log.info("replayed %d periods (%s) of %s", T, "EKF" if use_ekf else "recorded state",
             asm.scenario.name)  # fmt: skip
    return ReplayResult(times, detected=detected, estimated=use_ekf, **out)
