"""Scenario records of the flight aerodynamics: sections ``[aerodynamics]`` and ``[wind]``.

The rotor geometry is in ``[robot.drone]`` (``rotor_radius``, ``layout``, ``arm_length``:
:class:`tdacm.sim.robot.DroneConfig`). Every default here is the default of the physical record
it builds (:class:`~tdacm.aero.params.Air`, :class:`~tdacm.aero.params.Drag`,
:class:`~tdacm.aero.params.Aerodynamics`, the steady wind's :class:`~tdacm.aero.wind.SteadyWind`),
read from that record, so each value is written once.

Both sections are off by default (``aerodynamics.enabled = false``, no wind): the plant is then
exactly the aerodynamically empty model of the paper.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Annotated

import numpy as np
from pydantic import model_validator

from .._config import ConfigModel, Field
from .params import Aerodynamics, Air, Drag, RotorWake
from .wind import DrydenTurbulence, Gust, SteadyWind, Wind, low_altitude_scales

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Vec4 = Annotated[list[float], Field(min_length=4, max_length=4)]

#: the stream of the run's seed the turbulence is drawn from (``[seed, WIND_STREAM]``): its own,
#: so the other random draws of a run (disturbances, sensors, model) are unchanged by it
WIND_STREAM = 21


def _default(cls, name):
    """The default of field ``name`` of the dataclass ``cls`` (the one source of the value)."""
    return next(f.default for f in fields(cls) if f.name == name)


def _nonneg3(name: str, v: list[float]) -> list[float]:
    if any(x < 0 for x in v):
        raise ValueError(f"{name} must be non-negative, got {v!r}")
    return v


class AerodynamicsConfig(ConfigModel):
    """Section ``[aerodynamics]``: the rotor wake on the arm and the drag of the air on the rod,
    the tip camera and the drone (docs/aerodynamics.md); off unless ``enabled``."""

    enabled: bool = Field(
        False, description="integrate the aerodynamics in the plant (false: the paper's model)"
    )
    wake: bool = Field(
        _default(Aerodynamics, "wake"), description="the rotor wake acts on the rod and the tip"
    )
    rod_drag: bool = Field(
        _default(Aerodynamics, "rod_drag"),
        description="drag of the air (wake + wind) on the rod sections (and the tip body)",
    )
    tip_drag: bool = Field(True, description="drag on the tip body (camera); needs rod_drag")
    drone_drag: bool = Field(
        _default(Aerodynamics, "drone_drag"),
        description="rotor drag and body drag of the drone (in the wind)",
    )
    air_density: float = Field(_default(Air, "density"), gt=0, description="kg/m^3, ISA")
    air_viscosity: float = Field(_default(Air, "viscosity"), gt=0, description="Pa s, ISA")
    rod_cd: float | None = Field(
        _default(Drag, "rod_cd"),
        gt=0,
        description="cross-flow drag coefficient of the rod (unset: C_d = 1 + 10 Re^(-2/3))",
    )
    rod_cf: float | None = Field(
        _default(Drag, "rod_cf"),
        ge=0,
        description="axial skin-friction coefficient (unset: turbulent flat plate)",
    )
    tip_cda: Vec3 = Field(
        list(_default(Drag, "tip_cda")),
        description="m^2, C_D A of the tip body along the tip frame axes",
    )
    drone_linear: Vec3 = Field(
        list(_default(Drag, "drone_linear")),
        description="N s/m, rotor drag F = -D v of the drone along its body axes",
    )
    drone_cda: Vec3 = Field(
        list(_default(Drag, "drone_cda")),
        description="m^2, C_D A of the drone body along its body axes (quadratic drag)",
    )
    fixed_thrusts: Vec4 | None = Field(
        None,
        description="N per rotor: the wake of a drone held on a stand (fixed base; unset: "
        "motors off)",
    )

    @model_validator(mode="after")
    def _check(self):
        for name in ("tip_cda", "drone_linear", "drone_cda"):
            _nonneg3(name, getattr(self, name))
        if self.fixed_thrusts is not None:
            _nonneg3("fixed_thrusts", self.fixed_thrusts)
        if self.enabled and self.wake and not self.rod_drag:
            raise ValueError("wake = true needs rod_drag = true (the wake acts through the drag)")
        if self.enabled and self.tip_drag and not self.rod_drag and any(self.tip_cda):
            raise ValueError("tip_drag = true needs rod_drag = true (set tip_drag = false)")
        return self

    def record(self, rotor_radius: float, layout: str, arm_length: float) -> Aerodynamics:
        """The physical record (:class:`~tdacm.aero.params.Aerodynamics`) with the drone's
        rotor geometry (``[robot.drone]``)."""
        drag = Drag(
            rod_cd=self.rod_cd,
            rod_cf=self.rod_cf,
            tip_cda=tuple(self.tip_cda) if self.tip_drag else (0.0, 0.0, 0.0),
            drone_linear=tuple(self.drone_linear),
            drone_cda=tuple(self.drone_cda),
        )
        rotor = RotorWake(rotor_radius=rotor_radius, layout=layout, arm_length=arm_length)
        thrusts = _default(Aerodynamics, "fixed_thrusts")
        return Aerodynamics(
            air=Air(self.air_density, self.air_viscosity),
            rotor=rotor,
            drag=drag,
            wake=self.wake,
            rod_drag=self.rod_drag,
            drone_drag=self.drone_drag,
            fixed_thrusts=thrusts if self.fixed_thrusts is None else tuple(self.fixed_thrusts),
        )


class WindConfig(ConfigModel):
    """Section ``[wind]``: a steady wind, one 1-cosine gust and Dryden turbulence
    (MIL-F-8785C low-altitude form), uniform over the vehicle; needs ``aerodynamics.enabled``.
    The turbulence is drawn from its own stream of the run's seed (the other random draws of
    the run are unchanged)."""

    velocity: Vec3 = Field(
        SteadyWind().value.tolist(), description="m/s, steady wind (inertial, z up)"
    )
    gust_amplitude: Vec3 = Field(
        [0.0, 0.0, 0.0], description="m/s, peak of the 1-cosine gust (zero: none)"
    )
    gust_start: float = Field(0.0, ge=0, description="s, start of the gust")
    gust_duration: float = Field(1.0, gt=0, description="s, duration of the gust")
    turbulence_wind20: float = Field(
        0.0,
        ge=0,
        description="m/s, wind speed at 20 ft setting the turbulence level, sigma_w = 0.1 W20 "
        "(MIL-F-8785C; light 7.7, moderate 15.4, severe 23.2; 0: no turbulence)",
    )
    turbulence_height: float | None = Field(
        None,
        gt=0,
        lt=304.8,
        description="m above ground setting the turbulence scale lengths (unset: the drone's "
        "initial altitude)",
    )
    turbulence_airspeed: float | None = Field(
        None,
        gt=0,
        description="m/s at which the frozen turbulence passes the vehicle (unset: the steady "
        "wind's speed, or turbulence_wind20 without steady wind)",
    )

    @property
    def active(self) -> bool:
        return bool(any(self.velocity) or any(self.gust_amplitude) or self.turbulence_wind20 > 0)

    def build(self, dt: float, seed: int, height: float) -> Wind | None:
        """The :class:`~tdacm.aero.wind.Wind` of the section (``None`` when there is none),
        turbulence sampled every ``dt`` from the stream ``[seed, WIND_STREAM]``; ``height``
        (m) is used when ``turbulence_height`` is unset."""
        if not self.active:
            return None
        parts: list[Wind] = []
        if any(self.velocity):
            parts.append(SteadyWind(self.velocity))
        if any(self.gust_amplitude):
            parts.append(Gust(self.gust_amplitude, self.gust_start, self.gust_duration))
        if self.turbulence_wind20 > 0:
            h = self.turbulence_height if self.turbulence_height is not None else height
            sigma, scale = low_altitude_scales(h, self.turbulence_wind20)
            horiz = np.asarray(self.velocity[:2], float)
            speed = float(np.linalg.norm(self.velocity))
            airspeed = self.turbulence_airspeed
            if airspeed is None:
                airspeed = speed if speed > 0 else self.turbulence_wind20
            direction = horiz if np.any(horiz) else (1.0, 0.0)
            stream = np.random.SeedSequence([int(seed), WIND_STREAM])
            parts.append(
                DrydenTurbulence(
                    sigma,
                    scale,
                    airspeed,
                    dt,
                    int(stream.generate_state(1, dtype=np.uint64)[0]),
                    direction,
                )
            )
        out = parts[0]
        for p in parts[1:]:
            out = out + p
        return out


__all__ = ["WIND_STREAM", "AerodynamicsConfig", "WindConfig"]
