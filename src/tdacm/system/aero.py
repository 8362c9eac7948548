"""The flight aerodynamics of a built :class:`~tdacm.system.TDACM` (:mod:`tdacm.aero`).

:func:`aero_array` packs an :class:`~tdacm.aero.Aerodynamics` record for the model's Magnus
steps (the array the kernels ``forward_dynamics_aero`` / ``rk4_run_aero`` take); the other
functions evaluate what the kernels add, for tests and figures.
"""

from __future__ import annotations

import numpy as np

from ..aero import layout as AL
from ..aero.params import Aerodynamics
from ..base import Quadrotor
from . import kernels as K
from .tdacm import TDACM


def aero_array(system: TDACM, aero: Aerodynamics | None = None, wind=(0.0, 0.0, 0.0)):
    """The packed aerodynamic array (:mod:`tdacm.aero.layout`) of ``aero`` (default:
    :class:`~tdacm.aero.Aerodynamics` ()) on ``system``, with a uniform ``wind`` (inertial, m/s;
    change it between calls with :func:`tdacm.aero.layout.set_wind`)."""
    aero = Aerodynamics() if aero is None else aero
    if not isinstance(aero, Aerodynamics):
        raise ValueError(f"aero must be an Aerodynamics, got {aero!r}")
    m = system.model_arrays
    nst = m.h.shape[0]
    out = np.zeros(AL.N_HEADER + 2 * nst)
    out[AL.RHO] = aero.air.density
    out[AL.MU] = aero.air.viscosity
    AL.set_wind(out, np.asarray(wind, float))
    w = aero.rotor
    arm = w.arm_length
    if arm is None:
        arm = system.base.arm_length if system.floating else Quadrotor.arm_length
    out[AL.WAKE_ON] = float(aero.wake)
    out[AL.RADIUS] = w.rotor_radius
    out[AL.SPREAD] = w.spreading_rate
    out[AL.DECAY] = w.decay_constant
    out[AL.CORE] = w.core_length * w.rotor_radius
    out[AL.ROTORS : AL.ROTORS + 12] = w.rotor_positions(arm).ravel()
    out[AL.THRUST : AL.THRUST + 4] = aero.fixed_thrusts
    d = aero.drag
    out[AL.CD] = d.rod_cd if d.rod_cd is not None else 0.0
    out[AL.CF] = d.rod_cf if d.rod_cf is not None else 0.0
    out[AL.TIP_CDA : AL.TIP_CDA + 3] = d.tip_cda
    out[AL.DRONE_D : AL.DRONE_D + 3] = d.drone_linear
    out[AL.DRONE_CDA : AL.DRONE_CDA + 3] = d.drone_cda
    out[AL.ROD_ON] = float(aero.rod_drag)
    out[AL.DRONE_ON] = float(aero.drone_drag)
    dist = m.step_load == K.LOAD_DISTRIBUTED
    secs = system._sections
    diam = np.array([secs[i].rod.diameter for i in system._step_sec])
    length = np.array([system.arms[secs[i].arm].length for i in system._step_sec])
    out[AL.N_HEADER : AL.N_HEADER + nst] = np.where(dist, diam, 0.0)
    out[AL.N_HEADER + nst :] = length
    return out


def check_aero(system: TDACM, aero) -> np.ndarray:
    """``aero`` as a float array, checked to be a packed array of ``system`` (the kernels read
    its per-step part without bounds checks)."""
    a = np.ascontiguousarray(aero, dtype=float)
    n = AL.N_HEADER + 2 * system.model_arrays.h.shape[0]
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(
            f"aero must be the finite packed array of this system, shape ({n},) "
            f"(tdacm.system.aero.aero_array), got shape {a.shape}"
        )
    return a


def aero_generalized_force(system: TDACM, q, qd, u, aero: np.ndarray) -> np.ndarray:
    """The generalized force (n,) the aerodynamics add to ``tau_ext`` at ``(q, qdot, u)``."""
    q, qd, u = (np.asarray(x, float) for x in (q, qd, u))
    aero = check_aero(system, aero)
    m, loads = system.model_arrays, system.loads.packed()
    with_air = K.coupled_terms_aero(q, qd, m, loads, False, u, aero)[3]
    without = K.coupled_terms(q, qd, m, loads, False)[3]
    return with_air - without


def section_air_loads(system: TDACM, q, qd, u, aero: np.ndarray, rod: int = 0):
    """Aerodynamic loads on rod ``rod`` at ``(q, qdot, u)``: ``(points, force_density, tip)``,
    the Gauss points (n_g, 3) and the force per metre (n_g, 3) there, and the tip body's force
    (3,), all in the inertial frame."""
    q, qd, u = (np.asarray(x, float) for x in (q, qd, u))
    aero = check_aero(system, aero)
    m = system.model_arrays
    poses, twists = K.chain_frames(q, qd, m, rod)
    gb = system.base_pose(q)
    rot = np.empty((AL.N_ROTORS, AL.ROTOR_STATE))
    wake = bool(aero[AL.WAKE_ON] > 0 and aero[AL.ROD_ON] > 0)
    ax, ay, az = K._rotor_setup(q, qd, u, m, gb, aero, rot) if wake else (0.0, 0.0, 0.0)
    lo = system._rod_steps[rod]
    nst = m.h.shape[0]
    pts, dens, tip = [], [], np.zeros(3)
    for i in range(poses.shape[0]):
        k = lo + i
        load = m.step_load[k]
        if load == K.LOAD_GRAVITY or aero[AL.ROD_ON] <= 0:
            continue
        f = np.array(
            K._air_on_body(
                poses[i], twists[i], k, load == K.LOAD_TIP, aero, nst, rot, ax, ay, az, wake
            )
        )
        f = poses[i, :3, :3] @ f
        if load == K.LOAD_TIP:
            tip = f
        else:
            pts.append(poses[i, :3, 3])
            dens.append(f)
    return np.array(pts).reshape(-1, 3), np.array(dens).reshape(-1, 3), tip
