"""Estimated dynamics for the model-based controller (paper, "Simulation Results").

The paper evaluates robustness with "a 10 % multiplicative perturbation to the nominal
inertia, Coriolis, damping and stiffness matrices". :class:`EstimatedModel` reproduces it
while keeping the structural properties the stability analysis needs
(``M_hat`` symmetric positive definite, ``Mdot_hat - 2 C_hat`` skew-symmetric,
``D_hat`` constant symmetric positive semidefinite):

* ``M_hat = S_M M S_M`` and ``C_hat = S_M C S_M`` with ``S_M = diag(sqrt(1 + d_i))``,
  ``d_i ~ U(-level, level)``: every diagonal entry of ``M`` is scaled by exactly ``1 + d_i``
  and every off-diagonal entry by ``sqrt((1 + d_i)(1 + d_j))``, both within ``+-level``.
  Using the same congruence for ``C`` keeps ``Mdot_hat - 2 C_hat = S (Mdot - 2C) S`` skew.
* ``D_hat = S_D D S_D`` (another draw), ``K_hat = (1 + d_K) * K`` elementwise.
* Gravity: the paper lumps ``tau_ext`` (gravity included) into the uncertainty ``Delta``.
  Learning a 7.5 N weight from ``Delta_hat = 0`` is a needless transient, so by default the
  controller feeds forward the *estimated* gravity load (the nominal one scaled per
  coordinate by ``1 + d_g``) as part of ``K_hat`` (the potential forces); set
  ``gravity_feedforward=False`` for the paper's literal choice. Disturbances (base wrench,
  downwash) are never known to the controller: they are in ``Delta``.
* Rotor drag (optional, ``rotor_drag``): a drone's rotors drag it in proportion to its velocity
  in the body frame, ``F_b = -diag(k_r) v_b`` (Faessler, Franchi & Scaramuzza 2018), a property
  of the drone the user can identify like its mass. Given its coefficients, the model adds the
  generalized damping ``R diag(k_r_hat) R^T`` on the drone's position rows to ``D_hat``, with
  ``k_r_hat = (1 + d_r) k_r`` (its own draw), and stays symmetric positive semidefinite (it is
  no longer constant: it turns with the drone). The air's motion (wind, gusts) stays unknown.

The estimated terms are computed on a private copy of the model with gravity only, so the
plant's loads (disturbances) never leak into the controller.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from ..lie.euler import rot_zyx
from ..system.kernels import coupled_terms
from ..system.tdacm import TDACM, Loads
from .config import ModelConfig


@dataclass(frozen=True)
class EstimatedTerms:
    """``M_hat, C_hat, D_hat`` (n x n) and ``K_hat`` (n,: elastic + estimated gravity)."""

    M: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray


class EstimatedModel:
    """The controller's (perturbed) model of a :class:`~tdacm.system.tdacm.TDACM`.

    Parameters
    ----------
    system:
        The true system (only its structure and parameters are copied).
    level:
        Multiplicative perturbation bound (the paper's 0.1); 0 gives the nominal model.
    seed:
        Seed of the perturbation draw (reproducible).
    gravity_feedforward:
        Include the estimated gravity load in ``K_hat`` (see module docstring).
    rotor_drag:
        The drone's linear rotor drag along its body axes ``(k_x, k_y, k_z)`` (N s/m) for the
        model to know (see module docstring); ``None`` (default): no drag in the model.
    """

    def __init__(
        self,
        system: TDACM,
        level: float = ModelConfig().perturbation,
        seed: int = 0,
        gravity_feedforward: bool = ModelConfig().gravity_feedforward,
        rotor_drag=None,
    ):
        if not isinstance(system, TDACM):
            raise ValueError(f"system must be a TDACM, got {system!r}")
        level = float(level)
        if not (0.0 <= level < 1.0):
            raise ValueError(f"perturbation level must lie in [0, 1), got {level!r}")
        self.level = level
        self.seed = int(seed)
        self.gravity_feedforward = bool(gravity_feedforward)
        self.nominal_rotor_drag = None
        if rotor_drag is not None:
            k = np.asarray(rotor_drag, dtype=float)
            if k.shape != (3,) or not np.all(np.isfinite(k)) or np.any(k < 0):
                raise ValueError(f"rotor_drag must be 3 finite values >= 0, got {rotor_drag!r}")
            if not system.floating:
                raise ValueError("rotor_drag needs a floating base (a drone)")
            self.nominal_rotor_drag = k
        # private model with gravity only (no disturbances)
        arms = system.arms
        one = len(arms) == 1  # several arms: the lists of rods, tendons and attachments
        self.system = TDACM(
            arms[0].rod if one else [a.rod for a in arms],
            arms[0].tendons if one else [a.tendons for a in arms],
            system.base,
            arms[0].attachment if one else [a.attachment for a in arms],
            Loads(gravity=system.loads.gravity.copy()),
        )
        self.n = system.n
        self.reseed(self.seed)

    def reseed(self, seed: int) -> None:
        """Draw the parameter errors of ``seed`` (what a model built with that seed has)."""
        self.seed = int(seed)
        #: counts the draws: the holders of a snapshot of them (the controller's record) renew it
        self.revision = getattr(self, "revision", -1) + 1
        n, level = self.n, self.level
        rng = np.random.default_rng(self.seed)
        draw = lambda: rng.uniform(-level, level, n)  # noqa: E731
        self.d_m, self.d_d, self.d_k, self.d_g = draw(), draw(), draw(), draw()
        # M_hat = S_m M S_m, D_hat = S_d D S_d with S = diag(sqrt(1 + d)): symmetric and
        # positive definite like the true matrices
        self.mass_scale = np.sqrt(1.0 + self.d_m)
        self.damping_scale = np.sqrt(1.0 + self.d_d)
        # K_hat = (1 + d_K) (K q) - (1 + d_g) tau_grav: the factors every holder of the model
        # (the controller's and the filter's records, :meth:`terms`) takes from here
        self.stiffness_scale = 1.0 + self.d_k
        self.gravity_scale = 1.0 + self.d_g
        # drawn after the others so that knowing the drag leaves their draws unchanged
        self.d_r = rng.uniform(-level, level, 3)
        self.rotor_drag = (
            np.zeros(3)
            if self.nominal_rotor_drag is None
            else (1.0 + self.d_r) * self.nominal_rotor_drag
        )

    @property
    def knows_rotor_drag(self) -> bool:
        return self.nominal_rotor_drag is not None

    @property
    def damping_hat(self) -> np.ndarray:
        """The constant part of ``D_hat``: ``S_D D S_D`` (n x n)."""
        sd = self.damping_scale
        d = self.system.model_arrays.damping
        return np.ascontiguousarray(sd[:, None] * d * sd[None, :])

    def rotor_damping(self, q) -> np.ndarray:
        """The estimated rotor drag's generalized damping on the drone's position rows,
        ``R diag(k_r_hat) R^T`` (3 x 3), at the attitude of ``q``."""
        out = np.empty((3, 3))
        rotor_damping_into(np.asarray(q, float), self.rotor_drag, out)
        return out

    def terms(self, q, qd) -> EstimatedTerms:
        """Estimated ``M, C, D, K`` at ``(q, qdot)`` (:func:`estimated_terms`)."""
        q = np.ascontiguousarray(q, dtype=float)
        qd = np.ascontiguousarray(qd, dtype=float)
        n = self.n
        m_hat, c_hat, d_hat = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
        k_hat = np.empty(n)
        estimated_terms(
            q, qd, self.system.model_arrays, self.system.loads.packed(), self.mass_scale,
            self.damping_hat, self.stiffness_scale, self.gravity_scale, self.gravity_feedforward,
            self.knows_rotor_drag, self.rotor_drag, False, m_hat, c_hat, d_hat, k_hat,
        )  # fmt: skip
        return EstimatedTerms(m_hat, c_hat, d_hat, k_hat)

    def true_terms(self, q, qd):
        """The nominal (unperturbed) terms of the private model."""
        return self.system.terms(q, qd)


class ModelParams(NamedTuple):
    """The estimated model as a record for compiled steps (:func:`model_params`), besides the
    model arrays of its private gravity-only system (passed apart, shared by a batch): its
    packed ``loads`` (27,), ``mass_scale`` ``S_M`` (n,), ``damping`` ``D_hat = S_D D S_D``
    (n, n), ``stiffness_scale`` ``1 + d_K`` and ``gravity_scale`` ``1 + d_g`` (n,),
    ``gravity_feedforward``, ``rotor_drag`` (whether it knows the drone's rotor drag) and
    ``rotor_drag_k`` ``k_r_hat`` (3,)."""

    loads: np.ndarray
    mass_scale: np.ndarray
    damping: np.ndarray
    stiffness_scale: np.ndarray
    gravity_scale: np.ndarray
    gravity_feedforward: bool
    rotor_drag: bool
    rotor_drag_k: np.ndarray


def model_params(model: EstimatedModel) -> ModelParams:
    """The record of ``model``'s current draw (after ``reseed``, take it again: ``revision``)."""
    c = np.ascontiguousarray
    return ModelParams(
        loads=model.system.loads.packed().copy(),
        mass_scale=c(model.mass_scale, float),
        damping=model.damping_hat,
        stiffness_scale=c(model.stiffness_scale),
        gravity_scale=c(model.gravity_scale),
        gravity_feedforward=bool(model.gravity_feedforward),
        rotor_drag=model.knows_rotor_drag,
        rotor_drag_k=c(model.rotor_drag, float),
    )


@njit(cache=True)
def model_terms_into(mp, m, q, qd, m_hat, c_hat, d_hat, k_hat):
    """``M_hat, C_hat, D_hat, K_hat`` at ``(q, qdot)`` (:meth:`EstimatedModel.terms`) of the
    record ``mp`` (:class:`ModelParams`) on the private model's arrays ``m``."""
    estimated_terms(q, qd, m, mp.loads, mp.mass_scale, mp.damping, mp.stiffness_scale,
                    mp.gravity_scale, mp.gravity_feedforward, mp.rotor_drag, mp.rotor_drag_k,
                    False, m_hat, c_hat, d_hat, k_hat)  # fmt: skip


@njit(cache=True)
def rotor_damping_into(q, k_r, out):
    """``R diag(k_r) R^T`` (3 x 3) into ``out``: the rotor drag's generalized damping on the
    drone's position rows at the attitude of ``q`` (``R = Rz Ry Rx``)."""
    r = rot_zyx(q[0], q[1], q[2])
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for c in range(3):
                acc += r[i, c] * k_r[c] * r[j, c]
            out[i, j] = acc


@njit(cache=True)
def estimated_terms(q, qd, m, loads, mass_scale, damping, stiffness_scale, gravity_scale,
                    gravity_ff, rotor_drag, k_r, add_damping, m_hat, c_hat, d_hat, k_hat):  # fmt: skip
    """The estimated terms (module docstring) at ``(q, qdot)`` on the private model's arrays
    ``m`` and packed loads ``loads``: ``M_hat = S_m M S_m``, ``C_hat = S_m C S_m``,
    ``D_hat = damping`` (``S_D D S_D``) plus ``R diag(k_r_hat) R^T`` on the drone's position
    rows when the model knows the rotor drag, ``K_hat = (1 + d_K) K`` minus
    ``(1 + d_g) tau_ext`` with the gravity feed-forward, into ``m_hat, c_hat, d_hat, k_hat``.
    With ``add_damping``, ``c_hat`` receives ``C_hat + D_hat`` (what the adaptive law
    multiplies ``qdot_r`` by) and ``d_hat`` is left alone."""
    n = q.shape[0]
    mm, cc, _, tau_ext, _, _, _ = coupled_terms(q, qd, m, loads, bool(1))  # a variable: one compile
    for i in range(n):
        for j in range(n):
            m_hat[i, j] = mass_scale[i] * mm[i, j] * mass_scale[j]
            c_hat[i, j] = mass_scale[i] * cc[i, j] * mass_scale[j]
    if add_damping:
        for i in range(n):
            for j in range(n):
                if not (rotor_drag and 3 <= i < 6 and 3 <= j < 6):
                    c_hat[i, j] = c_hat[i, j] + damping[i, j]
    else:
        for i in range(n):
            for j in range(n):
                d_hat[i, j] = damping[i, j]
    if rotor_drag:  # on the drone's position rows: D_hat + R diag(k_r) R^T
        rd = np.empty((3, 3))
        rotor_damping_into(q, k_r, rd)
        for i in range(3):
            for j in range(3):
                if add_damping:
                    c_hat[3 + i, 3 + j] = c_hat[3 + i, 3 + j] + (damping[3 + i, 3 + j] + rd[i, j])
                else:
                    d_hat[3 + i, 3 + j] = d_hat[3 + i, 3 + j] + rd[i, j]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += m.stiffness[i, j] * q[j]
        k_hat[i] = stiffness_scale[i] * acc
        if gravity_ff:
            k_hat[i] = k_hat[i] - gravity_scale[i] * tau_ext[i]
