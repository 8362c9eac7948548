"""Parameter record of the low-level controller's law (the adaptive law, the drone loop and the
allocation of :class:`~tdacm.control.TDACMController`): the keys of the scenario's
``[controller]`` section that the law reads. The loop's ``[controller]`` record
(:class:`tdacm.loop.config.ControllerConfig`) extends it; :class:`TDACMController` and
:func:`~tdacm.control.default_gains` take it whole.

The adaptive law's diagonal gains come in three rates per group of coordinates: ``beta`` of the
sliding variable ``s_q = edot + beta e`` (``*_position_rate``, 1/s), the damping rate of
``A_d = S M0 S`` with ``S = diag(sqrt(rate))`` (``*_damping_rate``, 1/s) and the adaptation rate
of ``A_a`` (``*_adaptation_rate``), for the groups ``tilt`` (the drone's roll and pitch),
``yaw``, ``horizontal`` (x, y), ``vertical`` (z) and ``strain`` (the rod's strains; a held base
has these only); :func:`~tdacm.control.default_gains` scales them by the effective inertia.
"""

from __future__ import annotations

import math

from .._config import ConfigModel, Field

#: the coordinate groups of the gains, in the order of a floating base's q (strains last)
GAIN_GROUPS = ("tilt", "yaw", "horizontal", "vertical", "strain")


def _rate(default: float, what: str, group: str):
    return Field(default, gt=0, description=f"1/s, {what} of the {group}")


_TILT, _YAW, _HOR, _VER, _STR = (
    "drone's roll and pitch",
    "drone's yaw",
    "drone's x and y",
    "drone's z",
    "rod's strains",
)


class ControlLawConfig(ConfigModel):
    """The ``[controller]`` keys of the adaptive law (docs/control.md)."""

    pretension: float = Field(0.5, ge=0, description="N, minimum tendon tension")
    max_tilt: float = Field(
        0.35, gt=0, lt=math.pi / 2, description="rad, limit of the commanded drone tilt"
    )
    attitude_filter: float = Field(
        0.05, ge=0, description="s, time constant of the commanded-attitude filter"
    )
    max_tilt_rate: float = Field(1.5, ge=0, description="rad/s, limit of the commanded tilt rate")
    min_lift: float = Field(
        0.8,
        ge=0,
        description="the desired force's vertical part is kept above this fraction of the weight "
        "before the tilt is computed (a descending drone still needs thrust)",
    )
    horizontal_position_rate: float = Field(
        1.2,
        gt=0,
        description="1/s, beta of the drone's x and y in s_q = edot + beta e: a slow error b of "
        "the horizontal velocity estimate leaves the drone b / beta from its reference",
    )
    tilt_position_rate: float = _rate(6.0, "beta in s_q = edot + beta e", _TILT)
    yaw_position_rate: float = _rate(3.0, "beta", _YAW)
    vertical_position_rate: float = _rate(1.5, "beta", _VER)
    strain_position_rate: float = _rate(6.0, "beta", _STR)
    tilt_damping_rate: float = _rate(16.0, "damping rate of A_d", _TILT)
    yaw_damping_rate: float = _rate(8.0, "damping rate of A_d", _YAW)
    horizontal_damping_rate: float = _rate(
        1.5, "damping rate of A_d (low: the velocity is an estimate, docs/control.md)", _HOR
    )
    vertical_damping_rate: float = _rate(4.0, "damping rate of A_d", _VER)
    strain_damping_rate: float = _rate(25.0, "damping rate of A_d", _STR)
    tilt_adaptation_rate: float = _rate(20.0, "adaptation rate of A_a", _TILT)
    yaw_adaptation_rate: float = _rate(8.0, "adaptation rate of A_a", _YAW)
    horizontal_adaptation_rate: float = _rate(1.5, "adaptation rate of A_a", _HOR)
    vertical_adaptation_rate: float = _rate(3.0, "adaptation rate of A_a", _VER)
    strain_adaptation_rate: float = _rate(20.0, "adaptation rate of A_a", _STR)

    def rates(self, kind: str, floating: bool, n_s: int) -> list[float]:
        """The ``kind`` rate (``"position"``, ``"damping"`` or ``"adaptation"``) of every
        coordinate: ``[roll, pitch, yaw, x, y, z, strains...]`` for a floating base, the
        strains only for a held one."""
        g = {k: getattr(self, f"{k}_{kind}_rate") for k in GAIN_GROUPS}
        drone = [g["tilt"], g["tilt"], g["yaw"], g["horizontal"], g["horizontal"], g["vertical"]]
        return (drone if floating else []) + [g["strain"]] * n_s


#: the defaults (a controller built without a scenario)
LAW_DEFAULTS = ControlLawConfig()
