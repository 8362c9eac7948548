"""N closed loops in lockstep: one compiled control period over a structure of arrays.

:func:`step_worlds` is :meth:`tdacm.loop.ClosedLoop.step` for every world of a batch at once,
as compiled code parallel over the worlds (numba ``prange``), with no Python per world per
period. One period of one world, in the block loop's order:

    sensors     the tip camera's analytic detection at the true state, its pixel noise,
                dropped frames and latency (the world's own random stream)
    estimation  the true state
    servo       perception (normalized points, IPPE depths), the mode switch, the view in
                the virtual camera C_V (eq. (18)), the paper's IBVS on the advanced features
                (eqs. (19)-(21), (39)) or an external twist, the joint-rate mapping and its
                command shaping; or the robust servo (``ibvs.features = "predicted"``):
                the frame fused into the target filter, the IBVS on the points predicted
                from its estimate (:func:`~tdacm.batch.servo.robust_step`)
    controller  the adaptive sliding-mode law with its model error, the hierarchical drone
                loop and the allocation (eqs. S2-S10; :mod:`tdacm.batch.control`)
    safety      the error-growth monitor
    plant       RK4 substeps of the coupled model (eq. (9)) with the disturbances, the
                aerodynamics and the wind (:mod:`tdacm.batch.plant`)

A world that ends (a :class:`~tdacm.loop.data.Termination`, or its last period) stops; the
others go on. The state of all worlds is a :class:`BatchData` (arrays with a leading world
axis); the constants are a :class:`BatchModel` (shared arrays, and per-world rows where
worlds differ: the controller's model error, its camera model and reference snapshot, the
initial state, and each world's parameters of :class:`~tdacm.batch.params.WorldParams`: its
robot, C_L imperfections and target pose). A world's result depends only on its own seed and parameters, not on the
batch size, its index or the thread count (every random draw comes from its own
counter-based stream, :mod:`tdacm.batch.random`).

GPU: one world per thread is a translation of :func:`_period` (plain arrays, no Python
objects, the world's slices); docs/batch.md says what a port needs.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..vision.target_filter import FP_WINDOW, N_FSTATE
from . import control as CT
from . import plant as PL
from . import servo as S
from .random import normal

#: termination codes of :attr:`BatchData.termination` (0: running or ran to the end), in the
#: order of :data:`TERMINATIONS`
RUNNING, SAFETY, RECOVERY_FAILED, PLANT_FAILED, BEHIND_CAMERA, TUMBLED, NON_FINITE = range(7)
#: the :class:`~tdacm.loop.data.Termination` value of each code
TERMINATIONS = (
    None,
    "safety",
    "recovery failed",
    "plant failed",
    "behind camera",
    "tumbled",
    "non-finite command",
)


class BatchModel(NamedTuple):
    """The constants of a batch: the sensing half (:class:`~tdacm.batch.servo.ServoModel`),
    the controller (:class:`~tdacm.batch.control.ControllerArrays`, with the per-world rows
    ``coord`` (N, 5, n), ``damping`` (N, n, n) and ``control_params`` (N, p): each world's
    model error, its rotor-drag estimate included) with its model's
    :class:`~tdacm.system.kernels.ModelArrays` ``control_model``, the plant
    (:class:`~tdacm.batch.plant.PlantArrays`) with the system's ``plant_model``, the control
    period ``dt`` and the number of periods of a run ``steps`` (a run has ``steps + 1``
    samples, the last without a plant step, as :meth:`~tdacm.loop.ClosedLoop.run`).

    Each world's robot (the plant's and the controller model's arrays, which describe the same
    robot): the stacks ``stiffness``, ``rod_damping`` (N, n, n), ``step_mass``
    (N, n_steps, 6), ``mb6`` (N, 6), ``tendon_d``, ``tendon_dd`` (N, n_g, n_a, 3) replace
    those fields of ``plant_model`` and ``control_model``
    (:func:`~tdacm.batch.plant.model_of_world`; rows equal to the scenario's when the worlds
    share its robot). ``gains`` (N, 3, n, n): each world's ``A_d, A_p, A_a`` (the default
    gains are shaped by the robot's inertia, :func:`~tdacm.control.hierarchical.default_gains`)."""

    servo: S.ServoModel
    control: CT.ControllerArrays
    control_model: object
    coord: np.ndarray
    damping: np.ndarray
    control_params: np.ndarray
    plant: PL.PlantArrays
    plant_model: object
    dt: float
    steps: int
    stiffness: np.ndarray
    rod_damping: np.ndarray
    step_mass: np.ndarray
    mb6: np.ndarray
    tendon_d: np.ndarray
    tendon_dd: np.ndarray
    gains: np.ndarray


class BatchData(NamedTuple):
    """The state of every world (leading axis ``N``): the plant's ``q``, ``qd`` and period
    count ``k`` (``t = k dt``), whether it still runs (``active``) and why it ended
    (``termination``, :data:`TERMINATIONS`); the servo's ``sstate``
    (:data:`~tdacm.batch.servo.N_SSTATE` rows) and recovery trajectory ``rstate``, its
    reference ``q_d``, ``qd_d``; the latency
    buffer; the safety monitor's (armed at, previous RMSE); the controller's ``delta_hat``,
    ``att``, ``att_rate``, ``att_set``; the wind's state and each world's aerodynamics copy;
    the random streams of the sensors and of the plant; the last period's outputs (``u``,
    ``rmse``, ``found``, ``twist``, ``features``); the frame the tip camera delivered at the
    start of the current period (``meas_found``, ``meas_uv``: :func:`sense_worlds`); the
    robust servo's target filter, smoothed target pose and C_L pose history (``f_*``,
    ``t_pose``, ``cam_hist``: the fields of :class:`~tdacm.batch.servo.FilterData`; a window of
    zero frames when the servo works on the measured points); C_L's pose ``meas_gc`` at the
    state ``meas_q`` the frame was taken at (the period's servo reads it when the state is
    still that one: one camera-pose recursion a period instead of two). The robust servo's
    perception of the current period (:func:`~tdacm.batch.servo.robust_predict`, the frame
    fused into the filter), kept for the period ``pred_k`` (-1: none) by the first of the
    observation (:func:`world_view`) and the step (:func:`_act`) to need it: ``pred_flags``
    (valid, pix_ok, view), the predicted points ``pred_pv``, depths ``pred_zv`` and C_L
    pixels ``pred_pix``."""

    q: np.ndarray
    qd: np.ndarray
    k: np.ndarray
    active: np.ndarray
    termination: np.ndarray
    sstate: np.ndarray
    rstate: np.ndarray
    q_d: np.ndarray
    qd_d: np.ndarray
    fifo_uv: np.ndarray
    fifo_found: np.ndarray
    safety: np.ndarray
    delta_hat: np.ndarray
    att: np.ndarray
    att_rate: np.ndarray
    att_set: np.ndarray
    wind: np.ndarray
    aero: np.ndarray
    rng_sensors: np.ndarray
    rng_plant: np.ndarray
    u: np.ndarray
    rmse: np.ndarray
    found: np.ndarray
    twist: np.ndarray
    features: np.ndarray
    meas_found: np.ndarray
    meas_uv: np.ndarray
    f_state: np.ndarray
    f_pose: np.ndarray
    f_cov: np.ndarray
    f_hyp: np.ndarray
    f_rc: np.ndarray
    f_pc: np.ndarray
    f_z: np.ndarray
    t_pose: np.ndarray
    cam_hist: np.ndarray
    meas_gc: np.ndarray
    meas_q: np.ndarray
    pred_k: np.ndarray
    pred_flags: np.ndarray
    pred_pv: np.ndarray
    pred_zv: np.ndarray
    pred_pix: np.ndarray


def empty_data(model: BatchModel, n_worlds: int, n: int, n_u: int) -> BatchData:
    """Zeroed state for ``n_worlds`` worlds of ``n`` coordinates and ``n_u`` inputs (then
    :func:`reset_worlds`)."""
    n_strains = n - (6 if model.plant_model.floating else 0)
    cap = int(model.servo.sensor[:, S.SN_LATENCY].max()) + 1
    na = model.plant.aero.shape[0]
    robust = model.servo.params[S.P_ROBUST] != 0.0
    win = int(model.servo.filter_params[FP_WINDOW]) if robust else 0
    hist = cap if robust else 0
    return BatchData(
        q=np.zeros((n_worlds, n)),
        qd=np.zeros((n_worlds, n)),
        k=np.zeros(n_worlds, np.int64),
        active=np.zeros(n_worlds, np.bool_),
        termination=np.zeros(n_worlds, np.int64),
        sstate=np.zeros((n_worlds, S.N_SSTATE)),
        rstate=np.zeros((n_worlds, 3 + 2 * n_strains)),
        q_d=np.zeros((n_worlds, n)),
        qd_d=np.zeros((n_worlds, n)),
        fifo_uv=np.zeros((n_worlds, cap, 4, 2)),
        fifo_found=np.zeros((n_worlds, cap), np.bool_),
        safety=np.zeros((n_worlds, 2)),
        delta_hat=np.zeros((n_worlds, n)),
        att=np.zeros((n_worlds, 2)),
        att_rate=np.zeros((n_worlds, 2)),
        att_set=np.zeros((n_worlds, 1), np.bool_),
        wind=np.zeros((n_worlds, PL.N_WIND_STATE)),
        aero=np.zeros((n_worlds, na)),
        rng_sensors=np.zeros((n_worlds, 2), np.uint64),
        rng_plant=np.zeros((n_worlds, 2), np.uint64),
        u=np.zeros((n_worlds, n_u)),
        rmse=np.full(n_worlds, np.nan),
        found=np.zeros(n_worlds, np.bool_),
        twist=np.zeros((n_worlds, 6)),
        features=np.zeros((n_worlds, 6)),
        meas_found=np.zeros(n_worlds, np.bool_),
        meas_uv=np.zeros((n_worlds, 4, 2)),
        f_state=np.zeros((n_worlds, N_FSTATE)),
        f_pose=np.zeros((n_worlds, 4, 4)),
        f_cov=np.zeros((n_worlds, 6, 6)),
        f_hyp=np.zeros((n_worlds, 2, 4, 4)),
        f_rc=np.zeros((n_worlds, win, 3, 3)),
        f_pc=np.zeros((n_worlds, win, 3)),
        f_z=np.zeros((n_worlds, win, 4, 2)),
        t_pose=np.zeros((n_worlds, 4, 4)),
        cam_hist=np.zeros((n_worlds, hist, 4, 4)),
        meas_gc=np.zeros((n_worlds, 4, 4)),
        meas_q=np.full((n_worlds, n), np.nan),
        pred_k=np.full(n_worlds, -1, np.int64),
        pred_flags=np.zeros((n_worlds, 3), np.bool_),
        pred_pv=np.zeros((n_worlds, 4, 2)),
        pred_zv=np.zeros((n_worlds, 4)),
        pred_pix=np.zeros((n_worlds, 4, 2)),
    )


@njit(cache=True)
def reset_worlds(model, data, which, q0, qd0):
    """Start the worlds ``which`` (bool, N) at ``(q0, qd0)`` (N, n), as
    :meth:`~tdacm.loop.ClosedLoop.reset`: time 0, the initial mode from the first (ideal) C_L
    view, the reference at ``q0`` (roll and pitch zero), the controller, the safety monitor
    and the latency buffer cleared, the turbulence's initial state drawn from the world's
    plant stream. The random streams are not rewound: set ``data.rng_*`` to restart them."""
    sm = model.servo
    m = model.plant_model
    for w in range(which.shape[0]):
        if not which[w]:
            continue
        n = q0.shape[1]
        for i in range(n):
            data.q[w, i] = q0[w, i]
            data.qd[w, i] = qd0[w, i]
            data.q_d[w, i] = q0[w, i]
            data.qd_d[w, i] = 0.0
            data.delta_hat[w, i] = 0.0
        if m.floating:
            data.q_d[w, 0] = 0.0
            data.q_d[w, 1] = 0.0
        data.k[w] = 0
        data.active[w] = True
        data.termination[w] = RUNNING
        for i in range(S.N_SSTATE):
            data.sstate[w, i] = 0.0
        data.sstate[w, S.S_MODE] = S.first_mode(q0[w], m, sm, w)
        # a start in recovery asks C_G for its first period (ClosedLoop.reset)
        data.sstate[w, S.S_REQUEST] = 1.0 if data.sstate[w, S.S_MODE] == S.RECOVERY else 0.0
        data.sstate[w, S.S_LAST_FUSED] = -1.0
        data.sstate[w, S.S_LAST_SEEN] = np.nan
        data.sstate[w, S.S_CG_MISSED] = np.nan
        for i in range(data.f_state.shape[1]):
            data.f_state[w, i] = 0.0
        data.rstate[w, S.R_ON] = 0.0
        data.safety[w, 0] = 0.0
        data.safety[w, 1] = np.nan
        for i in range(2):
            data.att[w, i] = 0.0
            data.att_rate[w, i] = 0.0
        data.att_set[w, 0] = False
        normals = np.empty(PL.N_WIND_NORMALS)
        if model.plant.wind[PL.W_TURB_ON] != 0.0:
            for i in range(PL.N_WIND_NORMALS):
                normals[i] = normal(data.rng_plant[w])
        PL.wind_start(model.plant.wind, normals, data.wind[w])
        for i in range(model.plant.aero.shape[0]):
            data.aero[w, i] = model.plant.aero[i]
        data.rmse[w] = np.nan
        data.found[w] = False
        for i in range(n):
            data.meas_q[w, i] = np.nan  # no frame taken at this state yet
        data.pred_k[w] = -1


@njit(cache=True)
def _end(data, w, code):
    data.active[w] = False
    data.termination[w] = code


@njit(cache=True)
def _sense(model, data, w):
    """The first half of world ``w``'s period (:meth:`~tdacm.loop.ClosedLoop.sense`): the
    tip camera's frame at the current state, kept in ``meas_found``, ``meas_uv``."""
    uv = data.meas_uv[w]
    data.meas_found[w] = S.measure(data.q[w], model.plant_model, model.servo, w,
                                   data.rng_sensors[w], data.fifo_uv[w], data.fifo_found[w],
                                   data.sstate[w], uv, data.meas_gc[w])  # fmt: skip
    for i in range(data.q.shape[1]):
        data.meas_q[w, i] = data.q[w, i]
    data.pred_k[w] = -1  # a new frame: not fused yet


@njit(cache=True)
def _filter_data(data, w):
    """World ``w``'s :class:`~tdacm.batch.servo.FilterData` (views of its rows)."""
    return S.FilterData(data.f_state[w], data.f_pose[w], data.f_cov[w], data.f_hyp[w],
                        data.f_rc[w], data.f_pc[w], data.f_z[w], data.t_pose[w],
                        data.cam_hist[w])  # fmt: skip


@njit(cache=True)
def _predict(model, data, w, g_c):
    """The robust servo's perception of world ``w``'s current period
    (:func:`~tdacm.batch.servo.robust_predict`: the frame :func:`_sense` kept fused into the
    target filter, the points predicted from its estimate), run once a period: the first
    call keeps its results in ``data.pred_*``, the next ones of the same period read them.
    ``g_c``: C_L's pose at the world's state (:func:`world_camera_pose`)."""
    k = int(data.sstate[w, S.S_PERIOD])
    if data.pred_k[w] != k:
        valid, pix_ok, view = S.robust_predict(model.dt, k, data.q[w], data.meas_found[w],
                                               data.meas_uv[w], model.plant_model, model.servo,
                                               w, data.sstate[w], _filter_data(data, w), g_c,
                                               data.pred_pv[w], data.pred_zv[w],
                                               data.pred_pix[w])  # fmt: skip
        data.pred_flags[w, 0] = valid
        data.pred_flags[w, 1] = pix_ok
        data.pred_flags[w, 2] = view
        data.pred_k[w] = k


@njit(cache=True)
def world_camera_pose(model, data, w):
    """C_L's pose at world ``w``'s state: the one :func:`_sense` kept when the state is the
    one its frame was taken at (always, in a period), else computed."""
    q = data.q[w]
    for i in range(q.shape[0]):
        if not q[i] == data.meas_q[w, i]:
            g_c = np.empty((4, 4))
            S.tip_camera_pose(q, model.plant_model, model.servo.rod, model.servo.mount, g_c)
            return g_c
    return data.meas_gc[w]


@njit(cache=True)
def _period(model, data, w, twist_in):
    """One control period of world ``w`` (module docstring): :func:`_sense`, :func:`_act`."""
    _sense(model, data, w)
    _act(model, data, w, twist_in)


@njit(cache=True)
def _act(model, data, w, twist_in):
    """The second half of world ``w``'s period (:meth:`~tdacm.loop.ClosedLoop.act`) on the
    frame :func:`_sense` kept: the servo (or ``twist_in`` when finite), the controller, the
    safety monitor and the plant."""
    sm = model.servo
    pa = model.plant
    m = model.plant_model
    dt = model.dt
    k = data.k[w]
    t = k * dt
    q = data.q[w]
    qd = data.qd[w]
    n = q.shape[0]
    found = data.meas_found[w]
    out = np.empty(15)
    qdd_d = np.empty(n)
    g_c = world_camera_pose(model, data, w)
    if sm.params[S.P_ROBUST] != 0.0:
        _predict(model, data, w, g_c)
        pf = data.pred_flags[w]
        mode = S.robust_step(t, dt, q, found, data.meas_uv[w], m, sm, w, data.sstate[w],
                             data.rstate[w], data.q_d[w], data.qd_d[w], qdd_d, twist_in, out,
                             pf[0], pf[1], pf[2], data.pred_pv[w], data.pred_zv[w],
                             data.pred_pix[w])  # fmt: skip
    else:
        mode = S.servo_step(t, dt, q, found, data.meas_uv[w], m, sm, w, data.sstate[w],
                            data.rstate[w], data.q_d[w], data.qd_d[w], qdd_d, twist_in,
                            out, g_c)  # fmt: skip
    data.found[w] = found
    data.rmse[w] = out[0]
    for i in range(6):
        data.twist[w, i] = out[3 + i]
        data.features[w, i] = out[9 + i]
    if out[1] == S.IBVS_ENGAGED:  # the safety monitor re-arms (its grace period)
        data.safety[w, 0] = t
        data.safety[w, 1] = np.nan
    if out[2] == 1.0:
        _end(data, w, BEHIND_CAMERA)
        return
    if out[2] == 2.0:
        _end(data, w, RECOVERY_FAILED)
        return
    # the low-level controller on this world's model error, its model of this world's robot
    mc = PL.model_of_world(model.control_model, model.mb6[w], model.stiffness[w],
                           model.rod_damping[w], model.step_mass[w], model.tendon_d[w],
                           model.tendon_dd[w])  # fmt: skip
    base = model.control
    ca = CT.ControllerArrays(base.loads, model.control_params[w], model.coord[w],
                             model.damping[w], model.gains[w], base.g4_lu, base.g4_piv)  # fmt: skip
    tau = np.empty(n)
    q_ref = np.empty(n)
    work = np.zeros((CT.N_WORK, n))
    CT.controller_period(ca, mc, data.delta_hat[w], data.att[w], data.att_rate[w], data.att_set[w],
                         q, qd, data.q_d[w], data.qd_d[w], qdd_d, dt, data.u[w], tau,
                         q_ref, work)  # fmt: skip
    for i in range(data.u.shape[1]):
        if not np.isfinite(data.u[w, i]):
            _end(data, w, NON_FINITE)
            return
    if mode == S.IBVS and not S.safety_check(sm, t, out[0], data.safety[w]):
        _end(data, w, SAFETY)
        return
    if k >= model.steps:  # the last sample: recorded, no plant step
        data.active[w] = False
        return
    # the plant over the period
    dn = np.zeros(3)
    if pa.disturbances[PL.D_DOWNWASH_ON] != 0.0:
        for i in range(3):
            dn[i] = normal(data.rng_plant[w])
    wn = np.zeros((1, PL.N_WIND_NORMALS))
    if pa.wind[PL.W_TURB_ON] != 0.0 and k >= 1:
        for i in range(PL.N_WIND_NORMALS):
            wn[0, i] = normal(data.rng_plant[w])
    loads = np.empty(pa.loads.shape[0])
    q_out = np.empty(n)
    qd_out = np.empty(n)
    mw = PL.model_of_world(m, model.mb6[w], model.stiffness[w], model.rod_damping[w],
                           model.step_mass[w], model.tendon_d[w], model.tendon_dd[w])  # fmt: skip
    ok, tumbled, _ = PL.plant_period(pa, mw, data.aero[w], q, qd, data.wind[w], data.u[w], dt, 0.0,
                                     k, dn, wn, loads, q_out, qd_out)  # fmt: skip
    for i in range(n):
        q[i] = q_out[i]
        qd[i] = qd_out[i]
    data.k[w] = k + 1
    if not ok:
        _end(data, w, PLANT_FAILED)
    elif tumbled:
        _end(data, w, TUMBLED)


@njit(cache=True, nogil=True)
def step_worlds(model, data, twist, lo, hi):
    """One control period of every active world of ``lo <= w < hi`` (``twist`` (N, 6): an
    external twist per world replacing the IBVS twist, NaN rows for none). Releases the GIL:
    :func:`parallel` runs disjoint ranges of worlds in threads."""
    for w in range(lo, hi):
        if data.active[w]:
            _period(model, data, w, twist[w])


@njit(cache=True, nogil=True)
def sense_worlds(model, data, lo, hi):
    """The first half of the period (:func:`_sense`) of the active worlds ``lo <= w < hi``:
    what an agent observes before it acts (the Gymnasium vector env)."""
    for w in range(lo, hi):
        if data.active[w]:
            _sense(model, data, w)


@njit(cache=True, nogil=True)
def act_worlds(model, data, twist, lo, hi):
    """The second half of the period (:func:`_act`) of the active worlds ``lo <= w < hi``
    on the frames :func:`sense_worlds` kept, with the external twists ``twist`` (N, 6)."""
    for w in range(lo, hi):
        if data.active[w]:
            _act(model, data, w, twist[w])


@njit(cache=True, nogil=True)
def world_view(model, data, w, pv, zv, pix):
    """World ``w``'s view in the frame :func:`sense_worlds` kept: the points and depths in
    the servo's camera into ``pv`` (4, 2), ``zv`` (4,) (``pix`` (4, 2): the prediction in
    C_L's pixels, robust servo). The measured points (:func:`~tdacm.batch.servo.servo_view`),
    or with the robust servo the points predicted from the target filter after fusing the
    frame: the period's perception (:func:`_predict`), which the period's step then reuses
    (the step's result is the one it would have without the view). Returns
    :data:`~tdacm.batch.servo.NOT_SEEN`, ``SEEN`` (a prediction exists) or ``BEHIND``."""
    sm = model.servo
    m = model.plant_model
    if sm.params[S.P_ROBUST] != 0.0:
        _predict(model, data, w, world_camera_pose(model, data, w))
        pv[:, :] = data.pred_pv[w]
        zv[:] = data.pred_zv[w]
        pix[:, :] = data.pred_pix[w]
        return S.SEEN if data.pred_flags[w, 0] else S.NOT_SEEN
    return S.servo_view(data.q[w], data.meas_found[w], data.meas_uv[w], m, sm, w,
                        world_camera_pose(model, data, w), pv, zv)  # fmt: skip


@njit(cache=True, nogil=True)
def observe_worlds(model, data, points, error, status, lo, hi):
    """What each world ``lo <= w < hi`` sees in the frame :func:`sense_worlds` kept, without
    changing the course of its run (the env's observation, the features the servo works on): the points
    in the servo's camera ``points`` (N, 4, 2), the feature error ``error`` (N, 6) (angles
    wrapped) and ``status`` (N,) :data:`~tdacm.batch.servo.NOT_SEEN`, ``SEEN`` or ``BEHIND``.
    The measured points (:meth:`VisualServo.observe`), or with the robust servo the points
    predicted from the target filter after fusing the frame (:func:`world_view`: the
    period's perception, which the period's :func:`act_worlds` reuses); ``SEEN`` when a
    prediction exists."""
    zv = np.empty(4)
    pix = np.empty((4, 2))
    for w in range(lo, hi):
        _observe(model, data, w, points, error, status, zv, pix)


@njit(cache=True)
def _observe(model, data, w, points, error, status, zv, pix):
    """World ``w``'s row of :func:`observe_worlds`."""
    sm = model.servo
    st = world_view(model, data, w, points[w], zv, pix)
    status[w] = st
    if st == S.SEEN:
        f = S._features_kernel(points[w])
        for i in range(6):
            e = f[i] - sm.desired_features[w, i]
            error[w, i] = S._wrap(e) if i < 3 else e


@njit(cache=True, nogil=True)
def act_sense_observe(model, data, twist, acting, sensing, points, error, status, lo, hi):
    """The vector env's step of the worlds ``lo <= w < hi`` in one pass a world: the second
    half of the period (:func:`_act`, twist ``twist[w]``) of the active worlds of ``acting``
    (bool, N), then the tip camera's next frame (:func:`_sense`) of the worlds of ``sensing``
    whose state is finite, whether the engine still runs them or not, then every world's
    view into ``points``, ``error``, ``status`` as :func:`observe_worlds`. Equal to
    :func:`act_worlds`, :func:`sense_worlds`, :func:`observe_worlds` one after the other
    (the worlds are independent), with one meeting of the threads instead of three."""
    zv = np.empty(4)
    pix = np.empty((4, 2))
    n = data.q.shape[1]
    for w in range(lo, hi):
        if acting[w] and data.active[w]:
            _act(model, data, w, twist[w])
        if sensing[w]:
            finite = True
            for i in range(n):
                finite = finite and np.isfinite(data.q[w, i])
            if finite:
                _sense(model, data, w)
        _observe(model, data, w, points, error, status, zv, pix)


@njit(cache=True, nogil=True)
def run_worlds(model, data, periods, log_q, log_rmse, log_mode, log_u, lo, hi):
    """``periods`` control periods of every world with the IBVS twist, logging each world's
    state at the start of each period (``log_q`` (periods, N, n), or (0, N, n): not logged),
    the servo's normalized RMSE and mode (``log_rmse``, ``log_mode`` (periods, N); NaN / -1
    once a world has ended) and the inputs (``log_u`` (periods, N, n_u) or (0, ...)), for
    the worlds ``lo <= w < hi``. Each world runs all its periods in one call (no
    synchronization between periods); releases the GIL (:func:`parallel`)."""
    for w in range(lo, hi):
        nan6 = np.full(6, np.nan)
        for p in range(periods):
            if not data.active[w]:
                log_rmse[p, w] = np.nan
                log_mode[p, w] = -1
                continue
            if log_q.shape[0] > 0:
                for i in range(data.q.shape[1]):
                    log_q[p, w, i] = data.q[w, i]
            _period(model, data, w, nan6)
            log_rmse[p, w] = data.rmse[w]
            log_mode[p, w] = int(data.sstate[w, S.S_MODE])
            if log_u.shape[0] > 0:
                for i in range(data.u.shape[1]):
                    log_u[p, w, i] = data.u[w, i]


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
