"""A PD + gravity controller: the simplest alternative to the paper's adaptive law.

    tau = K_hat(q) + M_hat(q) qdd_d - A_d (qdot - qdot_d) - A_p (q - q_d)

with ``K_hat`` the controller's estimated elastic and gravity load (the perturbed model of
:class:`~.model.EstimatedModel`) and the inertia-scaled gains of :func:`~.hierarchical.default_gains`. It has
no adaptation and no Coriolis feed-forward, so with a 10 % model error it leaves a steady-state
joint error (``A_p^-1`` times the load error), which the visual loop absorbs by integrating the
image error into ``q_d`` (paper-in-fov: final RMSE 0.0045 against 0.0039 with the adaptive
law); it shares the hierarchical drone loop and the allocation with the adaptive controller:
the law is :data:`~.hierarchical.LAW_PD` of the controller's compiled step
(:func:`~.hierarchical.controller_step`). Use it in a scenario with
``controller.class = "tdacm.loop.lowlevel:PDGravityController"`` (the low-level block with this
law in place of the adaptive one), or from Python as
``TDACMController(system, model, gains, kind=LAW_PD)``.
"""

from __future__ import annotations

from .hierarchical import LAW_PD

__all__ = ["LAW_PD"]
