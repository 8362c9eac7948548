"""Frozen parameter records of the flight aerodynamics, every default with its reason.

* :class:`Air`: the atmosphere (ISA sea level);
* :class:`RotorWake`: the rotor geometry and the jet constants of the wake model
  (:mod:`tdacm.aero.wake`);
* :class:`Drag`: drag of the rod, of the tip body and of the drone (:mod:`tdacm.aero.drag`);
* :class:`Aerodynamics`: the three together, with switches for each effect.

Defaults are sized for the paper's 0.7331 kg drone on a Holybro X650 frame (the values the
paper does not give are those of :data:`tdacm.paper_values.PAPER_DEFAULTS_NOT_IN_PAPER`:
15-inch propellers, 0.325 m motor arms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as V

#: Rotor layouts: angle (rad) of rotor 0 from body +x, then counter-clockwise every 90 deg.
LAYOUTS = {"+": 0.0, "x": math.pi / 4}


@dataclass(frozen=True)
class Air:
    """Still air of the International Standard Atmosphere at sea level (15 deg C)."""

    density: float = 1.225  # kg/m^3, ISA sea level
    viscosity: float = 1.789e-5  # Pa s, ISA sea level (Sutherland's law at 288.15 K)

    def __post_init__(self):
        V.positive("density", self.density)
        V.positive("viscosity", self.viscosity)


@dataclass(frozen=True)
class RotorWake:
    """Geometry of the four rotors and constants of their wake (:mod:`tdacm.aero.wake`).

    rotor_radius : 0.1905 m, a 15-inch propeller (the size behind the drone's default
        ``drag_factor`` and ``max_thrust``, see ``tdacm.paper_values``)
    arm_length : distance from the centre of mass to each rotor axis (m); ``None`` takes the
        drone's own ``Quadrotor.arm_length`` (one source of truth: it also sets ``Gamma``)
    layout : ``"+"`` (rotor 0 on body +x, the motor order of ``Gamma`` in eq. (15) as
        implemented by :class:`tdacm.base.Quadrotor`) or ``"x"`` (rotor 0 at +45 deg); rotors
        are numbered counter-clockwise and rotor ``k`` is driven by the thrust ``u[k]``
    spreading_rate : 0.094, the half-width growth ``db/dz`` of a round turbulent jet
        (Hussein, Capp & George 1994, laser-Doppler data, as tabulated by Pope 2000, Table 5.1)
    decay_constant : 5.8, the centreline decay ``U_c / U_J = B d / (z - z_0)`` of the same jet
        (same source)
    core_length : 2.0 rotor radii below the disc, where momentum theory's contraction is 95 %
        complete (``w = 1.89 v_i``); below it the contracted slipstream spreads as a jet
    """

    rotor_radius: float = 0.1905
    arm_length: float | None = None
    layout: str = "+"
    spreading_rate: float = 0.094
    decay_constant: float = 5.8
    core_length: float = 2.0

    def __post_init__(self):
        V.positive("rotor_radius", self.rotor_radius)
        if self.arm_length is not None:
            V.positive("arm_length", self.arm_length)
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {sorted(LAYOUTS)}, got {self.layout!r}")
        V.positive("spreading_rate", self.spreading_rate)
        V.positive("decay_constant", self.decay_constant)
        V.positive("core_length", self.core_length)

    def rotor_positions(self, arm_length: float) -> np.ndarray:
        """Rotor centres in the body frame (4, 3), in the plane of the centre of mass."""
        a0 = LAYOUTS[self.layout]
        ang = a0 + 0.5 * math.pi * np.arange(4)
        return np.column_stack([arm_length * np.cos(ang), arm_length * np.sin(ang), np.zeros(4)])


@dataclass(frozen=True)
class Drag:
    """Drag coefficients of the rod, the tip body and the drone (:mod:`tdacm.aero.drag`).

    rod_cd : cross-flow drag coefficient of the rod; ``None`` uses the circular-cylinder
        correlation ``C_d = 1 + 10 Re^(-2/3)`` (White, *Viscous Fluid Flow*, 3rd ed. 2006, ch. 3,
        a fit of cylinder data for 1 < Re < 2e5: Re = 670 for the 2 mm rod at 5 m/s)
    rod_cf : axial skin-friction coefficient on the wetted perimeter ``pi d``; ``None`` uses the
        turbulent flat plate ``C_f = 0.074 Re_L^(-1/5)`` on the rod length (Prandtl's 1/7 law;
        the flow in the rotor wake is turbulent; the transverse curvature of a thin cylinder,
        which raises the friction, is neglected)
    tip_cda : ``C_D A`` of the tip body along the tip frame axes (m^2): a miniature USB camera,
        a 32 x 32 mm board facing the rod axis and 32 x 20 mm sideways, ``C_D = 1.05`` (a cube
        face-on, Hoerner 1965)
    drone_linear : rotor drag of the drone, ``F = -D v_rel`` in the body frame (N s/m): the
        standard first-order model (Faessler, Franchi & Scaramuzza 2018, IEEE RA-L 3(2)); their
        identified mass-normalized coefficients are about 0.4 1/s in the rotor plane, here
        ``0.4 x 0.73 kg`` for body x and y and 0 along the thrust axis
    drone_cda : ``C_D A`` of the drone's body along its body axes (m^2), quadratic drag
        ``F = -1/2 rho |v| (C_D A) v``: a 0.15 m x 0.1 m fuselage with battery seen from the side
        (``C_D = 1``, bluff body) and 0.04 m^2 of frame and arms seen from above
    """

    rod_cd: float | None = None
    rod_cf: float | None = None
    tip_cda: tuple = (1.05e-3, 6.7e-4, 6.7e-4)
    drone_linear: tuple = (0.29, 0.29, 0.0)
    drone_cda: tuple = (0.015, 0.015, 0.04)

    def __post_init__(self):
        if self.rod_cd is not None:
            V.positive("rod_cd", self.rod_cd)
        if self.rod_cf is not None:
            V.nonnegative("rod_cf", self.rod_cf)
        for name in ("tip_cda", "drone_linear", "drone_cda"):
            a = V.array(name, getattr(self, name), (3,))
            if np.any(a < 0):
                raise ValueError(f"{name} must be non-negative, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(x) for x in a))


@dataclass(frozen=True)
class Aerodynamics:
    """The flight aerodynamics of a TD-ACM: air, rotor wake and drag, each effect switchable.

    wake : the rotor wake acts on the rod and the tip body
    rod_drag : drag of the air (wake + wind) on the rod sections and the tip body
    drone_drag : rotor drag and body drag of the drone (wind only: no self-interaction)
    fixed_thrusts : rotor thrusts (N) making the wake when the base is fixed (a drone held on a
        stand, motors running); a floating drone uses its own inputs ``u[0:4]``
    """

    air: Air = field(default_factory=Air)
    rotor: RotorWake = field(default_factory=RotorWake)
    drag: Drag = field(default_factory=Drag)
    wake: bool = True
    rod_drag: bool = True
    drone_drag: bool = True
    fixed_thrusts: tuple = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self):
        for name, cls in (("air", Air), ("rotor", RotorWake), ("drag", Drag)):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {getattr(self, name)!r}")
        t = V.array("fixed_thrusts", self.fixed_thrusts, (4,))
        if np.any(t < 0):
            raise ValueError(f"fixed_thrusts must be non-negative, got {self.fixed_thrusts!r}")
        object.__setattr__(self, "fixed_thrusts", tuple(float(x) for x in t))
        if self.wake and not self.rod_drag:
            raise ValueError("wake = True needs rod_drag = True (the wake acts through the drag)")
