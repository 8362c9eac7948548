"""Numba kernels of the identification: segment-wise shooting and the measured poses.

:func:`shoot` integrates every multiple-shooting segment from its own initial state with the
recorded inputs held over each sample interval (a zero-order hold), using the classical RK4
update of :func:`tdacm.system.kernels.rk4_run` (the same formula, so the fit sees the model a
closed-loop run integrates) and :func:`tdacm.system.kernels.forward_dynamics`. Two effects the
system model does not carry are applied to the input before each stage:

* the thrust constant: the motor thrusts act as ``k_T u_thrust`` (``k_T = 1`` is the model);
* tendon friction (Coulomb + viscous, on the tension delivered to the rod, see
  :mod:`tdacm.identify.params`): ``T_eff = T (1 + mu tanh(ldot / v0)) + c_v ldot``, clipped at
  0, with ``ldot = -B_s(q)^T qdot_s`` the tendon length rate (``B_s = -dl/dq_s``, eq. (13)).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..system import kernels as K
from ..system import stiff as ST

#: A state beyond this magnitude ends its segment (the fit's trial models may be unstable).
BLOWUP = 1e4


@njit(cache=True)
def effective_input(q, qd, u, m, thrust_k, mu, cv, v0):
    """The input the rod and drone feel: thrust constant and tendon friction applied."""
    ue = u.copy()
    nu = u.shape[0]
    na = m.tendon_d.shape[1]
    if m.floating:
        for i in range(4):
            ue[i] = thrust_k * u[i]
    if mu != 0.0 or cv != 0.0:
        off = 6 if m.floating else 0
        bs = K.tendon_matrix(q[off:], m)
        ns = bs.shape[0]
        for i in range(na):
            ld = 0.0
            for c in range(ns):
                ld -= bs[c, i] * qd[off + c]
            t = u[nu - na + i]
            te = t * (1.0 + mu * np.tanh(ld / v0)) + cv * ld
            ue[nu - na + i] = te if te > 0.0 else 0.0
    return ue


@njit(cache=True)
def _acc(q, qd, u, m, loads, thrust_k, mu, cv, v0):
    return K.forward_dynamics(q, qd, effective_input(q, qd, u, m, thrust_k, mu, cv, v0), m, loads)


@njit(cache=True)
def _segment(q0, qd0, k0, length, o, us, substeps, dt, m, loads, thrust_k, mu, cv, v0, stiff,
             qs, qds):  # fmt: skip
    """One shooting segment: from ``(q0, qd0)`` through ``length`` samples with the inputs
    ``us[k0 + j]`` held over sample ``j``, the states written to rows ``o + j`` of
    ``qs``/``qds``. Returns False when the segment stopped (see :func:`shoot`)."""
    q = q0.copy()
    qd = qd0.copy()
    alive = True
    for j in range(length):
        qs[o + j] = q
        qds[o + j] = qd
        if j + 1 == length or not alive:
            continue
        u = us[k0 + j]
        for _ in range(substeps):
            if stiff:
                ue = effective_input(q, qd, u, m, thrust_k, mu, cv, v0)
                q1, qd1, _, _, oks = ST.rosw_step(
                    q, qd, ue, dt, m, loads, ST.A_T, ST.C_T, ST.M_T, ST.E_T, ST.GAMMA
                )
                if not (oks and np.all(np.abs(q1) < BLOWUP) and np.all(np.abs(qd1) < BLOWUP)):
                    alive = False
                    break
                q = q1
                qd = qd1
                continue
            a1, ok1 = _acc(q, qd, u, m, loads, thrust_k, mu, cv, v0)
            a2, ok2 = _acc(q + 0.5 * dt * qd, qd + 0.5 * dt * a1, u, m, loads, thrust_k, mu, cv, v0)
            a3, ok3 = _acc(
                q + 0.5 * dt * (qd + 0.5 * dt * a1),
                qd + 0.5 * dt * a2,
                u, m, loads, thrust_k, mu, cv, v0,
            )  # fmt: skip
            a4, ok4 = _acc(
                q + dt * (qd + 0.5 * dt * a2), qd + dt * a3, u, m, loads, thrust_k, mu, cv, v0
            )
            if not (ok1 and ok2 and ok3 and ok4):
                alive = False
                break
            q1 = q + dt * qd + dt * dt / 6.0 * (a1 + a2 + a3)
            qd1 = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            if not (np.all(np.abs(q1) < BLOWUP) and np.all(np.abs(qd1) < BLOWUP)):
                alive = False
                break
            q = q1
            qd = qd1
    return alive


@njit(cache=True)
def shoot(q0s, qd0s, starts, ends, us, substeps, dt, m, loads, thrust_k, mu, cv, v0, stiff=False):
    """States at every sample of every segment (one thread; :func:`shoot_many` runs the
    segments in parallel to the same result).

    Segment ``i`` holds samples ``starts[i] <= k < ends[i]``; it starts at ``(q0s[i], qd0s[i])``
    on sample ``starts[i]`` and reaches sample ``k + 1`` from ``k`` with ``us[k]`` held, in
    ``substeps`` RK4 steps of ``dt`` (``stiff``: ROS34PW2 steps of
    :func:`tdacm.system.stiff.rosw_step`, L-stable, for a basis whose damped higher modes
    make RK4 unstable at ``dt``; the friction-corrected input is then evaluated at each step's
    start). Returns ``(q, qd, ok)`` of shape (T, n); a segment whose mass matrix turns
    singular (or whose state leaves ``|x| < BLOWUP``) keeps its last state and ``ok`` becomes
    False.
    """
    n = q0s.shape[1]
    total = ends[-1]
    qs = np.zeros((total, n))
    qds = np.zeros((total, n))
    ok_all = True
    for i in range(starts.shape[0]):
        ok = _segment(q0s[i], qd0s[i], starts[i], ends[i] - starts[i], starts[i], us, substeps,
                      dt, m, loads, thrust_k, mu, cv, v0, stiff, qs, qds)  # fmt: skip
        ok_all = ok_all and ok
    return qs, qds, ok_all


@njit(cache=True, parallel=True)
def shoot_many(q0s, qd0s, in0, lengths, out0, total, us, substeps, dt, m, loads, thrust_k, mu,
               cv, v0, stiff=False):  # fmt: skip
    """Independent segments in parallel over the cores (numba ``prange``): segment ``i`` starts
    at ``(q0s[i], qd0s[i])``, takes its inputs from row ``in0[i]`` of ``us`` on and writes its
    ``lengths[i]`` states from row ``out0[i]`` of the ``(total, n)`` outputs; otherwise as
    :func:`shoot` (the same arithmetic per segment, so the same result to the bit whatever
    the number of threads). Many trajectories in one call: every window of a recording, and
    the same windows again from perturbed states (a Jacobian's state columns) or with other
    inputs (the load cells' noise draws). Returns ``(q, qd, ok)``, ``ok`` per segment."""
    n = q0s.shape[1]
    ns = q0s.shape[0]
    qs = np.zeros((total, n))
    qds = np.zeros((total, n))
    oks = np.ones(ns, dtype=np.bool_)
    for i in prange(ns):
        oks[i] = _segment(q0s[i], qd0s[i], in0[i], lengths[i], out0[i], us, substeps, dt, m,
                          loads, thrust_k, mu, cv, v0, stiff, qs, qds)  # fmt: skip
    return qs, qds, oks


@njit(cache=True)
def _pose_row(qs, k, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs, base, tip):
    """Row ``k`` of :func:`poses`: the drone's pose into ``base[k]``, ``g_L`` into ``tip[k]``."""
    out, _, gb = K.chain_poses(qs[k], floating, g_fixed, g_att, h, xi0s, bs, cols, ncs)
    base[k] = gb
    tip[k] = out[out.shape[0] - 1]


@njit(cache=True)
def poses(qs, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs):
    """Drone (base) pose and tip pose ``g_L`` at every row of ``qs``: two (T, 4, 4) arrays."""
    base, tip = np.empty((qs.shape[0], 4, 4)), np.empty((qs.shape[0], 4, 4))
    for k in range(qs.shape[0]):
        _pose_row(qs, k, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs, base, tip)
    return base, tip


@njit(cache=True, parallel=True)
def poses_many(qs, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs):
    """:func:`poses` in parallel over the rows (``prange``; the same result per row)."""
    base, tip = np.empty((qs.shape[0], 4, 4)), np.empty((qs.shape[0], 4, 4))
    for k in prange(qs.shape[0]):
        _pose_row(qs, k, floating, g_fixed, g_att, h, xi0s, bs, cols, ncs, base, tip)
    return base, tip
