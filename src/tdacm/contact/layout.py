"""Layout of the packed contact array read by the numba kernels.

The kernels of :mod:`tdacm.system.kernels` take the contact scene as one float64 array (like
the packed loads and the aerodynamics): a header of :data:`N_HEADER` values, one value per
Magnus step of the model (the contact radius of the rod at the body after the step: the rod's
radius at a Gauss section, the tip sphere's radius at a tip body, 0 elsewhere), then
:data:`SHAPE_SIZE` values per obstacle.  An empty array means "no contact".  Build it with
:func:`tdacm.system.contact.contact_array`.

An obstacle row is ``[kind, R (3 x 3, row-major), p (3), a, b, c]``: its pose (the columns of
``R`` are its axes in the inertial frame, ``p`` its centre) and its sizes (see
:mod:`tdacm.contact.shapes`).
"""

from __future__ import annotations

N_SHAPES = 0  # number of obstacles
K_ROD = 1  # N/m^2, normal stiffness of the rod per metre of contact and metre of penetration
K_TIP = 2  # N/m, normal stiffness of the tip sphere
DAMPING = 3  # s/m, Hunt-Crossley damping constant c: F = k delta (1 + c delta_dot)
MU_S = 4  # static friction coefficient
MU_K = 5  # kinetic friction coefficient
V_SLIP = 6  # m/s, regularization speed of the Coulomb law
V_STRIBECK = 7  # m/s, speed of the static -> kinetic transition
ROD_ON = 8  # 1: the rod's backbone (capsules between its nodes) touches the obstacles
TIP_ON = 9  # 1: the tip sphere touches the obstacles
TIP_RADIUS = 10  # m, radius of the tip sphere
PROBE = 12  # (3,) m, centre of the tip sphere in the tip frame (0: the tip; a rigid probe)
N_HEADER = 16

# obstacle row
KIND = 0
ROT = 1  # (3, 3) row-major
POS = 10  # (3,)
SIZE = 13  # (3,)
SHAPE_SIZE = 16

PLANE = 0.0  # half-space below the plane through p with normal R[:, 2]
SPHERE = 1.0  # radius a
BOX = 2.0  # half extents a, b, c along the axes
CYLINDER = 3.0  # radius a, half length b along the axis R[:, 2]
