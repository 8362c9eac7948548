"""IBVS law with the advanced features (paper, eq. (39)).

    v_{C_V}^{C_V} = -lambda J_img^-1 e_{p*},     e_{p*} = p* - p*_d

The twist is the camera's (virtual camera C_V's) velocity expressed in its own frame,
**angular-first** ``[w; v]`` like every twist of the model (``order="linear_first"`` returns
``[v; w]``). ``J_img`` is :func:`~.features.feature_interaction_matrix` evaluated at

* ``"current"``: the current points and depths (default; the choice that converges from
  yaw errors near 180 degrees),
* ``"desired"``: the desired points and depths (constant, computed once),
* ``"mean"``: ``(J(current) + J(desired)) / 2`` (Malis' choice, good local behaviour).

With ``floor = 0`` (the paper's law) the 6 x 6 system is solved directly; if ``J_img`` is
(nearly) singular the least-squares solution (pseudo-inverse) is used.

Well-conditioned solve (``floor > 0``, :func:`robust_solve`). For a 20 cm marker seen from
1.5-3.5 m, ``J_img`` has two singular values 30-60x below the others (rotation about the
camera x axis coupled with translation along y, and about y with x): ``J_img^-1`` multiplies
any feature noise along those directions by 1/sigma_min ~ 30-50. With the SVD
``J_img = U diag(sigma) V^T``,

* ``solver="floor"``: ``v = -lambda V diag(1 / max(sigma_i, floor)) U^T e`` - the exact
  inverse in every direction with ``sigma_i >= floor``, the amplification capped at
  ``1/floor`` in the others;
* ``solver="damped"``: damped least squares, ``v = -lambda V diag(sigma_i / (sigma_i^2 +
  floor^2)) U^T e``.

In both, ``J_img J_img^+ = U diag(d_i) U^T`` with ``0 < d_i <= 1`` (``d_i = min(1,
sigma_i/floor)`` or ``sigma_i^2/(sigma_i^2 + floor^2)``), so the ideal closed loop
``e_dot = -lambda U diag(d_i) U^T e`` still decreases ``|e|`` exponentially with rate at least
``lambda min_i d_i`` (docs/control.md, "Robust servo"): no direction is left free, the weak
ones are driven more slowly.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._linalg import SVD_DAMPED, SVD_FLOOR, svd_solve
from . import _checks as C
from .features import (
    _features_kernel,
    _interaction_kernel,
    _wrap,
    advanced_features,
    checked_view,
    feature_interaction_matrix,
    min_edge2_of,
    wrap_angle,
)

MODES = ("current", "desired", "mean")
SOLVERS = ("floor", "damped")
#: the default interaction matrix and solve (also the scenario's ``[ibvs]`` mode and solver)
DEFAULT_MODE, DEFAULT_SOLVER = "current", "floor"
#: the view passed to :func:`law_interaction` in ``"desired"`` mode, where it is not read
_UNREAD_VIEW = (np.zeros((4, 2)), np.ones(4))


def robust_solve(interaction, error, floor: float, solver: str = DEFAULT_SOLVER) -> np.ndarray:
    """``J^+ e`` with the small singular values of ``J`` floored (``solver="floor"``) or
    damped (``"damped"``) at ``floor`` (module docstring). ``floor = 0``: the plain solve."""
    jac = C.array("interaction", interaction, (6, 6))
    e = C.array("error", error, (6,))
    return _robust_solve(jac, e, floor, solver)


def _robust_solve(jac: np.ndarray, e: np.ndarray, floor: float, solver: str) -> np.ndarray:
    """:func:`robust_solve` on a checked ``(6, 6)`` matrix and ``(6,)`` error (the IBVS
    controller's own arrays, every period)."""
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    floor = float(floor)
    if not np.isfinite(floor) or floor < 0:
        raise ValueError(f"floor must be >= 0, got {floor!r}")
    return ibvs_solve(np.ascontiguousarray(jac), np.ascontiguousarray(e), floor, solver == "damped")


@njit(cache=True)
def plain_solve(jac, e):
    """``J^-1 e`` with the least-squares fallback when ``J`` is singular or the solution
    explodes (the paper's plain solve, ``floor = 0``)."""
    ok = True
    x = np.zeros(e.shape[0])
    try:
        x = np.linalg.solve(jac, e)
    except Exception:  # noqa: BLE001 - numba raises on a singular matrix
        ok = False
    if ok:
        big = 0.0
        emax = 0.0
        for i in range(e.shape[0]):
            if not np.isfinite(x[i]):
                ok = False
            big = max(big, abs(x[i]))
            emax = max(emax, abs(e[i]))
        if ok and big < 1e8 * (1.0 + emax):
            return x
    return np.linalg.lstsq(jac, e, rcond=1e-10)[0]


@njit(cache=True)
def ibvs_solve(jac, e, floor, damped):
    """``J^+ e`` (:func:`robust_solve`): floored (or damped) singular values for ``floor > 0``,
    the plain solve for ``floor = 0``."""
    if floor == 0.0:
        return plain_solve(jac, e)
    return svd_solve(jac, e, SVD_DAMPED if damped else SVD_FLOOR, floor)


@njit(cache=True)
def ibvs_law(p, z, desired, interaction_desired, mode, gain, floor, damped):
    """Features, error and twist of the law (paper eqs. (19)-(21), (39)) for checked points
    ``p`` (4, 2) and positive depths ``z`` (4,) in one call: ``mode`` 0 / 1 / 2 for
    ``"current"`` / ``"desired"`` / ``"mean"``, the solve of :func:`ibvs_solve` (``floor > 0``
    with ``damped`` False / True for the ``"floor"`` / ``"damped"`` solve, ``floor = 0`` the
    paper's plain solve)."""
    f = _features_kernel(p)
    e = f - desired
    for i in range(3):
        e[i] = _wrap(e[i])
    return f, e, ibvs_twist_of(p, z, e, interaction_desired, mode, gain, floor, damped)


@njit(cache=True)
def law_interaction(p, z, interaction_desired, mode):
    """``J_img`` (6, 6) the law uses at the checked points ``p`` (4, 2) and depths ``z`` (4,)
    (:meth:`IBVSController.interaction`; :func:`ibvs_law`'s ``mode``): the desired view's
    ``interaction_desired``, the current one, or their mean (a new array)."""
    if mode == 1:
        return interaction_desired.copy()
    if mode == 0:
        return _interaction_kernel(p, z)
    return 0.5 * (_interaction_kernel(p, z) + interaction_desired)


@njit(cache=True)
def ibvs_twist_of(p, z, e, interaction_desired, mode, gain, floor, damped):
    """The law's twist ``v = -gain J_img^+ e`` (paper eq. (39)) for a given feature error
    ``e`` (6,) at the checked points ``p`` (4, 2) and depths ``z`` (4,) (:func:`ibvs_law`'s
    ``mode``, ``floor`` and ``damped``): the servo's twist on an error it composed itself."""
    x = ibvs_solve(law_interaction(p, z, interaction_desired, mode), e, floor, damped)
    v = np.empty(6)
    for k in range(6):
        v[k] = -gain * x[k]
    return v


def ibvs_twist(
    error, interaction, *, gain: float, floor: float, solver: str = DEFAULT_SOLVER
) -> np.ndarray:
    """``v = -gain J_img^-1 e`` (paper eq. (39)); with ``floor > 0`` the well-conditioned
    solve of :func:`robust_solve`.

    The twist has the column order of ``interaction``: ``[w; v]`` for the (default)
    angular-first matrices of :func:`~.features.feature_interaction_matrix`.
    """
    lam = C.positive("gain", gain)
    return -lam * robust_solve(interaction, error, floor, solver)


class IBVSController:
    """Advanced-feature IBVS for one desired view.

    Parameters
    ----------
    desired_points:
        Normalized image points ``(4, 2)`` of the reference snapshot (paper order).
    desired_depths:
        Their depths (``(4,)`` or a scalar), needed by the ``"desired"`` and ``"mean"``
        interaction matrices.
    gain:
        ``lambda > 0`` (``[ibvs] gain`` in a scenario).
    mode:
        ``"current"``, ``"desired"`` or ``"mean"`` (see module docstring).
    order:
        Twist ordering of :meth:`twist`'s output: ``"angular_first"`` (``[w; v]``, default)
        or ``"linear_first"`` (``[v; w]``).
    floor, solver:
        Singular-value floor of the solve and its kind (:func:`robust_solve`); ``floor = 0``
        is the paper's plain ``J_img^-1`` (``[ibvs] floor`` in a scenario).
    """

    def __init__(
        self,
        desired_points,
        desired_depths,
        *,
        gain: float,
        floor: float,
        mode: str = DEFAULT_MODE,
        order: str = "angular_first",
        solver: str = DEFAULT_SOLVER,
    ):
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if not np.isfinite(floor) or floor < 0:
            raise ValueError(f"floor must be >= 0, got {floor!r}")
        self.floor = float(floor)
        self.solver = solver
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if order not in ("angular_first", "linear_first"):
            raise ValueError(f"order must be 'angular_first' or 'linear_first', got {order!r}")
        self.desired_points = C.array("desired_points", desired_points, (4, 2))
        self.desired = advanced_features(self.desired_points)
        self.desired_depths = desired_depths
        self.gain = C.positive("gain", gain)
        self.mode = mode
        self.order = order
        self.interaction_desired = feature_interaction_matrix(self.desired_points, desired_depths)
        self._mode_code = MODES.index(mode)

    def features_error_twist(self, points, depths):
        """``(features, error, twist)`` of checked points ``(4, 2)`` and depths ``(4,)`` (the
        predictive servo's every period; :func:`ibvs_law` when ``floor > 0``, angular-first
        twist)."""
        if self.order == "angular_first":
            if min_edge2_of(points) < 1e-24:
                raise ValueError("points must be four distinct corners (an edge has zero length)")
            return ibvs_law(
                points, depths, self.desired, self.interaction_desired, self._mode_code,
                self.gain, self.floor, self.solver == "damped",
            )  # fmt: skip
        f = advanced_features(points)
        e = self.error(points, features=f)
        return f, e, self.twist(points, depths, error=e)

    def error(self, points, features=None) -> np.ndarray:
        """Feature error ``p* - p*_d`` (angles wrapped); ``features``: the points' advanced
        features if the caller has them already (not recomputed)."""
        f = advanced_features(points) if features is None else features
        e = f - self.desired
        e[:3] = wrap_angle(e[:3])
        return e

    def interaction(self, points, depths) -> np.ndarray:
        """``J_img`` used by the law for the current points/depths (angular-first, a new
        array): the compiled :func:`law_interaction` of the law's steps on the checked view
        (not read in ``"desired"`` mode)."""
        p, z = _UNREAD_VIEW if self.mode == "desired" else checked_view(points, depths)
        return law_interaction(p, z, self.interaction_desired, self._mode_code)

    def twist(self, points, depths=None, error=None) -> np.ndarray:
        """Camera twist (paper eq. (39)) for the current normalized points ``(4, 2)``.

        ``depths`` may be omitted in ``"desired"`` mode; ``error``: :meth:`error` of the
        points if the caller has it already (not recomputed)."""
        e = self.error(points) if error is None else error
        if depths is None:
            if self.mode != "desired":
                raise ValueError("depths are required unless mode == 'desired'")
            depths = self.desired_depths
        jac = self.interaction(points, depths)  # (6, 6), from the features kernel
        v = -self.gain * _robust_solve(jac, e, self.floor, self.solver)
        if self.order == "linear_first":
            return np.concatenate((v[3:], v[:3]))
        return v
