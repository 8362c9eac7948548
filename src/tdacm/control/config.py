"""Parameter records of the low-level controller: its law (the adaptive law, the drone loop and
the allocation of :class:`~tdacm.control.TDACMController`), the keys of the scenario's
``[controller]`` section that the law reads, and its model of the robot (:class:`ModelConfig`,
section ``[model]``, whose defaults :class:`~tdacm.control.EstimatedModel` takes). The loop's
``[controller]`` record (:class:`tdacm.loop.config.ControllerConfig`) extends the law's;
:class:`TDACMController` and :func:`~tdacm.control.default_gains` take it whole.

The adaptive law's diagonal gains come in three rates per group of coordinates: ``beta`` of the
sliding variable ``s_q = edot + beta e`` (``*_position_rate``, 1/s), the damping rate of
``A_d = S M0 S`` with ``S = diag(sqrt(rate))`` (``*_damping_rate``, 1/s) and the adaptation rate
of ``A_a`` (``*_adaptation_rate``), for the groups ``tilt`` (the drone's roll and pitch),
``yaw``, ``horizontal`` (x, y), ``vertical`` (z) and ``strain`` (the rod's strains; a held base
has these only); :func:`~tdacm.control.default_gains` scales them by the effective inertia.
"""

from __future__ import annotations

import math

from pydantic import create_model

from .._config import ConfigModel, Field

#: The gains' rates (1/s) per kind and coordinate group (``*_position_rate`` is ``beta``); a
#: floating base's coordinates ``[roll, pitch, yaw, x, y, z, strains]`` are the groups
#: ``tilt, tilt, yaw, horizontal, horizontal, vertical, strain...``.
RATES = {
    "position": {"tilt": 6.0, "yaw": 3.0, "horizontal": 1.2, "vertical": 1.5, "strain": 6.0},
    "damping": {"tilt": 16.0, "yaw": 8.0, "horizontal": 1.5, "vertical": 4.0, "strain": 25.0},
    "adaptation": {"tilt": 20.0, "yaw": 8.0, "horizontal": 1.5, "vertical": 3.0, "strain": 20.0},
}
_KIND = {
    "position": "beta in s_q = edot + beta e",
    "damping": "damping rate of A_d",
    "adaptation": "adaptation rate of A_a",
}
_GROUP = {
    "tilt": "the drone's roll and pitch",
    "yaw": "the drone's yaw",
    "horizontal": "the drone's x and y",
    "vertical": "the drone's z",
    "strain": "the rod's strains",
}
_NOTE = {
    ("position", "horizontal"): ": a slow error b of the horizontal velocity estimate leaves "
    "the drone b / beta from its reference",
    ("damping", "horizontal"): " (low: the velocity is an estimate, docs/control.md)",
}


class _LawKeys(ConfigModel):
    pretension: float = Field(0.5, ge=0, description="N, minimum tendon tension")
    max_tilt: float = Field(
        0.35, gt=0, lt=math.pi / 2, description="rad, limit of the commanded drone tilt"
    )
    attitude_filter: float = Field(
        0.05, ge=0, description="s, time constant of the commanded-attitude filter"
    )
    max_tilt_rate: float = Field(1.5, ge=0, description="rad/s, limit of the commanded tilt rate")
    min_lift: float = Field(
        0.8, ge=0, description="least vertical part of the desired force, a fraction of the weight"
    )

    def rates(self, kind: str, floating: bool, n_s: int) -> list[float]:
        """The ``kind`` rate (``"position"``, ``"damping"`` or ``"adaptation"``) of every
        coordinate: ``[roll, pitch, yaw, x, y, z, strains...]`` for a floating base, the
        strains only for a held one."""
        g = {k: getattr(self, f"{k}_{kind}_rate") for k in _GROUP}
        drone = [g["tilt"], g["tilt"], g["yaw"], g["horizontal"], g["horizontal"], g["vertical"]]
        return (drone if floating else []) + [g["strain"]] * n_s


ControlLawConfig = create_model(
    "ControlLawConfig",
    __base__=_LawKeys,
    __doc__="The ``[controller]`` keys of the adaptive law (docs/control.md).",
    **{
        f"{group}_{kind}_rate": (
            float,
            Field(
                rate,
                gt=0,
                description=f"1/s, {_KIND[kind]} of {_GROUP[group]}{_NOTE.get((kind, group), '')}",
            ),
        )
        for kind, groups in RATES.items()
        for group, rate in groups.items()
    },
)


#: the defaults (a controller built without a scenario)
LAW_DEFAULTS = ControlLawConfig()


class ModelConfig(ConfigModel):
    """Section ``[model]``: the controller's model of the robot."""

    perturbation: float = Field(
        0.1, ge=0, lt=1, description="relative std of the model's parameter errors, in [0, 1)"
    )
    gravity_feedforward: bool = Field(
        True, description="compensate gravity with the model (false: lumped into Delta_hat)"
    )
    rotor_drag: bool = Field(
        True,
        description="with [aerodynamics] drone drag on, the model (controller and EKF) knows the "
        "drone's linear rotor drag (drone_linear, perturbed like D); false: lumped into Delta_hat",
    )
