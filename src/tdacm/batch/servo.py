"""The sensing half of one world's control period, compiled: the analytic tip camera with its
imperfections, perception, the virtual camera, the paper's IBVS on the advanced features, the
servo's joint-rate mapping with its command shaping, the mode switch and the safety monitor.

Each function here is the compiled twin of a block of :mod:`tdacm.loop` (named in its
docstring) on one world's plain arrays; :mod:`tdacm.batch.engine` calls them for every world of
a batch. They are tested equal to the blocks (``tests/batch``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._linalg import SVD_DAMPED, SVD_FLOOR, SVD_PINV, svd_solve
from ..control.planner import _IPPE_ORDER, plan_kernel, square_pose
from ..lie.blocks import compose_rp_into, expmap_rp_into
from ..lie.euler import rot_zyx
from ..lie.magnus import magnus_step_into
from ..lie.se3 import expmap, so3_log
from ..system.kernels import chain_start, make_workspace, rod_step
from ..vision.features import _features_kernel, _interaction_kernel, _wrap
from ..vision.ippe import DEPTHS_OK, point_depths
from ..vision.target_filter import filter_update, points_in_kernel
from . import random as R

#: the servo's mode codes (:class:`tdacm.control.Mode`)
IBVS, RECOVERY = 0, 1
#: the virtual-camera compensation codes (``ibvs.compensation``)
EXACT, ROTATION, APPROX = 0, 1, 2
#: the interaction-matrix codes (``ibvs.mode``)
CURRENT, DESIRED, MEAN = 0, 1, 2

# indices of :attr:`ServoModel.camera` rows: a pinhole camera
FX, FY, CX, CY, WIDTH, HEIGHT, NEAR, FAR = range(8)

#: columns of :attr:`ServoModel.sensor` (a world's C_L imperfections): pixel noise (px,
#: standard deviation), dropout probability, latency (frames)
SN_PIXEL_NOISE, SN_DROPOUT, SN_LATENCY = range(3)
N_SENSOR = 3

# indices of :attr:`ServoModel.params`
(
    P_GAIN,
    P_MODE,
    P_FLOOR,
    P_DAMPED,
    P_COMPENSATION,
    P_SOFT_START,
    P_RATE_FILTER,
    P_MARGIN,
    P_CONFIRM,
    P_LOSE,
    P_PIXEL_NOISE,
    P_DROPOUT,
    P_LATENCY,
    P_SAFETY_ON,
    P_GROWTH,
    P_MIN_INCREASE,
    P_GRACE,
    P_MAX_SPEED,
    P_GLOBAL_EVERY,
    P_Z_MIN,
    P_BOUND,
    P_LARGEST_TAG,
    P_ROBUST,
    P_SMOOTHING,
    P_LOST_TIMEOUT,
    P_ACCEL_FF,
    P_LEAK,
    N_PARAMS,
) = range(28)


class ServoModel(NamedTuple):
    """The constants of the sensing half (the blocks' parameters as arrays). Rows with a
    leading world axis (``N``) may differ between worlds; the others are shared.

    ``camera`` (8,): the true C_L (``FX, ..., FAR``); ``ctl_camera`` (N, 8): the controller's
    model of C_L (the intrinsics error of each world's seed); ``mount`` (4, 4) and
    ``ad_mount`` (6, 6): ``g_{C_L}^L`` and its adjoint; ``corners`` (N, M, 4, 3) and ``features``
    (N, 4, 3): the target's marker corners and feature points in the world (each world's
    target pose); ``sensor`` (N, :data:`N_SENSOR`): each world's C_L imperfections by the
    ``SN_*`` columns (the ``P_PIXEL_NOISE``, ``P_DROPOUT``, ``P_LATENCY`` of ``params`` are the
    scenario's, the first world's at packing); ``object_2d`` (4, 2):
    the feature points in the target plane's canonical frame (:func:`~tdacm.vision.ippe.canonical_frame`);
    ``desired_points`` (N, 4, 2), ``desired_depths`` (N, 4), ``desired_features`` (N, 6),
    ``desired_interaction`` (N, 6, 6): the reference snapshot in C_V; ``limits`` (n,): the
    joint-rate limits of the shaping; ``commanded`` (k,): the commanded coordinates;
    ``rod`` (2,): the first and last Magnus step of the camera's rod; ``params``: the scalars
    (``P_*`` indices). The recovery: ``global_camera`` (8,) C_G, ``drone_mount`` (4, 4)
    ``g_{C_G}^b``, ``mount_inv`` (4, 4) ``(g_{C_L}^L)^-1``, ``square`` (4, 2) a marker's
    corners in its plane (:func:`tdacm.control.planner.square_pose`), ``marker_centres``
    (M, 3) each marker's centre in the target frame. The robust servo (``P_ROBUST``, the
    features predicted from the target filter): ``filter_params`` the filter's constants
    (:func:`~tdacm.vision.target_filter.filter_params`), ``object_points`` (4, 3) the feature
    points in the target frame, ``canon_inv`` (4, 4) the target-to-canonical transform of
    ``object_2d``, ``level_normal`` (3,) the level prior's normal."""

    camera: np.ndarray
    ctl_camera: np.ndarray
    mount: np.ndarray
    ad_mount: np.ndarray
    corners: np.ndarray
    features: np.ndarray
    sensor: np.ndarray
    object_2d: np.ndarray
    desired_points: np.ndarray
    desired_depths: np.ndarray
    desired_features: np.ndarray
    desired_interaction: np.ndarray
    limits: np.ndarray
    commanded: np.ndarray
    rod: np.ndarray
    params: np.ndarray
    global_camera: np.ndarray
    drone_mount: np.ndarray
    mount_inv: np.ndarray
    square: np.ndarray
    marker_centres: np.ndarray
    filter_params: np.ndarray
    object_points: np.ndarray
    canon_inv: np.ndarray
    level_normal: np.ndarray


# ----------------------------------------------------------------------------- geometry
@njit(cache=True)
def camera_chain(q, m, rod, want_j, g_out, j_out):
    """The pose ``g_L(q)`` (4, 4) of the end of the camera's rod (the Magnus steps ``rod[0] <=
    k < rod[1]``) into ``g_out`` and, when ``want_j``, its Jacobian ``J_L^L(q)`` (6 x n) into
    ``j_out``: the recursion of :func:`~tdacm.system.kernels.chain_jacobian` at zero rates
    without what the servo does not read. The Jacobian comes from
    :func:`~tdacm.system.kernels.rod_step` without the Jacobian rate (its columns of ``T X``
    are computed one by one, so ``J`` and ``g`` are the same numbers); the pose alone needs
    only each step's Magnus exponential and the product of the poses (the same calls as in
    ``rod_step``). Measured: about half the cost of ``chain_jacobian`` for the Jacobian and
    a fifth for the pose."""
    lo, hi = rod[0], rod[1]
    n = q.shape[0]
    zero = np.zeros(n)
    off = 6 if m.floating else 0
    _, _, _, g, j, jd, jdq = chain_start(q, zero, m.floating, m.g_fixed, m.g_att[0])
    ws = make_workspace(n, m.bs.shape[3])
    if want_j:
        eta = np.zeros(6)
        for k in range(lo, hi):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            rod_step(m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], zero[c0:c1], c0, g, j, jd, eta, jdq,
                     False, ws)  # fmt: skip
        j_out[:, :] = j
    else:
        omega, z, zdq, zd, mwork, r, p = ws[0], ws[1], ws[2], ws[3], ws[4], ws[5], ws[6]
        gr = ws[13]
        for k in range(lo, hi):
            c0 = off + m.step_col[k]
            c1 = c0 + m.step_nc[k]
            magnus_step_into(m.h[k], m.xi0s[k], m.bs[k], q[c0:c1], zero[c0:c1], omega, z, zdq,
                             zd, mwork)  # fmt: skip
            expmap_rp_into(omega, r, p)
            compose_rp_into(g, gr, r, p)
    g_out[:, :] = g


@njit(cache=True)
def tip_camera_pose(q, m, rod, mount, out):
    """``g_{C_L} = g_L(q) g_{C_L}^L`` (:func:`tdacm.vision.mounts.tip_camera_pose`) into
    ``out`` (4, 4) (:func:`camera_chain`)."""
    g = np.empty((4, 4))
    camera_chain(q, m, rod, False, g, np.empty((0, 0)))
    _mul4(g, mount, out)


@njit(cache=True)
def tip_jacobian(q, m, rod):
    """``J_L^L(q)`` (6 x n) of the camera's rod (:meth:`tdacm.TDACM.tip_jacobian`,
    :func:`camera_chain`)."""
    j = np.empty((6, q.shape[0]))
    camera_chain(q, m, rod, True, np.empty((4, 4)), j)
    return j


@njit(cache=True)
def _mul4(a, b, out):
    for i in range(4):
        for j in range(4):
            out[i, j] = (
                a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j] + a[i, 3] * b[3, j]
            )


@njit(cache=True)
def _inv4(g, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = g[j, i]
        out[3, i] = 0.0
    for i in range(3):
        out[i, 3] = -(out[i, 0] * g[0, 3] + out[i, 1] * g[1, 3] + out[i, 2] * g[2, 3])
    out[3, 3] = 1.0


@njit(cache=True)
def base_pose(q, m, out):
    """The drone pose ``g_b`` (eq. (1)) into ``out``; the clamp for a fixed base."""
    if not m.floating:
        out[:, :] = m.g_fixed
        return
    r = rot_zyx(q[0], q[1], q[2])
    for i in range(3):
        for j in range(3):
            out[i, j] = r[i, j]
        out[i, 3] = q[3 + i]
        out[3, i] = 0.0
    out[3, 3] = 1.0


@njit(cache=True)
def virtual_transform(g_b, g_c, out):
    """``g_{C_L}^{C_V} = g_{C_V}^-1 g_{C_L}`` with ``g_{C_V} = g_psi g_b^-1 g_{C_L}``
    (:func:`tdacm.vision.virtual.virtual_transform`, eq. (18))."""
    psi = np.arctan2(g_b[1, 0], g_b[0, 0])
    c, s = np.cos(psi), np.sin(psi)
    gy = np.eye(4)
    gy[0, 0], gy[0, 1], gy[1, 0], gy[1, 1] = c, -s, s, c
    for i in range(3):
        gy[i, 3] = g_b[i, 3]
    ib = np.empty((4, 4))
    _inv4(g_b, ib)
    a = np.empty((4, 4))
    _mul4(gy, ib, a)
    v = np.empty((4, 4))
    _mul4(a, g_c, v)
    iv = np.empty((4, 4))
    _inv4(v, iv)
    _mul4(iv, g_c, out)


@njit(cache=True)
def virtual_points(p, z, g, method, out_p, out_z):
    """Points ``p`` (4, 2) with depths ``z`` of C_L in C_V (eq. (18),
    :func:`tdacm.vision.virtual.virtual_points`): ``out_z`` the depths in C_V for ``EXACT``,
    ``z^{C_V} / z^{C_L}`` for the other forms (times ``z`` by the caller, as the servo does).
    False when a point maps behind the virtual camera."""
    for k in range(p.shape[0]):
        x, y = p[k, 0], p[k, 1]
        if method == EXACT:
            zk = z[k]
            r0 = (x * zk) * g[0, 0] + (y * zk) * g[0, 1] + zk * g[0, 2] + g[0, 3]
            r1 = (x * zk) * g[1, 0] + (y * zk) * g[1, 1] + zk * g[1, 2] + g[1, 3]
            r2 = (x * zk) * g[2, 0] + (y * zk) * g[2, 1] + zk * g[2, 2] + g[2, 3]
        else:
            r0 = x * g[0, 0] + y * g[0, 1] + g[0, 2]
            r1 = x * g[1, 0] + y * g[1, 1] + g[1, 2]
            r2 = x * g[2, 0] + y * g[2, 1] + g[2, 2]
        if method == APPROX:
            out_p[k, 0], out_p[k, 1], out_z[k] = r0, r1, 1.0
            continue
        if not r2 > 0.0:
            return False
        out_p[k, 0], out_p[k, 1], out_z[k] = r0 / r2, r1 / r2, r2
    return True


# ----------------------------------------------------------------------------- camera
@njit(cache=True)
def _in_image(cam, u, v, margin):
    return (
        u >= margin - 0.5
        and u <= cam[WIDTH] - 0.5 - margin
        and v >= margin - 0.5
        and v <= cam[HEIGHT] - 0.5 - margin
    )


@njit(cache=True)
def detect(cam, g_c, corners, features, out_uv):
    """The analytic front end (:class:`tdacm.loop.sensors.AnalyticFrontEnd`): True when every
    corner of every marker lies between the clipping planes and inside the image, with the
    feature points' pixels in ``out_uv`` (4, 2)."""
    for mk in range(corners.shape[0]):
        for k in range(4):
            d0 = corners[mk, k, 0] - g_c[0, 3]
            d1 = corners[mk, k, 1] - g_c[1, 3]
            d2 = corners[mk, k, 2] - g_c[2, 3]
            x = d0 * g_c[0, 0] + d1 * g_c[1, 0] + d2 * g_c[2, 0]
            y = d0 * g_c[0, 1] + d1 * g_c[1, 1] + d2 * g_c[2, 1]
            z = d0 * g_c[0, 2] + d1 * g_c[1, 2] + d2 * g_c[2, 2]
            if not (z > 0.0 and z >= cam[NEAR] and z <= cam[FAR]):
                return False
            if not _in_image(cam, cam[FX] * x / z + cam[CX], cam[FY] * y / z + cam[CY], 0.0):
                return False
    for k in range(4):
        d0 = features[k, 0] - g_c[0, 3]
        d1 = features[k, 1] - g_c[1, 3]
        d2 = features[k, 2] - g_c[2, 3]
        x = d0 * g_c[0, 0] + d1 * g_c[1, 0] + d2 * g_c[2, 0]
        y = d0 * g_c[0, 1] + d1 * g_c[1, 1] + d2 * g_c[2, 1]
        z = d0 * g_c[0, 2] + d1 * g_c[1, 2] + d2 * g_c[2, 2]
        out_uv[k, 0] = cam[FX] * x / z + cam[CX]
        out_uv[k, 1] = cam[FY] * y / z + cam[CY]
    return True


@njit(cache=True)
def imperfect(found, uv, noise, dropout, rng):
    """The camera's imperfections (:meth:`tdacm.loop.sensors.CameraSensor._imperfect`): a
    dropped frame with probability ``dropout``, else Gaussian pixel noise of std ``noise`` on
    a detection (the world's own stream ``rng``). Returns whether the frame is detected."""
    if dropout > 0.0 and R.uniform(rng) < dropout:
        return False
    if found and noise > 0.0:
        for k in range(4):
            uv[k, 0] += noise * R.normal(rng)
            uv[k, 1] += noise * R.normal(rng)
    return found


@njit(cache=True)
def perceive(ctl, object_2d, uv, out_xy, out_z):
    """The perception block (:class:`tdacm.loop.perception.Perception`): normalized points
    through the controller's camera model and their depths from the known target geometry
    (planar PnP, IPPE); False for a frame no pose explains with the target in front."""
    for k in range(4):
        out_xy[k, 0] = (uv[k, 0] - ctl[CX]) / ctl[FX]
        out_xy[k, 1] = (uv[k, 1] - ctl[CY]) / ctl[FY]
    return point_depths(object_2d, out_xy, out_z) == DEPTHS_OK


# ----------------------------------------------------------------------------- servo
@njit(cache=True)
def inside(ctl, uv, margin):
    """All four pixels at least ``margin`` inside C_L's image (:meth:`ModeSwitch.inside`)."""
    for k in range(4):
        if not _in_image(ctl, uv[k, 0], uv[k, 1], margin):
            return False
    return True


@njit(cache=True)
def min_edge2(p):
    """The smallest squared length of the arctangent terms' edges (features defined)."""
    best = np.inf
    pairs = ((0, 1), (3, 2), (1, 2), (0, 3))
    for a, b in pairs:
        dx = p[a, 0] - p[b, 0]
        dy = p[a, 1] - p[b, 1]
        best = min(best, dx * dx + dy * dy)
    return best


@njit(cache=True)
def plain_solve(jac, e):
    """``J^-1 e`` with the least-squares fallback (the paper profile's plain solve,
    :func:`tdacm.vision.ibvs._solve`)."""
    ok = True
    x = np.zeros(6)
    try:
        x = np.linalg.solve(jac, e)
    except Exception:  # noqa: BLE001 - numba raises on a singular matrix
        ok = False
    if ok:
        big = 0.0
        emax = 0.0
        for i in range(6):
            if not np.isfinite(x[i]):
                ok = False
            big = max(big, abs(x[i]))
            emax = max(emax, abs(e[i]))
        if ok and big < 1e8 * (1.0 + emax):
            return x
    return np.linalg.lstsq(jac, e, rcond=1e-10)[0]


@njit(cache=True)
def ibvs_twist(p, z, sm, w, out_f, out_e, out_v):
    """Features, error and twist ``v = -lambda J_img^+ e`` (eqs. (19)-(21), (39);
    :class:`tdacm.vision.ibvs.IBVSController`) of points ``p`` (4, 2) with depths ``z`` in
    C_V, for world ``w``'s reference."""
    prm = sm.params
    floor = prm[P_FLOOR]
    mode = int(prm[P_MODE])
    gain = prm[P_GAIN]
    if floor > 0.0:
        f = _features_kernel(p)
        jd = sm.desired_interaction[w]
        if mode == DESIRED:
            jac = jd
        elif mode == CURRENT:
            jac = _interaction_kernel(p, z)
        else:
            jac = 0.5 * (_interaction_kernel(p, z) + jd)
        e = f - sm.desired_features[w]
        for i in range(3):
            e[i] = _wrap(e[i])
        x = svd_solve(jac, e, SVD_DAMPED if prm[P_DAMPED] > 0.0 else SVD_FLOOR, floor)
    else:
        f = _features_kernel(p)
        e = f - sm.desired_features[w]
        for i in range(3):
            e[i] = _wrap(e[i])
        jd = sm.desired_interaction[w]
        if mode == DESIRED:
            jac = jd.copy()
        elif mode == CURRENT:
            jac = _interaction_kernel(p, z)
        else:
            jac = 0.5 * (_interaction_kernel(p, z) + jd)
        x = plain_solve(jac, e)
    for i in range(6):
        out_f[i] = f[i]
        out_e[i] = e[i]
        out_v[i] = -gain * x[i]


@njit(cache=True)
def joint_rates(q, twist, m, sm, floating):
    """``qdot_d[cmd] = (J_L^L(q_v)[:, cmd])^+ Ad(g_{C_L}^L) v`` with roll and pitch of ``q_v``
    zero (:meth:`tdacm.loop.servo.VisualServo.joint_rates`)."""
    n = q.shape[0]
    qv = q.copy()
    if floating:
        qv[0] = 0.0
        qv[1] = 0.0
    jac = tip_jacobian(qv, m, sm.rod)
    tip = np.zeros(6)
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += sm.ad_mount[i, k] * twist[k]
        tip[i] = acc
    cmd = sm.commanded
    jc = np.empty((6, cmd.shape[0]))
    for i in range(6):
        for c in range(cmd.shape[0]):
            jc[i, c] = jac[i, cmd[c]]
    x = svd_solve(jc, tip, SVD_PINV, 1e-8)
    out = np.zeros(n)
    for c in range(cmd.shape[0]):
        out[cmd[c]] = x[c]
    return out


@njit(cache=True)
def shape(rates, t, dt, ibvs_start, sm, q_d, qd_d):
    """Limit, ramp and filter the joint rates into ``qd_d``; integrate ``q_d`` (in place;
    :meth:`tdacm.loop.servo.VisualServo.shape`)."""
    prm = sm.params
    cmd = sm.commanded
    lim = sm.limits
    soft = prm[P_SOFT_START]
    filt = prm[P_RATE_FILTER]
    t_ib = t - ibvs_start
    ramp = 1.0 - np.exp(-t_ib / soft) if soft > 0.0 else 1.0
    scale = 1.0
    for c in range(cmd.shape[0]):
        scale = max(scale, abs(rates[cmd[c]]) / lim[cmd[c]])
    a_f = min(1.0, dt / filt) if filt > 0.0 else 1.0
    n = q_d.shape[0]
    new = np.zeros(n)
    for c in range(cmd.shape[0]):
        new[cmd[c]] = rates[cmd[c]] / scale
    for i in range(n):
        qd_d[i] = qd_d[i] + a_f * (ramp * new[i] - qd_d[i])
        q_d[i] = q_d[i] + qd_d[i] * dt


@njit(cache=True)
def switch_update(mode, counters, seen_inside, found, confirm, lose):
    """The mode switch's hysteresis (:meth:`tdacm.control.ModeSwitch.update`): ``counters``
    = (frames inside the margin while recovering, frames missed while servoing), updated in
    place; returns the new mode."""
    if mode == RECOVERY:
        counters[0] = counters[0] + 1 if seen_inside else 0
        if counters[0] >= confirm:
            counters[1] = 0
            return IBVS
        return RECOVERY
    counters[1] = 0 if found else counters[1] + 1
    if counters[1] >= lose:
        counters[0] = 0
        return RECOVERY
    return IBVS


@njit(cache=True)
def safety_check(sm, t, rmse, safety):
    """The safety monitor (:class:`tdacm.loop.safety.SafetyMonitor`): ``safety`` = (armed at,
    previous RMSE or NaN); False when the normalized RMSE grew beyond the limit."""
    prm = sm.params
    if prm[P_SAFETY_ON] == 0.0 or not np.isfinite(rmse):
        return True
    prev = safety[1]
    safety[1] = rmse
    if not np.isfinite(prev) or t - safety[0] < prm[P_GRACE]:
        return True
    return not (rmse > prev * (1.0 + prm[P_GROWTH]) and rmse - prev > prm[P_MIN_INCREASE])


# ----------------------------------------------------------------------------- one period
#: servo events (:class:`tdacm.loop.data.ServoEvent`)
NO_EVENT, IBVS_ENGAGED, TARGET_LOST = 0, 1, 2

# rows of a world's servo state ``sstate`` (float array): the mode, the switch's two
# counters, the time IBVS engaged, the latency ring buffer's head and count
S_MODE, S_GOOD, S_BAD, S_IBVS_START, S_HEAD, S_COUNT, S_REQUEST, S_PERIOD = range(8)
# the robust servo's rows: the capture period of the last fused frame (-1: none), the capture
# time of the last frame the filter accepted and the time C_G first missed the target in a
# recovery (NaN: none), whether the smoothed target pose is set
S_LAST_FUSED, S_LAST_SEEN, S_CG_MISSED, S_TP_SET, N_SSTATE = range(8, 13)
# the recovery's cubic trajectory, from ``R_Q0`` (n_s) toward ``R_Q0 + R_D`` (n_s): rows of
# a world's ``rstate`` (float array of ``3 + 2 n_s``)
R_ON, R_T0, R_TF, R_Q0 = 0, 1, 2, 3


@njit(cache=True)
def measure(q, m, sm, w, rng, fifo_uv, fifo_found, sstate, out_uv, g_c):
    """World ``w``'s tip camera measurement of this period (:meth:`CameraSensor.measure`):
    the analytic detection at the true ``q``, its imperfections, then the latency buffer (a
    frame captured ``latency_steps`` periods ago, the first one until then; the buffer holds
    at least the world's latency + 1 frames). Returns whether the delivered frame is a
    detection, its pixels in ``out_uv``; ``g_c`` (4, 4) receives C_L's pose at ``q`` (the
    servo of the same period reads it, :func:`servo_view`)."""
    tip_camera_pose(q, m, sm.rod, sm.mount, g_c)
    uv = np.empty((4, 2))
    found = detect(sm.camera, g_c, sm.corners[w], sm.features[w], uv)
    sn = sm.sensor[w]
    found = imperfect(found, uv, sn[SN_PIXEL_NOISE], sn[SN_DROPOUT], rng)
    cap = int(sn[SN_LATENCY]) + 1
    head, count = int(sstate[S_HEAD]), int(sstate[S_COUNT])
    if count < cap:
        slot = (head + count) % cap
        count += 1
    else:
        slot = head
        head = (head + 1) % cap
    fifo_uv[slot] = uv
    fifo_found[slot] = found
    sstate[S_HEAD], sstate[S_COUNT] = head, count
    out_uv[:, :] = fifo_uv[head]
    return fifo_found[head]


@njit(cache=True)
def first_mode(q, m, sm, w):
    """The initial mode (:meth:`VisualServo.reset` on the first, ideal C_L view): IBVS when
    the target is detected, its pose explicable and inside the switch's margin."""
    g_c = np.empty((4, 4))
    tip_camera_pose(q, m, sm.rod, sm.mount, g_c)
    uv = np.empty((4, 2))
    if not detect(sm.camera, g_c, sm.corners[w], sm.features[w], uv):
        return RECOVERY
    xy = np.empty((4, 2))
    z = np.empty(4)
    if not perceive(sm.ctl_camera[w], sm.object_2d, uv, xy, z):
        return RECOVERY
    return IBVS if inside(sm.ctl_camera[w], uv, sm.params[P_MARGIN]) else RECOVERY


#: what :func:`servo_view` found: no view, a view in C_V, a point behind C_V
NOT_SEEN, SEEN, BEHIND = 0, 1, 2


@njit(cache=True)
def servo_view(q, found, uv, m, sm, w, g_c, pv, zv):
    """The delivered frame in the servo's camera (:meth:`VisualServo.observe`): perception
    (normalized points, IPPE depths), then C_V for a floating base (eq. (18)); the points and
    depths into ``pv`` (4, 2), ``zv`` (4,). Returns :data:`NOT_SEEN`, :data:`SEEN` or
    :data:`BEHIND` (a point maps behind C_V). ``g_c``: C_L's pose at ``q``
    (:func:`tip_camera_pose`)."""
    xy = np.empty((4, 2))
    z = np.empty(4)
    if not (found and perceive(sm.ctl_camera[w], sm.object_2d, uv, xy, z)):
        return NOT_SEEN
    if not m.floating:
        pv[:, :] = xy
        zv[:] = z
        return SEEN
    g_b = np.empty((4, 4))
    base_pose(q, m, g_b)
    gv = np.empty((4, 4))
    virtual_transform(g_b, g_c, gv)
    method = int(sm.params[P_COMPENSATION])
    if not virtual_points(xy, z, gv, method, pv, zv):
        return BEHIND
    if method != EXACT:
        for k in range(4):
            zv[k] = zv[k] * z[k]
    return SEEN


@njit(cache=True)
def rmse_to(pv, dp):
    """``sqrt(mean_k |p_k - p_k^d|^2)`` (:func:`tdacm.loop.servo.normalized_rmse`)."""
    acc = 0.0
    for k in range(4):
        dx = pv[k, 0] - dp[k, 0]
        dy = pv[k, 1] - dp[k, 1]
        acc += dx * dx + dy * dy
    return np.sqrt(acc / 4.0)


@njit(cache=True)
def detect_global(q, m, sm, w, corners_uv):
    """C_G's analytic detection at the drone's pose (:class:`AnalyticFrontEnd` of the global
    camera, ideal): True when every marker's corners are in its view, their pixels (OpenCV
    order) in ``corners_uv`` (M, 4, 2)."""
    g_b = np.empty((4, 4))
    base_pose(q, m, g_b)
    g = np.empty((4, 4))
    _mul4(g_b, sm.drone_mount, g)
    cam = sm.global_camera
    corners = sm.corners[w]
    for mk in range(corners.shape[0]):
        for k in range(4):
            d0 = corners[mk, k, 0] - g[0, 3]
            d1 = corners[mk, k, 1] - g[1, 3]
            d2 = corners[mk, k, 2] - g[2, 3]
            x = d0 * g[0, 0] + d1 * g[1, 0] + d2 * g[2, 0]
            y = d0 * g[0, 1] + d1 * g[1, 1] + d2 * g[2, 1]
            z = d0 * g[0, 2] + d1 * g[1, 2] + d2 * g[2, 2]
            if not (z > 0.0 and z >= cam[NEAR] and z <= cam[FAR]):
                return False
            u = cam[FX] * x / z + cam[CX]
            v = cam[FY] * y / z + cam[CY]
            if not _in_image(cam, u, v, 0.0):
                return False
            corners_uv[mk, k, 0] = u
            corners_uv[mk, k, 1] = v
    return True


@njit(cache=True)
def plan_recovery(t, q, m, sm, corners_uv, rstate):
    """The recovery plan from one C_G snapshot (:meth:`VisualServo.plan`): the target's pose
    in C_G from one square marker (the largest tag of a pattern), its centre in the body
    frame, the strains that put it on C_L's optical axis (:func:`plan_kernel`) and the cubic
    trajectory there (``rstate``, :class:`tdacm.control.CubicTrajectory.with_speed`). False
    when the marker's corners admit no pose."""
    prm = sm.params
    cam = sm.global_camera
    mk = 0
    if prm[P_LARGEST_TAG] > 0.0:
        best = -1.0
        for i in range(corners_uv.shape[0]):
            ext = 0.0
            for a in range(2):
                lo_, hi_ = np.inf, -np.inf
                for k in range(4):
                    lo_ = min(lo_, corners_uv[i, k, a])
                    hi_ = max(hi_, corners_uv[i, k, a])
                ext += hi_ - lo_
            if ext > best:
                best, mk = ext, i
    xy = np.empty((4, 2))
    for k in range(4):
        src = _IPPE_ORDER[k]
        xy[k, 0] = (corners_uv[mk, src, 0] - cam[CX]) / cam[FX]
        xy[k, 1] = (corners_uv[mk, src, 1] - cam[CY]) / cam[FY]
    g = np.empty((4, 4))
    if not square_pose(sm.square, xy, sm.marker_centres[mk], g):
        return False
    p_body = np.empty(3)
    dm = sm.drone_mount
    for i in range(3):
        p_body[i] = dm[i, 0] * g[0, 3] + dm[i, 1] * g[1, 3] + dm[i, 2] * g[2, 3] + dm[i, 3]
    n = q.shape[0]
    ns = (rstate.shape[0] - 3) // 2
    qs_now = q[n - ns :].copy()
    x, _, _, _ = plan_kernel(qs_now, m, sm.rod[0], sm.rod[1], sm.mount_inv, p_body,
                             prm[P_Z_MIN], prm[P_BOUND], True)  # fmt: skip
    big = 0.0
    for i in range(ns):
        big = max(big, abs(x[i] - qs_now[i]))
    rstate[R_ON] = 1.0
    rstate[R_T0] = t
    rstate[R_TF] = t + max(0.5, 1.5 * big / prm[P_MAX_SPEED])
    for i in range(ns):
        rstate[R_Q0 + i] = qs_now[i]
        rstate[R_Q0 + ns + i] = x[i] - qs_now[i]
    return True


@njit(cache=True)
def follow_recovery(t, rstate, q_d, qd_d, qdd_d):
    """The cubic trajectory at ``t`` into the strains of ``q_d``, ``qd_d``, ``qdd_d``
    (:meth:`tdacm.control.CubicTrajectory.__call__`; the drone's rows held)."""
    n = q_d.shape[0]
    ns = (rstate.shape[0] - 3) // 2
    t0, tf = rstate[R_T0], rstate[R_TF]
    h = tf - t0
    tt = min(max(t - t0, 0.0), h)
    moving = not (t >= tf or t < t0)
    for i in range(n):
        qd_d[i] = 0.0
    for i in range(ns):
        d = rstate[R_Q0 + ns + i]
        a2 = 3 * d / h**2
        a3 = -2 * d / h**3
        j = n - ns + i
        q_d[j] = rstate[R_Q0 + i] + a2 * tt**2 + a3 * tt**3
        if moving:
            qd_d[j] = 2 * a2 * tt + 3 * a3 * tt**2
            qdd_d[j] = 2 * a2 + 6 * a3 * tt


@njit(cache=True)
def switch_mode(t, prev, counters, ins, seen, prm, sstate, rstate):
    """The mode switch of one period (:func:`switch_update` on the target seen, and inside
    the margin), kept in ``sstate``: ``(mode, event)``; engaging IBVS starts its soft start
    and drops the recovery trajectory."""
    mode = switch_update(prev, counters, ins, seen, int(prm[P_CONFIRM]), int(prm[P_LOSE]))
    sstate[S_MODE], sstate[S_GOOD], sstate[S_BAD] = mode, counters[0], counters[1]
    event = NO_EVENT
    if prev == RECOVERY and mode == IBVS:
        sstate[S_IBVS_START] = t
        rstate[R_ON] = 0.0
        event = IBVS_ENGAGED
    elif prev == IBVS and mode == RECOVERY:
        event = TARGET_LOST
    return mode, event


@njit(cache=True)
def servo_step(t, dt, q, found, uv, m, sm, w, sstate, rstate, q_d, qd_d, qdd_d, twist_in, out,
               g_c):  # fmt: skip
    """One period of :class:`tdacm.loop.servo.VisualServo` on the measured points (the
    perception block first): the mode switch, the view in C_V, the IBVS twist (or
    ``twist_in`` when it is finite: an external command), the joint rates shaped into
    ``qd_d`` and ``q_d`` (in place), a hold, or the recovery (a plan from a C_G snapshot when
    C_G is read this period, then its cubic trajectory; ``qdd_d`` its acceleration). ``out``
    receives ``[rmse, event, failure, twist (6), features (6)]``; failure 1: a point behind
    C_V (the loop's ``BEHIND_CAMERA``), 2: the recovery failed (C_G does not see the target,
    or its corners admit no pose). ``g_c``: C_L's pose at ``q`` (:func:`tip_camera_pose`)."""
    prm = sm.params
    n = q.shape[0]
    ctl = sm.ctl_camera[w]
    pv = np.empty((4, 2))
    zv = np.empty(4)
    # C_G is offered this period every `global_every` periods or when the servo asked
    k = int(sstate[S_PERIOD])
    every = int(prm[P_GLOBAL_EVERY])
    offered = sstate[S_REQUEST] > 0.0 or (every > 0 and k % every == 0)
    sstate[S_PERIOD] = k + 1
    sstate[S_REQUEST] = 0.0
    status = servo_view(q, found, uv, m, sm, w, g_c, pv, zv)
    seen = status != NOT_SEEN
    prev = int(sstate[S_MODE])
    counters = np.array([int(sstate[S_GOOD]), int(sstate[S_BAD])])
    ins = seen and inside(ctl, uv, prm[P_MARGIN])
    mode, event = switch_mode(t, prev, counters, ins, seen, prm, sstate, rstate)
    out[:] = 0.0
    out[0] = np.nan
    out[1] = event
    for i in range(n):
        qdd_d[i] = 0.0
    if status == BEHIND:
        out[2] = 1
        return mode
    if seen:
        out[0] = rmse_to(pv, sm.desired_points[w])
    external = np.isfinite(twist_in[0])
    if mode == IBVS and (seen or external):
        v = np.empty(6)
        if external:
            for i in range(6):
                v[i] = twist_in[i]
        else:
            if min_edge2(pv) < 1e-24:  # coincident corners: the view cannot be servoed on
                out[2] = 1
                return mode
            f = np.empty(6)
            e = np.empty(6)
            ibvs_twist(pv, zv, sm, w, f, e, v)
            for i in range(6):
                out[9 + i] = f[i]
        for i in range(6):
            out[3 + i] = v[i]
        rates = joint_rates(q, v, m, sm, m.floating)
        shape(rates, t, dt, sstate[S_IBVS_START], sm, q_d, qd_d)
    elif mode == RECOVERY:
        recovery_period(t, q, m, sm, w, offered, -1.0, sstate, rstate, q_d, qd_d, qdd_d, out)
    else:
        for i in range(n):
            qd_d[i] = 0.0
    return mode


@njit(cache=True)
def recovery_period(t, q, m, sm, w, offered, retry_for, sstate, rstate, q_d, qd_d, qdd_d, out):
    """The servo's recovery mode for one period: before a trajectory exists, hold and ask C_G
    for a snapshot (``offered`` false), detect the target in it, plan (the target's pose from
    the snapshot, the cubic trajectory) and start from the current pose with a level drone;
    then follow the trajectory. When C_G misses the target, ``retry_for`` > 0 s (the robust
    servo's ``lost_timeout``) holds and asks again until that long has passed since the first
    miss; otherwise (and when no plan exists) the run ends as a failed recovery
    (``out[2] = 2``)."""
    n = q.shape[0]
    if rstate[R_ON] == 0.0:
        if not offered:  # hold and ask C_G for the next period
            for i in range(n):
                qd_d[i] = 0.0
            sstate[S_REQUEST] = 1.0
            return
        corners_uv = np.empty((sm.corners.shape[1], 4, 2))
        if not detect_global(q, m, sm, w, corners_uv):
            for i in range(n):
                qd_d[i] = 0.0
            if retry_for <= 0.0:
                out[2] = 2
                return
            if not np.isfinite(sstate[S_CG_MISSED]):
                sstate[S_CG_MISSED] = t
            if t - sstate[S_CG_MISSED] >= retry_for:
                out[2] = 2
            else:
                sstate[S_REQUEST] = 1.0
            return
        sstate[S_CG_MISSED] = np.nan
        if not plan_recovery(t, q, m, sm, corners_uv, rstate):
            out[2] = 2
            return
        for i in range(n):
            q_d[i] = q[i]
        if m.floating:
            q_d[0] = 0.0
            q_d[1] = 0.0
    follow_recovery(t, rstate, q_d, qd_d, qdd_d)


# ----------------------------------------------------------------------------- robust servo
class FilterData(NamedTuple):
    """One world's robust-servo state (rows of :class:`~tdacm.batch.engine.BatchData`): the
    target filter's scalars ``st``, estimate ``pose``, covariance ``cov``, PnP hypotheses
    ``hyp`` and window ``rc``, ``pc``, ``z`` (:func:`~tdacm.vision.target_filter.filter_update`),
    the smoothed target pose ``t_pose`` and the C_L poses of the last periods ``cam_hist``
    (latency + 1, 4, 4; a frame is fused with the pose of its capture period)."""

    st: np.ndarray
    pose: np.ndarray
    cov: np.ndarray
    hyp: np.ndarray
    rc: np.ndarray
    pc: np.ndarray
    z: np.ndarray
    t_pose: np.ndarray
    cam_hist: np.ndarray


@njit(cache=True)
def _smooth_target(fd, sstate, a):
    """:meth:`RobustServo.predict_target`: the smoothed pose toward the filter's estimate by
    the fraction ``a`` of one period (a first-order filter on SE(3))."""
    if fd.st[0] == 0.0:  # F_INIT: nothing fused yet, or the filter restarted
        return
    if sstate[S_TP_SET] == 0.0 or a >= 1.0:
        fd.t_pose[:, :] = fd.pose
        sstate[S_TP_SET] = 1.0
        return
    d = np.empty((4, 4))
    _inv4(fd.t_pose, d)
    d2 = np.empty((4, 4))
    _mul4(d, fd.pose, d2)
    w = a * so3_log(np.ascontiguousarray(d2[:3, :3]))
    step = expmap(np.array([w[0], w[1], w[2], 0.0, 0.0, 0.0]))
    for i in range(3):
        step[i, 3] = a * d2[i, 3]
    out = np.empty((4, 4))
    _mul4(fd.t_pose, step, out)
    fd.t_pose[:, :] = out


@njit(cache=True)
def robust_predict(dt, k, q, found, uv, m, sm, w, sstate, fd, g_c, pv, zv, pix):
    """The first part of :func:`robust_step` (:meth:`RobustServo.perceive`): the delivered
    frame fused into the target filter with the C_L pose of its capture period ``k -
    latency`` (``k``: this period), the smoothed target estimate and the feature points
    predicted in the servo camera (``pv``, ``zv``) and in C_L (``pix``, pixels). Returns
    ``(valid, pix_ok, view)``: a prediction exists (in front of the servo camera, corners
    apart), it is in front of C_L, the frame was perceived. ``g_c``: C_L's pose at ``q``
    (:func:`tip_camera_pose`)."""
    prm = sm.params
    ctl = sm.ctl_camera[w]
    # fuse the delivered frame with the C_L pose of its capture period (latency compensation)
    hist = fd.cam_hist.shape[0]
    fd.cam_hist[k % hist] = g_c
    xy = np.empty((4, 2))
    zz = np.empty(4)
    view = found and perceive(ctl, sm.object_2d, uv, xy, zz)
    cap = max(0, k - int(sm.sensor[w, SN_LATENCY]))
    if view and cap > sstate[S_LAST_FUSED]:
        sstate[S_LAST_FUSED] = cap
        if filter_update(sm.filter_params, ctl[:4], fd.st, fd.pose, fd.cov, fd.hyp, fd.rc,
                         fd.pc, fd.z, sm.object_points, sm.object_2d, sm.canon_inv,
                         sm.level_normal, uv, fd.cam_hist[cap % hist]):  # fmt: skip
            sstate[S_LAST_SEEN] = cap * dt
    smoothing = prm[P_SMOOTHING]
    _smooth_target(fd, sstate, min(1.0, dt / smoothing) if smoothing > 0.0 else 1.0)
    # the prediction in the servo camera and in C_L
    valid = False
    pix_ok = False
    if sstate[S_TP_SET] != 0.0:
        g_s = g_c
        if m.floating:
            g_b = np.empty((4, 4))
            base_pose(q, m, g_b)
            gv = np.empty((4, 4))
            virtual_transform(g_b, g_c, gv)  # g_{C_L}^{C_V}; C_V = C_L (g_{C_L}^{C_V})^-1
            iv = np.empty((4, 4))
            _inv4(gv, iv)
            g_s = np.empty((4, 4))
            _mul4(g_c, iv, g_s)
        points_in_kernel(sm.object_points, g_s, fd.t_pose, pv, zv)
        valid = min_edge2(pv) >= 1e-24
        for i in range(4):
            if not zv[i] > 0.0:
                valid = False
        if valid:
            xl = np.empty((4, 2))
            zl = np.empty(4)
            points_in_kernel(sm.object_points, g_c, fd.t_pose, xl, zl)
            pix_ok = True
            for i in range(4):
                if not zl[i] > 0.0:
                    pix_ok = False
                pix[i, 0] = ctl[FX] * xl[i, 0] / 1.0 + ctl[CX]
                pix[i, 1] = ctl[FY] * xl[i, 1] / 1.0 + ctl[CY]
    return valid, pix_ok, view


@njit(cache=True)
def robust_step(t, dt, q, found, uv, m, sm, w, sstate, rstate, q_d, qd_d, qdd_d, twist_in, out,
                valid, pix_ok, view, pv, zv, pix):  # fmt: skip
    """One period of :class:`tdacm.loop.servo.RobustServo` (``ibvs.features = "predicted"``):
    the delivered frame fused into the target filter with the C_L pose of its capture period
    (:func:`~tdacm.vision.target_filter.filter_update`), the smoothed target estimate, the
    feature points predicted in the servo camera (C_V, eq. (18); C_L for a held base) and in
    C_L (the mode switch's field-of-view test while servoing), the IBVS twist on the
    predicted points (eqs. (19)-(21), (39)), the joint rates shaped as :func:`servo_step`
    with the acceleration feed-forward and the leak of ``q_d`` toward ``q``, or the recovery
    (which holds and retries for ``lost_timeout`` s while C_G misses the target). ``out`` as
    :func:`servo_step` (no behind-camera failure: a prediction behind the camera counts as
    not seen).

    The perception part is :func:`robust_predict` of this period (``k``: the row
    ``S_PERIOD`` before this step), run by the caller once (the engine keeps it, so an
    observation of the period and its step share one fusion): its results ``valid``,
    ``pix_ok``, ``view`` and the predicted points ``pv``, ``zv`` (servo camera) and ``pix``
    (C_L pixels) are inputs here."""
    prm = sm.params
    n = q.shape[0]
    ctl = sm.ctl_camera[w]
    k = int(sstate[S_PERIOD])
    every = int(prm[P_GLOBAL_EVERY])
    offered = sstate[S_REQUEST] > 0.0 or (every > 0 and k % every == 0)
    sstate[S_PERIOD] = k + 1
    sstate[S_REQUEST] = 0.0
    f = np.zeros(6)
    e = np.zeros(6)
    v = np.zeros(6)
    if valid:
        ibvs_twist(pv, zv, sm, w, f, e, v)
    # the mode switch: on the predicted C_L pixels while servoing, on the view otherwise
    prev = int(sstate[S_MODE])
    counters = np.array([int(sstate[S_GOOD]), int(sstate[S_BAD])])
    if prev == IBVS:
        seen = (
            valid
            and pix_ok
            and np.isfinite(sstate[S_LAST_SEEN])
            and t - sstate[S_LAST_SEEN] <= prm[P_LOST_TIMEOUT]
            and inside(ctl, pix, 0.0)
        )
        ins = seen and inside(ctl, pix, prm[P_MARGIN])
    else:
        seen = view
        ins = seen and inside(ctl, uv, prm[P_MARGIN])
    mode, event = switch_mode(t, prev, counters, ins, seen, prm, sstate, rstate)
    out[:] = 0.0
    out[0] = rmse_to(pv, sm.desired_points[w]) if valid else np.nan
    out[1] = event
    for i in range(n):
        qdd_d[i] = 0.0
    if valid:
        for i in range(6):
            out[9 + i] = f[i]
    external = np.isfinite(twist_in[0])
    if mode == IBVS and (valid or external):
        if external:
            for i in range(6):
                v[i] = twist_in[i]
        for i in range(6):
            out[3 + i] = v[i]
        qd_prev = qd_d.copy()
        rates = joint_rates(q, v, m, sm, m.floating)
        shape(rates, t, dt, sstate[S_IBVS_START], sm, q_d, qd_d)
        if m.floating:  # the feed-forward and the leak are the flying base's
            if prm[P_ACCEL_FF] != 0.0:
                for i in range(n):
                    qdd_d[i] = (qd_d[i] - qd_prev[i]) / dt
            leak = prm[P_LEAK]
            if leak > 0.0:
                cmd = sm.commanded
                for c in range(cmd.shape[0]):
                    j = cmd[c]
                    q_d[j] += leak * dt * (q[j] - q_d[j])
    elif mode == RECOVERY:
        recovery_period(
            t, q, m, sm, w, offered, prm[P_LOST_TIMEOUT], sstate, rstate, q_d, qd_d, qdd_d, out
        )
    else:
        for i in range(n):
            qd_d[i] = 0.0
    return mode
