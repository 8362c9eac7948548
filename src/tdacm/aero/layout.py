"""Layout of the packed aerodynamic parameter array read by the numba kernels.

The kernels of :mod:`tdacm.system.kernels` take the aerodynamics as one float64 array (like the
packed loads): a header of :data:`N_HEADER` values, then two per-step arrays of the model's
Magnus steps (the cylinder diameter of the section after each step, 0 where there is none, and
the wetted length of its rod for the skin friction).  An empty array means "no aerodynamics".
Build it with :func:`tdacm.system.aero.aero_array`; change the wind between integration calls
with :func:`set_wind`.
"""

from __future__ import annotations

import numpy as np

RHO = 0  # air density (kg/m^3)
MU = 1  # dynamic viscosity (Pa s)
WIND = 2  # (3,) wind velocity in the inertial frame (m/s), uniform over the system
WAKE_ON = 5  # 1: the rotor wake acts on the rod and the tip body
RADIUS = 6  # rotor radius R (m)
SPREAD = 7  # jet half-width spreading rate S
DECAY = 8  # jet centreline decay constant B
CORE = 9  # distance below the disc where the contracted wake turns into a jet (m)
ROTORS = 10  # (4, 3) rotor centres in the body frame (m), rotor k driven by thrust u[k]
THRUST = 22  # (4,) rotor thrusts used when the base is fixed (a drone on a test stand)
CD = 26  # cross-flow drag coefficient of the rod; <= 0: the Reynolds-number correlation
CF = 27  # axial skin-friction coefficient; <= 0: turbulent flat plate on the rod length
TIP_CDA = 28  # (3,) drag areas C_D A of the tip body along the tip frame axes (m^2)
DRONE_D = 31  # (3,) linear rotor drag of the drone along its body axes (N s/m)
DRONE_CDA = 34  # (3,) drag areas C_D A of the drone body along its body axes (m^2)
ROD_ON = 37  # 1: drag on the rod sections and the tip body
DRONE_ON = 38  # 1: rotor and body drag on the drone
N_ROTORS = 4
ROTOR_STATE = 8  # per-rotor state of tdacm.aero.wake.rotor_states
N_HEADER = 40


def set_wind(aero: np.ndarray, wind) -> None:
    """Set the uniform wind velocity (inertial frame, m/s) of a packed array in place."""
    aero[WIND : WIND + 3] = wind
