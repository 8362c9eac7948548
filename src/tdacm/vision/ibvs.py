"""IBVS law with the advanced features (paper, eq. (39)).

    v_{C_V}^{C_V} = -lambda J_img^-1 e_{p*},     e_{p*} = p* - p*_d

The twist is the camera's (virtual camera C_V's) velocity expressed in its own frame,
**angular-first** ``[w; v]`` like every twist of the model (``order="linear_first"`` returns
``[v; w]``). ``J_img`` is :func:`~.features.feature_interaction_matrix` evaluated at

* ``"current"``: the current points and depths (default; the choice that converges from
  yaw errors near 180 degrees),
* ``"desired"``: the desired points and depths (constant, computed once),
* ``"mean"``: ``(J(current) + J(desired)) / 2`` (Malis' choice, good local behaviour).

The 6 x 6 system is solved directly; if ``J_img`` is (nearly) singular the least-squares
solution (pseudo-inverse) is used.
"""

from __future__ import annotations

import numpy as np

from . import _checks as C
from .features import advanced_features, feature_interaction_matrix, wrap_angle

MODES = ("current", "desired", "mean")


def ibvs_twist(error, interaction, gain: float = 0.5) -> np.ndarray:
    """``v = -gain J_img^-1 e`` (paper eq. (39)).

    The twist has the column order of ``interaction``: ``[w; v]`` for the (default)
    angular-first matrices of :func:`~.features.feature_interaction_matrix`.
    """
    e = C.array("error", error, (6,))
    jac = C.array("interaction", interaction, (6, 6))
    lam = C.positive("gain", gain)
    return -lam * _solve(jac, e)


def _solve(jac: np.ndarray, e: np.ndarray) -> np.ndarray:
    try:
        x = np.linalg.solve(jac, e)
        if np.all(np.isfinite(x)) and np.abs(x).max() < 1e8 * (1.0 + np.abs(e).max()):
            return x
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(jac, e, rcond=1e-10)[0]


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
        ``lambda > 0``.
    mode:
        ``"current"``, ``"desired"`` or ``"mean"`` (see module docstring).
    order:
        Twist ordering of :meth:`twist`'s output: ``"angular_first"`` (``[w; v]``, default)
        or ``"linear_first"`` (``[v; w]``).
    """

    def __init__(
        self,
        desired_points,
        desired_depths,
        gain: float = 0.5,
        mode: str = "current",
        order: str = "angular_first",
    ):
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

    def error(self, points) -> np.ndarray:
        """Feature error ``p* - p*_d`` (angles wrapped)."""
        e = advanced_features(points) - self.desired
        e[:3] = wrap_angle(e[:3])
        return e

    def interaction(self, points, depths) -> np.ndarray:
        """``J_img`` used by the law for the current points/depths (angular-first)."""
        if self.mode == "desired":
            return self.interaction_desired
        cur = feature_interaction_matrix(points, depths)
        if self.mode == "current":
            return cur
        return 0.5 * (cur + self.interaction_desired)

    def twist(self, points, depths=None) -> np.ndarray:
        """Camera twist (paper eq. (39)) for the current normalized points ``(4, 2)``.

        ``depths`` may be omitted in ``"desired"`` mode."""
        e = self.error(points)
        if depths is None:
            if self.mode != "desired":
                raise ValueError("depths are required unless mode == 'desired'")
            depths = self.desired_depths
        v = -self.gain * _solve(self.interaction(points, depths), e)
        if self.order == "linear_first":
            return np.concatenate((v[3:], v[:3]))
        return v
