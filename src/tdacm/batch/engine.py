"""N closed loops in lockstep: the blocks' compiled steps called for every world.

The engine is the loop over worlds, nothing more: a world's period calls the same compiled
steps as the block loop's blocks (:class:`tdacm.loop.ClosedLoop`), in the same order, on that
world's records (:func:`tdacm._records.take` of the stacked ones). It owns the threads, one
random stream per world, the terminations and the logging; no block's logic lives here.

The engine's one compiled entry is :func:`worlds` (:func:`step_worlds`, :func:`run_worlds`,
:func:`act_sense` call it). One period of world ``w`` (:func:`sense` then :func:`act`)::

    sense   the tip camera at the true state      loop.sensors: camera_pose_into,
            (analytic detection, dropped frames,  analytic_detect, frame_dropped,
            pixel noise, latency)                 add_pixel_noise, latency_push
            perception (normalized points, IPPE)  loop.perception.perceive
            the estimate (the EKF's period)       estimation.ekf_step, sensor_steps
            the servo's view, target filter and   loop.servo.servo_perceive
            mode switch
            (into contact: the tip force          estimation.contact_force.force_step,
            estimate, the touch law's view)       loop.touch.touch_perceive (a squeeze:
                                                  loop.touch_arms.squeeze_perceive)
    act     C_G's snapshot when the recovery      loop.servo.needs_global, servo_command
            needs one; IBVS or recovery           (into contact: loop.touch.touch_command,
                                                  loop.touch_arms.squeeze_command)
            the low-level controller              control.hierarchical.controller_step
            the safety monitor                    loop.safety.safety_arm, safety_check
            the plant over the period             loop.plant.plant_step

The estimate is the true state or each world's EKF (:func:`_estimate`). A world that ends
(a termination, or its last sample) stops; the others go on. The constants of all worlds are a :class:`BatchModel` (the blocks' records
stacked with a leading world axis, and the model arrays the worlds share), their state a
:class:`BatchData`. A world's result depends only on its seed and its rows, not on the batch
size, its index or the thread count (every draw comes from its own counter-based stream,
:mod:`tdacm.batch.random`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._records import borrow, copy_into, take, take_at
from ..aero.wind import N_WIND_NORMALS, wind_samples_due, wind_start
from ..control.hierarchical import controller_step
from ..estimation import ekf_step as EK
from ..estimation import sensor_steps as SS
from ..estimation.block import filter_start
from ..estimation.contact_force import DIFFERENCED, force_reset, force_step, force_tare
from ..loop.arms import arms_command
from ..loop.data import Termination
from ..loop.perception import perceive
from ..loop.plant import plant_step
from ..loop.safety import safety_arm, safety_check
from ..loop.sensors import (
    add_pixel_noise,
    analytic_detect,
    camera_pose_into,
    frame_dropped,
    global_offered,
    latency_push,
)
from ..loop.servo import (
    BEHIND,
    IBVS,
    IBVS_ENGAGED,
    NO_FAILURE,
    RECOVERY,
    needs_global,
    servo_command,
    servo_perceive,
    servo_reset,
)
from ..loop.touch import touch_command, touch_perceive, touch_reset
from ..loop.touch_arms import squeeze_command, squeeze_perceive, squeeze_reset
from ..system.worlds import model_of_world
from ..vision.camera import normalize_into
from .random import normal, uniform

#: the termination codes of :attr:`BatchData.termination` (0: running or ran to its end),
#: each the :class:`~tdacm.loop.data.Termination` of :data:`TERMINATIONS`
RUNNING, SAFETY, RECOVERY_FAILED, PLANT_FAILED, BEHIND_CAMERA, TUMBLED, NON_FINITE = range(7)
FORCE_LIMIT, ESTIMATOR_FAILED = 7, 8
TERMINATIONS = (
    None,
    Termination.SAFETY,
    Termination.RECOVERY_FAILED,
    Termination.PLANT_FAILED,
    Termination.BEHIND_CAMERA,
    Termination.TUMBLED,
    Termination.NON_FINITE,
    Termination.FORCE_LIMIT,
    Termination.ESTIMATOR_FAILED,
)


class BatchModel(NamedTuple):
    """The constants of a batch: every block's record stacked over the worlds (a leading
    world axis; :func:`tdacm._records.stack`; the arms' blocks with a second axis, one row an
    arm) and what the worlds share. ``sensor`` the tip cameras' and ``global_sensor`` C_G's
    (:class:`~tdacm.loop.sensors.CameraSensorParams`), ``perception``
    (:class:`~tdacm.loop.perception.PerceptionParams`), ``servo``
    (:class:`~tdacm.loop.servo.ServoParams`), ``controller``
    (:class:`~tdacm.control.hierarchical.ControllerParams`), ``safety``
    (:class:`~tdacm.loop.safety.SafetyParams`), ``plant``
    (:class:`~tdacm.loop.plant.PlantParams`) and ``robot`` each world's robot
    (:class:`~tdacm.system.worlds.RobotRows`, the plant's and the controller model's alike),
    ``estimation`` (:class:`~tdacm.estimation.block.Estimation`) and ``touch``
    (:class:`~tdacm.loop.touch.TouchRecords`);
    the shared model arrays of the plant's system ``plant_model`` and of the controller's
    private model ``control_model``; the control period ``dt``, the periods of a run
    ``steps`` (``steps + 1`` samples, the last without a plant step, as
    :meth:`~tdacm.loop.ClosedLoop.run`) and C_G's schedule ``global_every``; ``n_arms`` the
    arms (one arm: :func:`~tdacm.loop.servo.servo_command`, several:
    :func:`~tdacm.loop.arms.arms_command`)."""

    sensor: object
    global_sensor: object
    perception: object
    servo: object
    controller: object
    safety: object
    plant: object
    robot: object
    plant_model: object
    control_model: object
    dt: float
    steps: int
    global_every: int
    n_arms: int
    estimation: object
    touch: object


class Frame(NamedTuple):
    """The frame a world's tip camera delivered this period: ``detected``, ``found`` (detected
    and perceived), its pixels ``uv`` (4, 2), normalized points ``xy`` and depths ``z`` (the
    perception's), its capture period ``capture`` (stacked: a leading world axis)."""

    detected: np.ndarray
    found: np.ndarray
    uv: np.ndarray
    xy: np.ndarray
    z: np.ndarray
    capture: np.ndarray


class BatchData(NamedTuple):
    """The state of every world (leading axis ``N``): the plant's ``q``, ``qd`` and period
    count ``k`` (``t = k dt``), whether it runs (``active``), why it ended (``termination``),
    whether its servo asked C_G for the next period (``request``), its random streams
    (``rng_sensors``, ``rng_plant``), the blocks' states (``sensor``, ``servo``,
    ``controller``, ``safety``, ``plant``; the arms' with a second axis), the period's frames
    (``frame``, one per arm), each arm's servo outputs (``servo_out``) and the robot's
    (``robot_out``, arm 0's for one arm; ``memo`` the servo of several arms' own,
    :class:`~tdacm.loop.arms.ArmsMemo`), the estimation's (``estimation``) and the touch
    servo's (``touch``, :class:`~tdacm.loop.touch.TouchData`), the controller's scratch (``work``) and outputs (``u``,
    ``tau``, ``q_ref``), and the plant step's scratch ``q_next``, ``qd_next``, ``qdd_next``."""

    q: np.ndarray
    qd: np.ndarray
    k: np.ndarray
    active: np.ndarray
    termination: np.ndarray
    request: np.ndarray
    rng_sensors: np.ndarray
    rng_plant: np.ndarray
    rng_estimation: np.ndarray
    sensor: object
    frame: Frame
    servo: object
    servo_out: object
    robot_out: object
    memo: object
    estimation: object
    touch: object
    controller: object
    work: object
    safety: object
    plant: object
    u: np.ndarray
    tau: np.ndarray
    q_ref: np.ndarray
    saturated: np.ndarray
    force: np.ndarray
    q_next: np.ndarray
    qd_next: np.ndarray
    qdd_next: np.ndarray


# inlined: a compiled function of ``data`` costs seconds of compile for its argument alone,
# and a call with a constant ``code`` would compile one specialization per code
@njit(cache=True, inline="always")
def _end(data, w, code):
    data.active[w] = False
    data.termination[w] = code


@njit(cache=True)
def _draws(base, due, count, rng):
    """A proprioceptive sensor's draws when it captures (``due``): ``count`` standard normals,
    then a uniform when it drops readings (the order its Python block draws them in)."""
    if not due:
        return np.empty(0), 0.0
    normals = np.empty(count)
    for i in range(count):
        normals[i] = normal(rng)
    return normals, (uniform(rng) if base.dropout > 0.0 else 0.0)


@njit(cache=True)
def _poll_pose(p, st, t, q, rng, out, meas):
    """Poll the pose sensor at ``t`` on the true ``q``; a delivered reading into ``meas``."""
    due = SS.sensor_due(p.base, st, t)
    normals, u01 = _draws(p.base, due, SS.pose_normals(p), rng)
    tc = SS.pose_sample(p, st, t, q, normals, u01, out)
    if tc == tc:
        EK.measurement_put(meas, EK.POSE, tc, out[:12])


@njit(cache=True)
def _poll_imu(p, st, t, q, qd, qdd, has_qdd, rng, out, meas):
    """Poll the IMU at ``t`` on the true state and accelerations; a reading into ``meas``."""
    due = SS.sensor_due(p.base, st.base, t)
    normals, u01 = _draws(p.base, due, SS.imu_normals(p, st, has_qdd) if due else 0, rng)
    tc = SS.imu_sample(p, st, t, q, qd, qdd, has_qdd, normals, u01, out)
    if tc == tc:
        EK.measurement_put(meas, EK.IMU, tc, out[:6])


@njit(cache=True)
def _poll_encoders(p, st, m, t, q, rng, out, meas):
    """Poll the tendon encoders at ``t`` on the true ``q``; a reading into ``meas``."""
    due = SS.sensor_due(p.base, st.base, t)
    normals, u01 = _draws(p.base, due, SS.encoder_normals(p), rng)
    tc = SS.encoder_sample(p, st, m, t, q, normals, u01, out)
    if tc == tc:
        EK.measurement_put(meas, EK.ENCODERS, tc, out[: st.bias.shape[0]])


@njit(cache=True)
def _estimate_of(e, d, n):
    """The estimate of the filter's latest tick into ``d.q_hat``, ``d.qd_hat``, ``d.p_qq``."""
    s = EK.ekf_latest(d.ekf)
    for i in range(n):
        d.q_hat[i] = d.ekf.x[s, i]
        d.qd_hat[i] = d.ekf.x[s, n + i]
        for j in range(n):
            d.p_qq[i, j] = d.ekf.p[s, i, j]


@njit(cache=True, inline="always")  # a function of ``model`` and ``data``: see _end
def _start_estimation(model, data, w, mw, mc):
    """The estimator's start at time 0: the sensors' schedules and turn-on biases (the world's
    estimation stream) and the start-up reading, then the filter's start
    (:func:`~tdacm.estimation.block.filter_start`, which
    :meth:`~tdacm.estimation.block.FilterBlock.reset` calls)."""
    e = model.estimation
    ep, ip, cp = take(e.ekf, w), take(e.imu, w), take(e.encoders, w)
    d = take(data.estimation, w)
    rng = data.rng_estimation[w]
    n = data.q.shape[1]
    for st in (d.pose, d.start_pose):
        SS.sensor_reset(st, 0.0)
    for st in (d.imu.base, d.encoders.base, d.start_encoders.base):
        SS.sensor_reset(st, 0.0)
    d.imu.t_last[0] = np.nan
    z = np.empty(6)
    for i in range(6):
        z[i] = normal(rng)
    SS.imu_turn_on(ip, d.imu, z)
    z = np.empty(d.encoders.bias.shape[0])
    for i in range(z.shape[0]):
        z[i] = normal(rng)
    SS.encoder_turn_on(cp, d.encoders, z)
    for i in range(z.shape[0]):
        z[i] = normal(rng)
    SS.encoder_turn_on(take(e.start_encoders, w), d.start_encoders, z)
    meas = d.meas
    meas.rows[0] = 0
    q = data.q[w]
    if e.measured:
        if take(e.start_pose, w).base.enabled:
            _poll_pose(take(e.start_pose, w), d.start_pose, 0.0, q, rng, d.out, meas)
        _poll_encoders(take(e.start_encoders, w), d.start_encoders, mw, 0.0, q, rng, d.out, meas)
    d.status[0] = filter_start(ep, d.ekf, mc, meas, e.nominal[w], e.q_ref[w], e.strain_error,
                               e.position_error, 0.0, data.u[w], e.measured, np.empty(ep.nx))  # fmt: skip
    _estimate_of(e, d, n)
    d.has_qdd[0] = False


@njit(cache=True, inline="always")  # a function of ``model`` and ``data``: see _end
def _estimate(model, data, w, mw, mc, k, dt):
    """The estimator's period (:meth:`~tdacm.estimation.block.FilterBlock.step`): the
    proprioceptive sensors polled on the true state (the pose, the IMU, the encoders), C_L's
    new detection of the target when the filter fuses it (the first arm's, normalized by the
    controller's camera model), then the filter's step with the input applied over the last
    period (:func:`~tdacm.estimation.ekf_step.ekf_step`)."""
    e = model.estimation
    ep = take(e.ekf, w)
    d = take(data.estimation, w)
    rng = data.rng_estimation[w]
    n = data.q.shape[1]
    t = k * dt
    q, qd = data.q[w], data.qd[w]
    meas = d.meas
    meas.rows[0] = 0
    _poll_pose(take(e.pose, w), d.pose, t, q, rng, d.out, meas)
    _poll_imu(take(e.imu, w), d.imu, t, q, qd, d.qdd, d.has_qdd[0], rng, d.out, meas)
    _poll_encoders(take(e.encoders, w), d.encoders, mw, t, q, rng, d.out, meas)
    f = take_at(data.frame, w, 0)
    if e.fuse_view and f.detected[0]:
        t_capture = f.capture[0] * dt
        if EK.view_is_new(d.ekf, t_capture):
            xy = np.empty((4, 2))
            normalize_into(take_at(model.perception, w, 0).camera, f.uv, xy)
            EK.measurement_put(meas, EK.VIEW, t_capture, xy.ravel())
    d.status[0] = EK.ekf_step(ep, d.ekf, mc, t, data.u[w], k > 0, meas)
    if d.status[0] == EK.OK:
        _estimate_of(e, d, n)


@njit(cache=True)
def reset_worlds(model, data, which, q0, qd0):
    """Start the worlds ``which`` (bool, N) at ``(q0, qd0)`` (N, n), as
    :meth:`~tdacm.loop.ClosedLoop.reset`: time 0, the blocks' states cleared, the initial mode
    from the first (ideal) C_L frame, the turbulence's initial state from the world's plant
    stream. The random streams are not rewound: set ``data.rng_*`` to restart them."""
    n = q0.shape[1]
    for w in range(which.shape[0]):
        if not which[w]:
            continue
        for i in range(n):
            data.q[w, i] = q0[w, i]
            data.qd[w, i] = qd0[w, i]
        data.k[w] = 0
        data.active[w] = True
        data.termination[w] = RUNNING
        rw = take(model.robot, w)
        mw = model_of_world(model.plant_model, rw)
        mc = model_of_world(model.control_model, rw)
        for i in range(data.u.shape[1]):
            data.u[w, i] = 0.0
        q_est = data.q[w]
        if model.estimation.on:  # the estimate the blocks start from
            _start_estimation(model, data, w, mw, mc)
            q_est = data.estimation.q_hat[w]
        recovering = False
        for a in range(model.n_arms):
            sp = take_at(model.sensor, w, a)
            ss = take_at(data.sensor, w, a)
            ss.head[0] = 0
            ss.count[0] = 0
            # the first C_L frame, ideal (no draws): the initial mode
            g_c = np.empty((4, 4))
            camera_pose_into(sp, mw, data.q[w], g_c)
            uv = np.empty((4, 2))
            corners = np.empty((sp.corners.shape[0], 4, 2))
            seen = np.empty(sp.corners.shape[0], np.bool_)
            found = analytic_detect(sp, g_c, uv, corners, seen)
            st = take_at(data.servo, w, a)
            servo_reset(take_at(model.servo, w, a), st, mw, q_est, found, uv)
            recovering = recovering or st.mode[0] != IBVS
        # a start in recovery asks C_G for its first period (ClosedLoop.reset)
        data.request[w] = recovering
        data.memo.lost[w, 0] = recovering
        cs = take(data.controller, w)
        for i in range(n):
            cs.delta_hat[i] = 0.0
        cs.att_set[0] = False
        st = take(data.safety, w)
        st.armed_at[0] = 0.0
        st.prev[0] = np.nan
        pp = take(model.plant, w)
        pd = take(data.plant, w)
        for i in range(pp.aero.shape[0]):
            pd.aero[i] = pp.aero[i]
        normals = np.zeros(N_WIND_NORMALS)
        if pp.wind.turbulence:
            for i in range(N_WIND_NORMALS):
                normals[i] = normal(data.rng_plant[w])
        wind_start(pp.wind, pd.wind, normals)
        data.robot_out.rmse[w, 0] = np.nan
        for a in range(model.n_arms):
            data.servo_out.rmse[w, a, 0] = np.nan
        if model.touch.on or model.touch.squeeze_on:  # one arm's law or the squeeze
            touch_reset(take(data.touch.state, w))
            squeeze_reset(take(data.touch.squeeze_state, w))
            force_reset(take(data.touch.force, w))


@njit(cache=True)
def sense(model, data, w):
    """The first half of world ``w``'s period (:meth:`~tdacm.loop.ClosedLoop.sense`): the
    tip camera's frame at the true state (its imperfections drawn from the world's sensor
    stream, its latency), perceived, and the servo's view of it
    (:func:`~tdacm.loop.servo.servo_perceive`: what an agent observes)."""
    k = data.k[w]
    dt = model.dt
    q = data.q[w]
    n = q.shape[0]
    rw = take(model.robot, w)  # this world's robot rows, taken once
    mw = model_of_world(model.plant_model, rw)
    rng = data.rng_sensors[w]
    p_qq = np.zeros((n, n))  # the true state: an exact camera pose
    g_c = np.empty((4, 4))
    uv = np.empty((4, 2))
    normals = np.empty(8)
    for a in range(model.n_arms):
        sp = take_at(model.sensor, w, a)
        camera_pose_into(sp, mw, q, g_c)
        corners = np.empty((sp.corners.shape[0], 4, 2))
        seen = np.empty(sp.corners.shape[0], np.bool_)
        found = analytic_detect(sp, g_c, uv, corners, seen)
        if sp.dropout > 0.0 and frame_dropped(sp, uniform(rng)):
            found = False
        elif found and sp.pixel_noise > 0.0:
            for i in range(8):
                normals[i] = normal(rng)
            add_pixel_noise(sp, uv, corners[:0], normals)
        ss = take_at(data.sensor, w, a)
        slot = latency_push(sp, ss, found, uv, corners, k)
        f = take_at(data.frame, w, a)
        f.uv[:, :] = ss.uv[slot]
        f.capture[0] = ss.capture[slot]
        pc = take_at(model.perception, w, a)
        f.detected[0] = ss.found[slot]
        f.found[0] = f.detected[0] and perceive(pc.camera, pc.object_2d, f.uv, f.xy, f.z)
    q_est = q
    if model.estimation.on:  # the estimator's period; a failure ends the world in act
        _estimate(model, data, w, mw, model_of_world(model.control_model, rw), k, dt)
        if data.estimation.status[w, 0] != EK.OK:
            return
        q_est = data.estimation.q_hat[w]
        p_qq = data.estimation.p_qq[w]
    for a in range(model.n_arms):  # each arm's servo view
        f = take_at(data.frame, w, a)
        servo_perceive(take_at(model.servo, w, a), take_at(data.servo, w, a), mw, k * dt,
                       dt, k, q_est, p_qq, f.found[0], f.uv, f.xy, f.z, f.capture[0],
                       take_at(data.servo_out, w, a))  # fmt: skip
    tm, td = model.touch, data.touch
    fo = take(td.force_out, w)
    if tm.on or tm.squeeze_on:  # the tip force estimate, then the touch law's view; the
        # force step shares no state with the servo's view above: the block loop's numbers
        qd_est = data.estimation.qd_hat[w] if model.estimation.on else data.qd[w]
        mc = model_of_world(model.control_model, rw)
        cov = np.zeros((0, 0))  # with differenced velocities: the EKF's covariance of (q, qd)
        if model.estimation.on and take(tm.force, w).kind == DIFFERENCED:
            p = data.estimation.ekf.p[w, EK.ekf_latest(take(data.estimation.ekf, w))]
            cov = np.ascontiguousarray(p[: 2 * n, : 2 * n])
        force_step(take(tm.force, w), take(td.force, w), mc, q_est, qd_est, data.u[w], k > 0,
                   cov, dt, fo)  # fmt: skip
    if tm.on:  # one arm
        f_hat = fo.force[0] if fo.valid[0] else np.nan
        f = take_at(data.frame, w, 0)
        touch_perceive(take(tm.law, w), take(tm.refs, w), take(td.state, w),
                       take_at(model.servo, w, 0), take_at(data.servo, w, 0), mw, k * dt, dt,
                       q_est, f.found[0], f.xy, f_hat, take_at(data.servo_out, w, 0),
                       take(td.out, w))  # fmt: skip
    elif tm.squeeze_on:  # the squeeze of several arms, on every arm's frame
        f_hats = fo.force.copy() if fo.valid[0] else np.full(model.n_arms, np.nan)
        squeeze_perceive(take(tm.law, w), take(tm.squeeze, w), take(tm.arm_refs, w),
                         take(td.squeeze_state, w), take(model.servo, w), take(data.servo, w),
                         mw, k * dt, dt, q_est, np.ascontiguousarray(data.frame.found[w, :, 0]),
                         data.frame.xy[w], f_hats, take(data.servo_out, w),
                         take(td.squeeze_out, w))  # fmt: skip


@njit(cache=True)
def act(model, data, w, twist_in):
    """The second half of world ``w``'s period (:meth:`~tdacm.loop.ClosedLoop.act`) on the
    frame :func:`sense` perceived: the servo's command (``twist_in`` when finite replaces the
    IBVS twist; C_G's analytic snapshot when the recovery reads one), the low-level
    controller, the safety monitor and the plant over the period."""
    dt = model.dt
    k = data.k[w]
    t = k * dt
    q = data.q[w]
    qd = data.qd[w]
    n = q.shape[0]
    rw = take(model.robot, w)  # this world's robot rows, taken once
    mw = model_of_world(model.plant_model, rw)
    q_est, qd_est = q, qd
    if model.estimation.on:  # the blocks read the estimate (the estimator's failure ends)
        if data.estimation.status[w, 0] != EK.OK:
            _end(data, w, ESTIMATOR_FAILED)
            return
        q_est, qd_est = data.estimation.q_hat[w], data.estimation.qd_hat[w]
    offered = global_offered(k, model.global_every, data.request[w])
    servos, states = take(model.servo, w), take(data.servo, w)
    outs = take(data.servo_out, w)
    robot = take(data.robot_out, w)
    karms = model.n_arms
    m_count = model.global_sensor.corners.shape[2]  # (worlds, arms, markers, 4, 2)
    corners = np.zeros((karms, m_count, 4, 2))
    seen = np.zeros((karms, m_count), np.bool_)
    g_found = np.zeros(karms, np.bool_)
    for a in range(karms):  # C_G's analytic snapshot of each arm's marker, when it is read
        st, out = take(states, a), take(outs, a)
        if karms == 1:
            need = needs_global(st, out, offered)
        else:
            need = offered and out.mode[0] == RECOVERY and st.traj_on[0] == 0.0
        if need:
            gp = take_at(model.global_sensor, w, a)
            g_c = np.empty((4, 4))
            camera_pose_into(gp, mw, q, g_c)
            uv = np.empty((4, 2))
            g_found[a] = analytic_detect(gp, g_c, uv, corners[a], seen[a])
            for i in range(m_count):
                g_found[a] = g_found[a] or seen[a, i]
    changed = tare = False  # the touch law's phase or view; its force estimate's tare
    if model.touch.on:  # the touch servo (one arm)
        out = take(outs, 0)
        ts, tout = take(data.touch.state, w), take(data.touch.out, w)
        touch_command(take(model.touch.law, w), ts, take(servos, 0), take(states, 0), mw, t,
                      dt, q_est, offered, twist_in, g_found[0], corners[0], seen[0], out)  # fmt: skip
        copy_into(out, robot)
        changed, tare = tout.phase_changed[0] or tout.switched[0], tout.tare[0]
    elif karms == 1:
        out = take(outs, 0)
        servo_command(take(servos, 0), take(states, 0), mw, t, dt, q_est, offered, twist_in,
                      g_found[0], corners[0], seen[0], out)  # fmt: skip
        copy_into(out, robot)
    elif model.touch.squeeze_on:  # the squeeze of several arms
        so = take(data.touch.squeeze_out, w)
        squeeze_command(take(model.touch.law, w), take(model.touch.squeeze, w),
                        take(data.touch.squeeze_state, w), so, servos, states, mw, t, dt, q_est,
                        qd_est, offered, twist_in, g_found, corners, seen, outs,
                        take(data.memo, w), robot)  # fmt: skip
        changed, tare = so.phase_changed[0], so.tare[0]
    else:
        arms_command(servos, states, mw, t, dt, q_est, offered, twist_in, g_found, corners, seen,
                     outs, take(data.memo, w), robot, np.zeros((0, 6, 6)), np.zeros(0, np.bool_),
                     0.0)  # fmt: skip
    if changed:  # a new phase or view of the touch law re-arms the safety monitor
        safety_arm(take(data.safety, w), t)
    if tare:
        force_tare(take(data.touch.force, w))
    lead = take(states, 0)
    data.request[w] = robot.request[0]
    if robot.event[0] == IBVS_ENGAGED:  # the safety monitor re-arms (its grace period)
        safety_arm(take(data.safety, w), t)
    if robot.failure[0] != NO_FAILURE:
        _end(data, w, BEHIND_CAMERA if robot.failure[0] == BEHIND else RECOVERY_FAILED)
        return
    # the low-level controller on its model of this world's robot
    mc = model_of_world(model.control_model, rw)
    u = data.u[w]
    _, thrust_sat, tension_sat, _, _ = controller_step(
        take(model.controller, w), take(data.controller, w), mc, q_est, qd_est, lead.q_d, lead.qd_d,
        robot.qdd_d, dt, u, data.tau[w], data.q_ref[w], take(data.work, w),
    )  # fmt: skip
    data.saturated[w, 0] = thrust_sat
    data.saturated[w, 1] = tension_sat
    for i in range(u.shape[0]):
        if not np.isfinite(u[i]):
            _end(data, w, NON_FINITE)
            return
    if robot.mode[0] == IBVS and not safety_check(take(model.safety, w), take(data.safety, w),
                                                  t, robot.rmse[0]):  # fmt: skip
        _end(data, w, SAFETY)
        return
    if k >= model.steps:  # the last sample: recorded, no plant step
        data.active[w] = False
        return
    # the plant over the period, its draws from the world's plant stream
    pp = take(model.plant, w)
    pd = take(data.plant, w)
    dn = np.zeros(3)
    if pp.downwash_on:
        for i in range(3):
            dn[i] = normal(data.rng_plant[w])
    due = wind_samples_due(pp.wind, pd.wind, t) if pp.has_wind else 0
    wn = np.empty((due, N_WIND_NORMALS))
    for r in range(due):
        for i in range(N_WIND_NORMALS):
            wn[r, i] = normal(data.rng_plant[w])
    ok, tumbled, _, force = plant_step(pp, pd, mw, q, qd, u, dt, 0.0, k, dn, wn, data.q_next[w],
                                       data.qd_next[w], data.qdd_next[w])  # fmt: skip
    data.force[w] = force
    for i in range(n):
        q[i] = data.q_next[w, i]
        qd[i] = data.qd_next[w, i]
    if model.estimation.on:  # what the IMU senses next period
        e = take(data.estimation, w)
        e.has_qdd[0] = ok
        for i in range(n):
            e.qdd[i] = data.qdd_next[w, i]
    data.k[w] = k + 1
    if not ok:
        _end(data, w, PLANT_FAILED)
    elif tumbled:
        _end(data, w, TUMBLED)
    elif force > pp.force_limit:
        _end(data, w, FORCE_LIMIT)


#: What a call of :func:`worlds` does with each world of its range: ``PERIODS`` control periods
#: (:func:`sense` then :func:`act`, logged), or ``ACT_SENSE``: :func:`act` then :func:`sense`
#: (the vector env's step: the second half of a period, then the next view)
PERIODS, ACT_SENSE = 0, 1


@njit(cache=True, nogil=True)
def worlds(model, data, what, twist, acting, sensing, log_q, log_rmse, log_mode, log_u, lo, hi):
    """The engine's one compiled entry: the worlds ``lo <= w < hi``, each in one pass.

    ``what == PERIODS``: ``log_rmse.shape[0]`` control periods of every active world with the
    external twist ``twist[w]`` (NaN: the IBVS twist), logging its state at the start of each
    period (``log_q`` (periods, N, n), or (0, N, n): not logged), the servo's normalized RMSE
    and mode (``log_rmse``, ``log_mode`` (periods, N); NaN / -1 once the world has ended) and
    the inputs (``log_u`` (periods, N, n_u) or (0, ...)).

    ``what == ACT_SENSE``: :func:`act` (twist ``twist[w]``) of the active worlds of ``acting``
    (bool, N), then :func:`sense` of the worlds of ``sensing`` whose state is finite, whether
    the engine still runs them or not (equal to acting on every world, then sensing them: the
    worlds are independent).

    One entry, not one per use: numba links every callee's code into each compiled entry and
    optimizes and compiles it again there, so each entry holding :func:`sense` and
    :func:`act` cost their whole compile once more (docs/benchmarks.md, "What compiles"). Releases the GIL:
    :func:`parallel` runs disjoint ranges of worlds in threads.

    The model's and data's arrays are borrowed (:func:`~tdacm._records.borrow`: the caller
    holds them), so the steps below pass them on without counting references: a third of
    the compiled time before, and the threads' contention on the stacked arrays' owners."""
    model, data = borrow(model), borrow(data)
    n = data.q.shape[1]
    periods = log_rmse.shape[0] if what == PERIODS else 1
    first_acts = what == ACT_SENSE
    for w in range(lo, hi):
        live = False  # PERIODS: the world ran this period (it was active at its start)
        # the halves of the periods in order: sense, act, sense, act, ... (ACT_SENSE: act,
        # sense)
        for h in range(2 * periods):
            p = h // 2
            if (h % 2 == 1) != first_acts:  # the act half
                if first_acts:
                    if acting[w] and data.active[w]:
                        act(model, data, w, twist[w])
                    continue
                if not live:  # ended before this period
                    log_rmse[p, w] = np.nan
                    log_mode[p, w] = -1
                    continue
                act(model, data, w, twist[w])
                log_rmse[p, w] = data.robot_out.rmse[w, 0]
                log_mode[p, w] = data.robot_out.mode[w, 0]
                if log_u.shape[0] > 0:
                    for i in range(data.u.shape[1]):
                        log_u[p, w, i] = data.u[w, i]
                continue
            if first_acts:  # the view after the act, of a world whose state is finite
                go = sensing[w]
                for i in range(n):
                    go = go and np.isfinite(data.q[w, i])
            else:
                go = live = data.active[w]
                if go and log_q.shape[0] > 0:
                    for i in range(n):
                        log_q[p, w, i] = data.q[w, i]
            if go:
                sense(model, data, w)


def _no_log(data, periods: int):
    """Logs of ``periods`` periods that keep nothing but the RMSE and mode (of :func:`worlds`,
    with the argument types of every call: one compiled signature)."""
    nw, n = data.q.shape
    return (
        np.zeros((0, nw, n)),
        np.full((periods, nw), np.nan),
        np.full((periods, nw), -1, np.int64),
        np.zeros((0, nw, data.u.shape[1])),
    )


def _all(data, value: bool):
    return np.full(data.q.shape[0], value, np.bool_)


def step_worlds(model, data, twist, lo, hi):
    """One control period (:func:`sense`, :func:`act`) of every active world of
    ``lo <= w < hi`` (``twist`` (N, k 6): an external twist per world, NaN rows for the IBVS
    twist)."""
    worlds(model, data, PERIODS, twist, _all(data, True), _all(data, False), *_no_log(data, 1),
           lo, hi)  # fmt: skip


def run_worlds(model, data, periods, log_q, log_rmse, log_mode, log_u, lo, hi):
    """``periods`` control periods of every world with the IBVS twist, logged (:func:`worlds`,
    ``PERIODS``); ``log_rmse`` has ``periods`` rows."""
    nan = np.full((data.q.shape[0], 6 * data.servo_out.rmse.shape[1]), np.nan)
    worlds(model, data, PERIODS, nan, _all(data, True), _all(data, False), log_q,
           log_rmse[:periods], log_mode[:periods], log_u, lo, hi)  # fmt: skip


def act_sense(model, data, twist, acting, sensing, lo, hi):
    """The vector env's step (:func:`worlds`, ``ACT_SENSE``): :func:`act` of the active
    worlds of ``acting``, then :func:`sense` of the worlds of ``sensing`` whose state is
    finite."""
    acting = np.ascontiguousarray(acting, np.bool_)  # the argument types of every call
    sensing = np.ascontiguousarray(sensing, np.bool_)
    twist = np.ascontiguousarray(twist, np.float64)
    worlds(model, data, ACT_SENSE, twist, acting, sensing, *_no_log(data, 0), lo, hi)


def sense_worlds(model, data, lo, hi):
    """:func:`sense` of the active worlds ``lo <= w < hi``: what an agent observes before it
    acts."""
    act_sense(model, data, np.full((data.q.shape[0], 6), np.nan), _all(data, False),
              data.active.copy(), lo, hi)  # fmt: skip


def act_worlds(model, data, twist, lo, hi):
    """:func:`act` of the active worlds ``lo <= w < hi`` with the external twists ``twist``
    (N, k 6; NaN rows: the IBVS twist)."""
    act_sense(model, data, twist, _all(data, True), _all(data, False), lo, hi)


_POOLS = {}  # a pool per thread count: never more threads than asked
#: ranges of worlds a thread of :func:`parallel` (load balance against the cost of a call)
CHUNKS_PER_THREAD = 4


def parallel(kernel, args, n_worlds: int, threads: int | None = None) -> None:
    """Call ``kernel(*args, lo, hi)`` on disjoint ranges of the ``n_worlds`` worlds in
    ``threads`` threads at once (threads of one process: the kernels release the GIL;
    default: the machine's cores): :data:`CHUNKS_PER_THREAD` ranges a thread, taken by
    whichever thread is free, so worlds that cost more (a recovery, an ended world that
    costs nothing) do not leave a thread idle. The worlds are independent, so the result
    does not depend on the split."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    k = max(1, min(int(threads or os.cpu_count() or 1), n_worlds))
    if k == 1:
        kernel(*args, 0, n_worlds)
        return
    pool = _POOLS.get(k)
    if pool is None:
        pool = _POOLS[k] = ThreadPoolExecutor(max_workers=k, thread_name_prefix="tdacm-batch")
    chunks = min(n_worlds, k * CHUNKS_PER_THREAD)
    bounds = np.linspace(0, n_worlds, chunks + 1).round().astype(int)
    futures = [
        pool.submit(kernel, *args, int(bounds[i]), int(bounds[i + 1])) for i in range(chunks)
    ]
    for f in futures:
        f.result()
