"""Packing the block loop's blocks into the engine's arrays (set-up code, once per batch).

The engine is the block loop's compiled twin, never a second truth: its constants are read
from the blocks that :func:`tdacm.sim.assemble.build_loop` assembled (the cameras, the
perception's camera model, the servo's reference snapshot, gains and limits, the safety
monitor), not from the scenario again. What the engine does not run is refused here with one
line naming the scenario key that selects it.
"""

from __future__ import annotations

import numpy as np

from ..control.planner import PLAN_BOUND, _square
from ..loop.estimation import TrueState
from ..loop.sensors import AnalyticFrontEnd
from ..loop.servo import RobustServo, VisualServo
from ..vision.ibvs import MODES
from ..vision.ippe import canonical_frame
from ..vision.target_filter import N_FPARAMS, filter_params
from ..vision.targets import ArucoMarker
from ..vision.virtual import METHODS
from . import servo as S
from .params import MAX_LATENCY


class Unsupported(ValueError):
    """A scenario the engine does not run; the message names the key."""


def camera_row(cam) -> np.ndarray:
    """A pinhole camera as the engine's row ``[fx, fy, cx, cy, width, height, near, far]``."""
    if cam.has_distortion:
        raise Unsupported("the engine's cameras have no lens distortion (robot.cameras.*)")
    return np.array(
        [cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.near, cam.far], float
    )


def check_loop(loop) -> None:
    """Refuse (:class:`Unsupported`, naming the key) the blocks the engine does not run."""
    if len(loop.plant.system.arms) > 1:
        raise Unsupported("the engine runs one arm (robot.arms)")
    if not isinstance(loop.sensors.local.front_end, AnalyticFrontEnd):
        raise Unsupported(
            "the engine's tip camera is analytic: set cameras.local_renderer = 'analytic'"
        )
    if type(loop.servo) not in (VisualServo, RobustServo):
        raise Unsupported(f"the servo {type(loop.servo).__name__} is not batched (touch.enabled)")
    if not isinstance(loop.estimator, TrueState):
        raise Unsupported(
            "the engine runs on the true state: set estimation.source = 'true' "
            "(the EKF is not batched)"
        )
    if loop.force is not None:
        raise Unsupported("servoing into contact is not batched (touch.enabled)")
    if loop.sensors.global_ is None:
        raise Unsupported("the engine needs the global camera C_G")
    if not isinstance(loop.sensors.global_.front_end, AnalyticFrontEnd):
        raise Unsupported(
            "the engine's global camera is analytic: set cameras.global_renderer = 'planar' "
            "(with the analytic C_L)"
        )


def target_points(target, pose):
    """``(corners (M, 4, 3), features (4, 3))``: the target's marker corners and feature
    points in the world for the target pose ``pose`` (4, 4), as
    :class:`~tdacm.loop.sensors.AnalyticFrontEnd` places them."""
    ids = tuple(getattr(target, "ids", ())) or (target.marker_id,)
    r, p = pose[:3, :3], pose[:3, 3]
    corners = np.array([target.corner_points(i) @ r.T + p for i in ids], float)
    return corners, target.feature_points @ r.T + p


def servo_model(
    loop, n_worlds: int = 1, ctl_cameras=None, references=None, targets=None, sensor_rows=None
) -> S.ServoModel:
    """The :class:`~tdacm.batch.servo.ServoModel` of an assembled loop, for ``n_worlds``
    worlds sharing its controller camera, reference snapshot, target and C_L imperfections
    unless ``ctl_cameras`` (``n_worlds`` cameras) and ``references`` (``n_worlds`` pairs
    ``(points, depths)`` in C_V) give each world its own (an intrinsics error drawn per seed,
    another target pose), ``targets`` (``n_worlds`` pairs ``(corners, features)``,
    :func:`target_points`) each world's target and ``sensor_rows`` (``n_worlds``, 3) its pixel
    noise, dropout and latency (:data:`~tdacm.batch.servo.SN_PIXEL_NOISE`, ...)."""
    check_loop(loop)
    sensor = loop.sensors.local
    fe = sensor.front_end
    servo = loop.servo
    ib = servo.ibvs
    system = servo.system
    m = system.model_arrays
    if len(m.rod_steps) > 2:
        raise Unsupported("the engine runs one arm (robot.arms)")
    ctl = [loop.perception.local_camera] * n_worlds if ctl_cameras is None else list(ctl_cameras)
    refs = (
        [(servo.desired_points, servo.desired_depths)] * n_worlds
        if references is None
        else list(references)
    )
    if len(ctl) != n_worlds or len(refs) != n_worlds:
        raise ValueError("ctl_cameras and references need one entry per world")
    if targets is None:
        targets = [(np.array(fe._corners_w, float), fe._features_w)] * n_worlds
    if len(targets) != n_worlds:
        raise ValueError("targets need one entry per world")
    cam_model = sensor.model
    nominal = [cam_model.pixel_noise, cam_model.dropout, cam_model.latency_steps]
    sn = np.tile(np.asarray(nominal, float), (n_worlds, 1)) if sensor_rows is None else sensor_rows
    sn = np.ascontiguousarray(sn, float)
    if sn.shape != (n_worlds, S.N_SENSOR):
        raise ValueError(f"sensor needs ({n_worlds}, {S.N_SENSOR}) rows, got {sn.shape}")
    from ..vision.features import advanced_features, feature_interaction_matrix

    dpts = np.array([np.asarray(p, float) for p, _ in refs])
    dz = np.array([np.broadcast_to(np.asarray(z, float), (4,)) for _, z in refs])
    dfeat = np.array([advanced_features(p) for p in dpts])
    dint = np.array([feature_interaction_matrix(p, z) for p, z in zip(dpts, dz, strict=True)])
    obj2d, canon = canonical_frame(loop.perception.target.feature_points)
    sm = servo.shaping
    rc = servo.recovery
    sf = loop.safety
    prm = np.zeros(S.N_PARAMS)
    prm[S.P_GAIN] = ib.gain
    prm[S.P_MODE] = MODES.index(ib.mode)
    prm[S.P_FLOOR] = ib.floor
    prm[S.P_DAMPED] = 1.0 if ib.solver == "damped" else 0.0
    prm[S.P_COMPENSATION] = METHODS.index(servo.compensation)
    prm[S.P_SOFT_START] = sm.soft_start
    prm[S.P_RATE_FILTER] = sm.rate_filter
    prm[S.P_MARGIN] = rc.margin_px
    prm[S.P_CONFIRM] = rc.confirm
    prm[S.P_LOSE] = rc.lose
    prm[S.P_PIXEL_NOISE] = cam_model.pixel_noise
    prm[S.P_DROPOUT] = cam_model.dropout
    prm[S.P_LATENCY] = cam_model.latency_steps
    prm[S.P_SAFETY_ON] = 1.0 if sf.enabled else 0.0
    prm[S.P_GROWTH] = sf.growth_limit
    prm[S.P_MIN_INCREASE] = sf.min_increase
    prm[S.P_GRACE] = sf.grace
    prm[S.P_MAX_SPEED] = rc.max_speed
    prm[S.P_GLOBAL_EVERY] = loop.sensors.global_every
    prm[S.P_Z_MIN] = servo.local_camera.near
    prm[S.P_BOUND] = PLAN_BOUND
    target = loop.perception.target
    ids = tuple(getattr(target, "ids", ())) if not isinstance(target, ArucoMarker) else ()
    prm[S.P_LARGEST_TAG] = 1.0 if ids else 0.0
    robust = isinstance(servo, RobustServo)
    prm[S.P_ROBUST] = 1.0 if robust else 0.0
    if robust:
        if sn[:, S.SN_LATENCY].max() > MAX_LATENCY:
            raise Unsupported(
                f"the robust servo keeps {MAX_LATENCY + 1} camera poses: "
                f"sensors.latency_steps <= {MAX_LATENCY}"
            )
        tf = servo.target_filter
        if not np.array_equal(tf.object_points, loop.perception.target.feature_points):
            raise ValueError("the target filter and the perception see different targets")
        cfg = servo.config
        prm[S.P_SMOOTHING] = servo.smoothing
        prm[S.P_LOST_TIMEOUT] = rc.lost_timeout
        prm[S.P_ACCEL_FF] = 1.0 if cfg.accel_feedforward else 0.0
        prm[S.P_LEAK] = cfg.reference_leak
        fprm, obj, normal = filter_params(tf), tf.object_points, tf.level_normal
    else:  # unused
        fprm, obj, normal = np.zeros(N_FPARAMS), np.zeros((4, 3)), np.zeros(3)
    marker_ids = ids or (target.marker_id,)
    corners_t = [target.corner_points(i) for i in marker_ids]
    side = float(np.linalg.norm(corners_t[0][1] - corners_t[0][0]))
    gfe = loop.sensors.global_.front_end
    return S.ServoModel(
        camera=camera_row(fe.camera),
        ctl_camera=np.array([camera_row(c) for c in ctl]),
        mount=np.ascontiguousarray(sensor.mount, float),
        ad_mount=np.ascontiguousarray(servo._ad_mount, float),
        corners=np.ascontiguousarray(np.array([c for c, _ in targets], float)),
        features=np.ascontiguousarray(np.array([f for _, f in targets], float)),
        sensor=sn,
        object_2d=obj2d,
        desired_points=np.ascontiguousarray(dpts),
        desired_depths=np.ascontiguousarray(dz),
        desired_features=np.ascontiguousarray(dfeat),
        desired_interaction=np.ascontiguousarray(dint),
        limits=np.ascontiguousarray(servo._lim, float),
        commanded=np.ascontiguousarray(servo._cmd, np.int64),
        rod=np.array([m.rod_steps[0], m.rod_steps[1]], np.int64),
        params=prm,
        global_camera=camera_row(gfe.camera),
        drone_mount=np.ascontiguousarray(loop.sensors.global_.mount, float),
        mount_inv=np.ascontiguousarray(np.linalg.inv(sensor.mount)),
        square=_square(side),
        marker_centres=np.ascontiguousarray([c.mean(axis=0) for c in corners_t]),
        filter_params=fprm,
        object_points=np.ascontiguousarray(obj, float),
        canon_inv=np.ascontiguousarray(np.linalg.inv(canon)),
        level_normal=np.ascontiguousarray(normal, float),
    )
