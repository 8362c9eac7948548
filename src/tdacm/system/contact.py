"""The contact scene of a built :class:`~tdacm.system.TDACM` (:mod:`tdacm.contact`).

:func:`contact_array` packs a :class:`~tdacm.contact.ContactModel` (its parameters and
obstacles) for the model's Magnus steps (the array the kernels ``forward_dynamics_env`` /
``rk4_run_env`` take); :func:`contact_state` evaluates the forces the kernels add, for the
logs, tests and figures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..contact import layout as CL
from ..contact.shapes import ContactModel
from . import kernels as K
from .tdacm import TDACM


def contact_array(system: TDACM, model: ContactModel, probe=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The packed contact array (:mod:`tdacm.contact.layout`) of ``model`` on ``system``: the
    header, the rod radius at every node step (a Gauss section or a tip body) and the
    obstacles' rows.  ``probe`` (m, tip frame): the tip sphere's centre on a rigid, massless
    probe ahead of the tip (:func:`probe_offset`; zero: the sphere at the tip, as without)."""
    if not isinstance(model, ContactModel):
        raise ValueError(f"model must be a ContactModel, got {model!r}")
    probe = np.asarray(probe, float)
    if probe.shape != (3,) or not np.all(np.isfinite(probe)):
        raise ValueError(f"probe must be a finite 3-vector (m, tip frame), got {probe!r}")
    m = system.model_arrays
    secs = system._sections
    radius = np.array([0.5 * secs[i].rod.diameter for i in system._step_sec])
    node = (m.step_load != K.LOAD_GRAVITY) & (m.step_w != 0.0)
    head = model.header()
    head[CL.TIP_RADIUS] = model.tip_radius
    head[CL.PROBE : CL.PROBE + 3] = probe
    rows = [o.row() for o in model.obstacles]
    return np.concatenate([head, np.where(node, radius, 0.0)] + rows)


def probe_offset(tip_mount, length: float) -> np.ndarray:
    """The tip sphere's centre in the tip frame for a rigid probe of ``length`` (m) along the
    optical axis of the tip camera mounted at ``tip_mount`` (``g_{C_L}^L``, 4x4): the camera's
    centre plus ``length`` along its z axis; zero for ``length = 0`` (the sphere at the tip,
    where the camera sits)."""
    if length == 0.0:
        return np.zeros(3)
    g = np.asarray(tip_mount, float)
    return g[:3, 3] + float(length) * g[:3, 2]


def check_contact(system: TDACM, contact) -> np.ndarray:
    """``contact`` as a float array, checked to be a packed array of ``system`` (the kernels
    read it without bounds checks)."""
    a = np.ascontiguousarray(contact, dtype=float)
    nst = system.model_arrays.h.shape[0]
    ok = a.ndim == 1 and a.shape[0] >= CL.N_HEADER + nst and np.all(np.isfinite(a))
    if ok:
        ok = a.shape[0] == CL.N_HEADER + nst + int(a[CL.N_SHAPES]) * CL.SHAPE_SIZE
    if not ok:
        raise ValueError(
            "contact must be the finite packed array of this system "
            f"(tdacm.system.contact.contact_array), got shape {a.shape}"
        )
    return a


@dataclass(frozen=True)
class ContactState:
    """The contact forces at one state (inertial frame, N): ``tip`` the tip sphere's,
    ``rod`` the sum over the backbone's capsules, ``points`` / ``forces`` per node (rod bases,
    Gauss points, tips), ``clearance`` the smallest gap of a node sphere to an obstacle (m,
    negative when penetrating), ``speed`` the fastest node's speed (m/s)."""

    tip: np.ndarray
    rod: np.ndarray
    points: np.ndarray
    forces: np.ndarray
    clearance: float
    speed: float

    @property
    def total(self) -> np.ndarray:
        return self.forces.sum(axis=0)


def contact_state(system: TDACM, q, qd, contact: np.ndarray) -> ContactState:
    """The contact forces of the packed ``contact`` at ``(q, qdot)``."""
    q, qd = (np.asarray(x, float) for x in (q, qd))
    contact = check_contact(system, contact)
    pts, f, tip, clear, speed = K.contact_nodes(q, qd, system.model_arrays, contact)
    return ContactState(tip, f.sum(axis=0) - tip, pts, f, float(clear), float(speed))


def contact_generalized_force(system: TDACM, q, qd, contact: np.ndarray) -> np.ndarray:
    """The generalized force (n,) the contact adds to ``tau_ext`` at ``(q, qdot)``."""
    q, qd = (np.asarray(x, float) for x in (q, qd))
    contact = check_contact(system, contact)
    m, loads = system.model_arrays, system.loads.packed()
    u = np.zeros(system.n_u)
    e = np.empty(0)
    with_c = K.coupled_terms_env(q, qd, m, loads, False, u, e, contact)[3]
    return with_c - K.coupled_terms(q, qd, m, loads, False)[3]
