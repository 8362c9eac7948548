"""The paper's values in one place: Table I (the TD-ACM) and Table II (the cameras), and the
values the paper does not give (with the reason for each).

Every default that is a paper value refers to a constant of this module: the constructors of
:class:`~tdacm.rod.Rod`, :class:`~tdacm.rod.Tendons`, :class:`~tdacm.base.Quadrotor`,
:func:`~tdacm.paper_system`, the camera constants of :mod:`tdacm.vision.camera` and the
``[robot]`` section of a scenario. The module sits below every layer (it imports nothing), so
``rod`` and ``base`` can use it although they sit below ``system``.
"""

from __future__ import annotations

# Table I: the rod (Nitinol)
ROD_LENGTH = 1.0  # m
ROD_DIAMETER = 2e-3  # m
ROD_DENSITY = 6.45e3  # kg/m^3
ROD_YOUNGS_MODULUS = 5e10  # Pa
ROD_POISSON_RATIO = 0.33
ROD_DAMPING = 1e2  # Pa s, material damping
#: the paper's strain basis: both curvatures of order 0 (``n_s = 2``)
ROD_BASIS = "bending:0"
#: Gauss points and Magnus order the paper's basis is integrated with (exact for order 0)
ROD_N_GAUSS = 5
ROD_MAGNUS_ORDER = 2

# Table I: the drone
DRONE_MASS = 0.7331  # kg
DRONE_INERTIA = (2.4388e-2, 2.6151e-2, 2.6929e-2)  # kg m^2, principal

# Not in the paper (reasons in PAPER_DEFAULTS_NOT_IN_PAPER)
DRONE_ARM_LENGTH = 0.325
DRONE_DRAG_FACTOR = 0.016
DRONE_MAX_THRUST = 15.0
TENDON_RADIUS = 0.01
TENDON_COUNT = 4  # two antagonistic pairs
TENDON_MAX_TENSION = 20.0
TIP_MASS = 0.01
ATTACHMENT_OFFSET = 0.1

#: Values the paper does not give, with the reason for each default.
PAPER_DEFAULTS_NOT_IN_PAPER = {
    "arm_length": (
        DRONE_ARM_LENGTH,
        "m, half the 650 mm motor-to-motor diagonal of a Holybro X650 frame",
    ),
    "drag_factor": (
        DRONE_DRAG_FACTOR,
        "m, rotor torque/thrust ratio typical of 15-inch propellers",
    ),
    "max_thrust": (
        DRONE_MAX_THRUST,
        "N per motor, a 5010-class motor on 4S with a 15-inch propeller",
    ),
    "tendon_radius": (TENDON_RADIUS, "m, tendon offset on 20 mm spacer disks"),
    "max_tension": (TENDON_MAX_TENSION, "N, a safe load for a 0.3 mm braided tendon"),
    "tip_mass": (TIP_MASS, "kg, a miniature USB camera with its mount"),
    "attachment_offset": (ATTACHMENT_OFFSET, "m, the rod base below the drone's centre of mass"),
}

# Table II: the cameras (width, height, fx, fy, cx, cy in px; near, far in m)
LOCAL_CAMERA_INTRINSICS = (1024, 1024, 886.8, 886.8, 512.0, 512.0, 0.5, 10.0)  # C_L, tip
GLOBAL_CAMERA_INTRINSICS = (500, 500, 350.5, 350.5, 250.0, 250.0, 0.01, 20.0)  # C_G, drone
#: the mounts (not in the paper): C_L at the tip; C_G in the drone's body frame, tilted down
LOCAL_CAMERA_OFFSET = 0.0  # m beyond the tip along the backbone
GLOBAL_CAMERA_POSITION = (0.10, 0.0, -0.06)  # m, body frame
GLOBAL_CAMERA_TILT_DEG = 10.0
