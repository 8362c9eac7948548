"""The plant of one world as a compiled function over plain arrays.

:func:`plant_period` is :meth:`tdacm.loop.plant.Plant.advance` without contact: the loads
(gravity and the scenario's ``[disturbances]``: the base wrench ``amplitude sin(2 pi f t)`` on
a drone, the downwash ``downwash + noise N(0, I3)`` on the rod), the wind of ``[wind]`` at the
period's start in the packed aerodynamics, ``substeps`` RK4 steps of the coupled model
(paper eq. (9), :func:`tdacm.system.kernels.rk4_run_aero`), the health flags and the clock
``t0 + k dt``. Its inputs are a :class:`PlantArrays` built once from the Python block
(:func:`plant_arrays`), so the compiled plant is the block's twin and never a second truth.

Random numbers are inputs: the engine owns the streams. Per period the plant reads 3 standard
normals for the downwash noise (read only when ``[disturbances]`` has a downwash or its
noise) and, with Dryden turbulence, 5 standard normals per turbulence sample: the turbulence
is sampled every control period (:meth:`tdacm.aero.wind.WindConfig.build`), so a period
starting at ``t = k dt`` with ``k >= 1`` takes one sample (one row of ``wind_normals``) and
the first period none; its initial state takes 5 more (:func:`wind_start`). The draws are
used in the order of :class:`tdacm.aero.wind.DrydenTurbulence` (``u``, then ``v``'s two, then
``w``'s two), so the same normals give its samples.

Per-world parameters: the model arrays' stiffness, damping, step masses, ``mb6`` and tendon
offsets (:func:`model_of_world` builds a world's :class:`~tdacm.system.kernels.ModelArrays` inside
compiled code), ``loads``, ``disturbances``, ``aero`` and ``wind`` may differ per world (a
leading world axis; each world integrates with its own ``aero`` copy, whose wind slot the
period overwrites).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..aero import layout as AL
from ..aero.wind import DrydenTurbulence, Gust, SteadyWind, Wind, _Sum
from ..loop.plant import MAX_TILT_RAD, Plant
from ..system.kernels import LOAD_SLICES, ModelArrays, forward_dynamics_aero, rk4_run_aero

_BW = LOAD_SLICES["base_wrench"].start
_RF = LOAD_SLICES["rod_force"].start

#: ``disturbances`` of :class:`PlantArrays`: 1 when the base wrench acts (a drone, a non-zero
#: amplitude and a positive frequency)
D_WRENCH_ON = 0
#: (6,) its amplitude ``[m; f]`` in the body frame
D_WRENCH_AMPLITUDE = 1
#: its frequency (Hz)
D_WRENCH_FREQUENCY = 7
#: 1 when the downwash acts (a non-zero force density or a positive noise)
D_DOWNWASH_ON = 8
#: (3,) the downwash force density (N/m, inertial)
D_DOWNWASH = 9
#: the downwash noise's standard deviation (N/m)
D_DOWNWASH_NOISE = 12
N_DISTURBANCES = 13

#: ``wind`` of :class:`PlantArrays`: 1 when the plant has a wind (it sets the aerodynamics'
#: wind at every period's start)
W_ON = 0
#: 1: a steady wind of velocity ``W_STEADY`` (3,)
W_STEADY_ON = 1
W_STEADY = 2
#: 1: a 1-cosine gust of amplitude ``W_GUST`` (3,), start and duration (s)
W_GUST_ON = 5
W_GUST = 6
W_GUST_START = 9
W_GUST_DURATION = 10
#: 1: Dryden turbulence sampled every ``W_TURB_DT`` (s)
W_TURB_ON = 11
W_TURB_DT = 12
#: (3, 3) row-major: the inertial directions (columns) of ``u, v, w``
W_AXES = 13
#: the three shaping filters (``u``: one state, ``v``, ``w``: two), each ``W_FILTER`` values
#: from ``W_FILTERS + i W_FILTER``: the transition ``Phi`` (2 x 2, row-major), the Cholesky
#: factor of the sample covariance (2 x 2), the output row ``c`` (2,), the Cholesky factor of
#: the stationary covariance (2 x 2), padded with zeros for ``u``
W_FILTERS = 22
W_FILTER = 14
_F_PHI, _F_LQ, _F_C, _F_L0 = 0, 4, 8, 10
N_WIND = W_FILTERS + 3 * W_FILTER
#: the state dimension of each filter
_DIMS = (1, 2, 2)
#: the wind's state (:func:`wind_start`): ``[samples taken, x_u, x_v (2), x_w (2)]``
N_WIND_STATE = 6
#: standard normals per turbulence sample (and for its initial state)
N_WIND_NORMALS = 5


class PlantArrays(NamedTuple):
    """The plant of one world as arrays (:func:`plant_arrays`), besides the system's model
    arrays (a :class:`~tdacm.system.kernels.ModelArrays`, passed apart: numba's parallel loops
    take no NamedTuple inside a NamedTuple).

    ``loads`` (27,): the packed loads without the
    disturbances (gravity and the system's own loads); ``disturbances``
    (:data:`N_DISTURBANCES`,) by the ``D_*`` indices; ``aero``: the packed aerodynamics
    (:mod:`tdacm.aero.layout`; empty: none), a template each world copies; ``wind``
    (:data:`N_WIND`,) by the ``W_*`` indices; ``substeps``: RK4 steps a period."""

    loads: np.ndarray
    disturbances: np.ndarray
    aero: np.ndarray
    wind: np.ndarray
    substeps: int


def plant_arrays(plant: Plant) -> tuple[PlantArrays, ModelArrays]:
    """``(arrays, model)`` of the scenario's plant block (``loop.plant``, a
    :class:`~tdacm.loop.plant.Plant`): the :class:`PlantArrays` and the system's model
    arrays.

    Refused (``ValueError`` naming the scenario key): contact (``scene.obstacles`` or
    ``scene.contact.target_box``). The accelerations an IMU senses (a block with
    ``accelerations``, ``estimation.source = "estimated"``) are :func:`plant_accelerations`."""
    if type(plant) is not Plant:
        raise ValueError(f"the batched plant packs a tdacm.loop.plant.Plant, got {plant!r}")
    if plant.contact is not None:
        raise ValueError(
            "scene.obstacles / scene.contact.target_box: the batched plant has no contact "
            "(run the scenario with the block loop)"
        )
    d = plant.disturbances
    floating = plant.system.floating
    dist = np.zeros(N_DISTURBANCES)
    if floating and np.any(d.base_wrench_amplitude) and d.base_wrench_frequency > 0:
        dist[D_WRENCH_ON] = 1.0
    dist[D_WRENCH_AMPLITUDE : D_WRENCH_AMPLITUDE + 6] = d.base_wrench_amplitude
    dist[D_WRENCH_FREQUENCY] = d.base_wrench_frequency
    if np.any(d.downwash) or d.downwash_noise > 0:
        dist[D_DOWNWASH_ON] = 1.0
    dist[D_DOWNWASH : D_DOWNWASH + 3] = d.downwash
    dist[D_DOWNWASH_NOISE] = d.downwash_noise
    aero = np.empty(0) if plant.aero is None else plant.aero.copy()
    arrays = PlantArrays(
        plant._base.copy(), dist, aero, wind_array(plant.wind), int(plant.substeps)
    )
    return arrays, plant.system.model_arrays


def wind_array(wind: Wind | None) -> np.ndarray:
    """The packed ``wind`` (:data:`N_WIND`,) of a :class:`~tdacm.aero.wind.Wind`: a
    :class:`~tdacm.aero.wind.SteadyWind`, a :class:`~tdacm.aero.wind.Gust`, a
    :class:`~tdacm.aero.wind.DrydenTurbulence` or a sum with at most one of each, in that
    order (as :meth:`tdacm.aero.config.WindConfig.build` makes them: the sum's order is the
    order of the additions); ``None``: no wind."""
    w = np.zeros(N_WIND)
    if wind is None:
        return w
    parts = list(wind.parts) if type(wind) is _Sum else [wind]
    if any(type(p) is _Sum for p in parts):
        parts = _flatten(parts)
    order = [SteadyWind, Gust, DrydenTurbulence]
    kinds = [type(p) for p in parts]
    if any(k not in order for k in kinds) or kinds != sorted(kinds, key=order.index):
        raise ValueError(
            "wind: the batched plant ports a steady wind, a gust and Dryden turbulence "
            f"(at most one each, in that order), got {[k.__name__ for k in kinds]}"
        )
    if len(set(kinds)) != len(kinds):
        raise ValueError("wind: at most one steady wind, one gust and one turbulence")
    w[W_ON] = 1.0
    for p in parts:
        if type(p) is SteadyWind:
            w[W_STEADY_ON] = 1.0
            w[W_STEADY : W_STEADY + 3] = p.value
        elif type(p) is Gust:
            w[W_GUST_ON] = 1.0
            w[W_GUST : W_GUST + 3] = p.amplitude
            w[W_GUST_START] = p.start
            w[W_GUST_DURATION] = p.duration
        else:
            w[W_TURB_ON] = 1.0
            w[W_TURB_DT] = p.dt
            w[W_AXES : W_AXES + 9] = p.axes.ravel()
            for i, (phi, lq, c, p0) in enumerate(p._filters):
                k = phi.shape[0]
                base = W_FILTERS + i * W_FILTER
                for off, mat in ((_F_PHI, phi), (_F_LQ, lq), (_F_L0, np.linalg.cholesky(p0))):
                    blk = np.zeros((2, 2))
                    blk[:k, :k] = mat
                    w[base + off : base + off + 4] = blk.ravel()
                w[base + _F_C : base + _F_C + k] = c
    return w


def _flatten(parts):
    out = []
    for p in parts:
        out.extend(_flatten(p.parts) if type(p) is _Sum else [p])
    return out


def plant_state(plant: Plant):
    """``(q, qd, wind_state)`` of the block's state (copies; ``wind_state`` zeros, see
    :func:`wind_start`)."""
    s = plant.state
    return s.q.copy(), s.qd.copy(), np.zeros(N_WIND_STATE)


@njit(cache=True)
def model_of_world(m, mb6, stiffness, damping, step_mass, tendon_d, tendon_dd):
    """``m`` (:class:`~tdacm.system.kernels.ModelArrays`) with one world's drone inertia
    ``mb6`` (6,), ``stiffness`` and ``damping`` (n, n), ``step_mass`` (n_steps, 6) and tendon
    offsets ``tendon_d``, ``tendon_dd`` (n_g, n_a, 3), for an engine that stacks these along a
    world axis: built inside compiled code (numba constructs the NamedTuple; it has no
    ``_replace``); the run constants are the scenario's (the factors keep the zeros of
    ``stiffness`` and ``damping``). Pass C-contiguous rows of C-contiguous stacks (``stack[w]``): the record
    then has the type of ``m`` and the kernels run their compiled build (no new
    specialization)."""
    return ModelArrays(
        m.floating, m.g_fixed, m.g_att, m.rod_steps, m.h, m.xi0s, m.bs, m.step_col, m.step_nc,
        m.step_w, step_mass, m.step_load, mb6, stiffness, damping, m.gamma, m.wq, m.xi0g, m.bg,
        m.g_col, m.g_nc, tendon_d, tendon_dd, m.tendon_on, m.step_z, m.step_c4, m.step_one,
        m.step_nzc, m.step_nzn, m.g_nzc, m.g_nzn, m.g_nzr, m.g_nzrn, m.kd_lo, m.kd_hi,
    )  # fmt: skip


@njit(cache=True)
def wind_start(wind, normals, state):
    """The turbulence's initial state from ``normals`` (:data:`N_WIND_NORMALS`,): the
    stationary distribution of its filters (``x_i = L0_i z_i``, as
    :meth:`tdacm.aero.wind.DrydenTurbulence.reset`), no sample taken yet."""
    for i in range(N_WIND_STATE):
        state[i] = 0.0
    if wind[W_TURB_ON] == 0.0:
        return
    z = 0
    x = 1
    for f in range(3):
        base = W_FILTERS + f * W_FILTER + _F_L0
        k = 1 if f == 0 else 2
        for r in range(k):
            acc = 0.0
            for c in range(k):
                acc += wind[base + 2 * r + c] * normals[z + c]
            state[x + r] = acc
        z += k
        x += k


@njit(cache=True)
def _turbulence_step(wind, state, normals):
    """One sample of the turbulence: ``x_i <- Phi_i x_i + Lq_i z_i`` (exact discretization of
    the shaping filters, :class:`tdacm.aero.wind.DrydenTurbulence`)."""
    z = 0
    x = 1
    for f in range(3):
        base = W_FILTERS + f * W_FILTER
        k = 1 if f == 0 else 2
        x0 = state[x]
        x1 = state[x + 1] if k == 2 else 0.0
        for r in range(k):
            a = wind[base + _F_PHI + 2 * r] * x0
            b = wind[base + _F_LQ + 2 * r] * normals[z]
            if k == 2:
                a += wind[base + _F_PHI + 2 * r + 1] * x1
                b += wind[base + _F_LQ + 2 * r + 1] * normals[z + 1]
            state[x + r] = a + b
        z += k
        x += k
    state[0] += 1.0


@njit(cache=True)
def wind_velocity(wind, state, t, normals, out):
    """The wind (3,) at time ``t`` into ``out``: steady + gust + turbulence, the turbulence
    brought to its sample ``floor(t / dt)`` first (one row of ``normals``, (rows, 5), per
    sample; ``ValueError`` if they do not suffice or ``t`` is before the last sample)."""
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    if wind[W_STEADY_ON] != 0.0:
        for i in range(3):
            out[i] = out[i] + wind[W_STEADY + i]
    if wind[W_GUST_ON] != 0.0:
        x = (t - wind[W_GUST_START]) / wind[W_GUST_DURATION]
        if 0.0 <= x <= 1.0:
            g = 1.0 - math.cos(2.0 * math.pi * x)
            for i in range(3):
                out[i] = out[i] + 0.5 * wind[W_GUST + i] * g
    if wind[W_TURB_ON] != 0.0:
        k = int(math.floor(t / wind[W_TURB_DT] + 1e-9))
        taken = int(state[0])
        if k < taken:
            raise ValueError("turbulence is sampled forward in time")
        if k - taken > normals.shape[0]:
            raise ValueError("turbulence: more samples due than rows of normals")
        row = 0
        while int(state[0]) < k:
            _turbulence_step(wind, state, normals[row])
            row += 1
        # the filters' outputs c_i . x_i (u: one state, v and w: two)
        u_ = wind[W_FILTERS + _F_C] * state[1]
        b = W_FILTERS + W_FILTER + _F_C
        v_ = wind[b] * state[2] + wind[b + 1] * state[3]
        b = W_FILTERS + 2 * W_FILTER + _F_C
        w_ = wind[b] * state[4] + wind[b + 1] * state[5]
        for i in range(3):
            a = W_AXES + 3 * i
            out[i] = out[i] + (wind[a] * u_ + wind[a + 1] * v_ + wind[a + 2] * w_)


@njit(cache=True)
def plant_period(
    pa, m, aero, q, qd, wind_state, u, dt, t0, k, dist_normals, wind_normals, loads, q_out, qd_out
):
    """One control period of the plant of one world (module docstring):
    :meth:`tdacm.loop.plant.Plant.advance` without contact on the arrays ``pa`` (a
    :class:`PlantArrays`) and the system's model arrays ``m`` (:func:`plant_arrays`).

    ``aero``: the world's own copy of ``pa.aero`` (its wind slot is set here); ``q, qd`` (n,)
    the state at the period's start ``t = t0 + k dt``; ``wind_state`` (:data:`N_WIND_STATE`,)
    updated in place; ``u`` (n_u,) the inputs held over the period; ``dist_normals`` (3,) the
    downwash noise's draws; ``wind_normals`` (rows, 5) the turbulence's draws (one row a
    sample, see the module docstring); ``loads`` (27,) scratch. Writes the state at the
    period's end into ``q_out, qd_out`` and returns ``(ok, tumbled, t_end)``: ``ok`` false
    when the integration failed (a singular mass matrix; the state is then the last good
    RK4 step's) or the state is not finite, ``tumbled`` when the drone's roll or pitch
    exceeds :data:`~tdacm.loop.plant.MAX_TILT_RAD`, ``t_end = t0 + (k + 1) dt``."""
    t = t0 + k * dt
    dist = pa.disturbances
    for i in range(loads.shape[0]):
        loads[i] = pa.loads[i]
    if dist[D_WRENCH_ON] != 0.0:
        sn = np.sin(2 * np.pi * dist[D_WRENCH_FREQUENCY] * t)
        for i in range(6):
            loads[_BW + i] = dist[D_WRENCH_AMPLITUDE + i] * sn
    if dist[D_DOWNWASH_ON] != 0.0:
        for i in range(3):
            loads[_RF + i] = dist[D_DOWNWASH + i] + dist[D_DOWNWASH_NOISE] * dist_normals[i]
    if pa.wind[W_ON] != 0.0:
        wind_velocity(pa.wind, wind_state, t, wind_normals, aero[AL.WIND : AL.WIND + 3])
    n = pa.substeps
    qs, qds, ok = rk4_run_aero(q, qd, u, dt / n, n, n, m, loads, aero)
    last = qs.shape[0] - 1
    finite = True
    for i in range(q.shape[0]):
        q_out[i] = qs[last, i]
        qd_out[i] = qds[last, i]
        finite = finite and np.isfinite(q_out[i]) and np.isfinite(qd_out[i])
    tumbled = m.floating and max(abs(q_out[0]), abs(q_out[1])) > MAX_TILT_RAD
    return ok and finite, tumbled, t0 + (k + 1) * dt


@njit(cache=True)
def plant_accelerations(m, aero, loads, q, qd, u, qdd_out):
    """The accelerations at the end of a period (what an accelerometer senses, the
    ``PlantState.qdd`` of a :class:`~tdacm.loop.plant.Plant` with ``accelerations``): the
    forward dynamics (paper eq. (9)) at the period's end state ``q, qd`` under its input ``u``,
    loads and wind (the ``loads`` and ``aero`` :func:`plant_period` just used) into
    ``qdd_out``; returns ``ok`` (false: a singular mass matrix, ``qdd_out`` unchanged). Call it
    only after a period that ended ``ok``, as the block does."""
    qdd, ok = forward_dynamics_aero(q, qd, u, m, loads, aero)
    if ok:
        for i in range(qdd.shape[0]):
            qdd_out[i] = qdd[i]
    return ok
