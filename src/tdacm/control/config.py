"""Parameter record of the low-level controller's law (the adaptive law, the drone loop and the
allocation of :class:`~tdacm.control.TDACMController`): the keys of the scenario's
``[controller]`` section that the law reads. The loop's ``[controller]`` record
(:class:`tdacm.loop.config.ControllerConfig`) extends it; :class:`TDACMController`'s defaults
are these."""

from __future__ import annotations

import math

from .._config import ConfigModel, Field


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
    horizontal_position_rate: float = Field(
        1.2,
        gt=0,
        description="1/s, beta of the drone's x and y in s_q = edot + beta e: a slow error b of "
        "the horizontal velocity estimate leaves the drone b / beta from its reference",
    )


#: the defaults, for the constructors
LAW_DEFAULTS = ControlLawConfig()
