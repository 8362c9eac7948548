"""A PD + gravity controller: the simplest alternative to the paper's adaptive law.

    tau = K_hat(q) + M_hat(q) qdd_d - A_d (qdot - qdot_d) - A_p (q - q_d)

with ``K_hat`` the controller's estimated elastic and gravity load (the perturbed model of
:class:`~.model.EstimatedModel`) and the inertia-scaled gains of :func:`~.hierarchical.default_gains`. It has
no adaptation and no Coriolis feed-forward, so with a 10 % model error it leaves a steady-state
joint error (``A_p^-1`` times the load error), which the visual loop absorbs by integrating the
image error into ``q_d`` (paper-in-fov: final RMSE 0.0045 against 0.0039 with the adaptive
law); it shares the hierarchical drone loop and the
allocation with the adaptive controller. Use it in a scenario with
``controller.class = "tdacm.loop.lowlevel:PDGravityController"`` (the low-level block with this
law in place of the adaptive one).
"""

from __future__ import annotations

import numpy as np

from .adaptive import AdaptiveOutput


class PDGravityLaw:
    """The PD + gravity law with the interface :class:`~.hierarchical.TDACMController` expects
    of a law."""

    def __init__(self, model, gains):
        self.model = model
        self.gains = gains
        self.n = model.n
        self.delta_hat = np.zeros(self.n)

    def reset(self, delta0=None) -> None:
        pass

    def law(self, q, qd, q_d, qd_d, qdd_d, terms=None) -> AdaptiveOutput:
        g = self.gains
        t = self.model.terms(q, qd) if terms is None else terms
        e = np.asarray(q, float) - q_d
        edot = np.asarray(qd, float) - qd_d
        tau = t.K + t.M @ qdd_d - g.A_d @ edot - g.A_p @ e
        s = edot + g.beta * e
        v = 0.5 * edot @ t.M @ edot + 0.5 * e @ g.A_p @ e
        return AdaptiveOutput(tau, e, edot, s, np.asarray(qd_d), np.asarray(qdd_d), float(v))

    def adapt(self, s, dt: float) -> None:
        pass
