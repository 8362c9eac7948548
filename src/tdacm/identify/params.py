"""The physical parameters :mod:`tdacm.identify` can estimate, and how each enters the model.

Each :class:`Parameter` names one scalar of the robot, the ``[robot]`` TOML key it is written to
(:data:`tdacm.sim.robot.ROBOT_SCHEMA`), and how the optimizer sees it: strictly positive
quantities are fitted as ``log(value)`` (a relative step is the same anywhere, so a start 30 %
off is as far as any other; the standard deviation of the log is the relative one); the
friction coefficients, which may be 0, are fitted linearly with a typical ``scale``.

Tendon friction model (an addition to the model of eq. (13), which has loss-free tendons): the
tension delivered along tendon ``i`` is

    T_eff = T (1 + mu tanh(ldot / v0)) + c_v ldot,   clipped at 0,

with ``T`` the tension measured at the actuator, ``ldot = dl_i/dt`` the tendon's length rate
(``l_i`` its path length, ``ldot = -B_s^T qdot_s``), ``mu`` a Coulomb coefficient (the capstan
loss ``exp(mu_c theta) - 1`` of the guides, linearized: ``mu = 0.05`` is 5 % of the tension
lost while the actuator reels the tendon in, ``ldot < 0``, and 5 % added while the rod pulls it
out) smoothed over ``v0`` (:data:`FRICTION_V0`), and ``c_v`` (N s/m) a viscous loss. Both do
negative work ``-ldot (T_eff - T)`` on the rod: they only dissipate.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Smoothing speed of the Coulomb tendon friction (m/s): below it ``tanh`` is linear.
FRICTION_V0 = 1e-3


@dataclass(frozen=True)
class Parameter:
    """One identifiable scalar: ``name`` (the ``--params`` spelling), its ``[robot]`` TOML
    place ``toml = (section, key[, index])``, unit, ``log`` scaling (else linear with
    ``scale``), whether it exists only with a flying base or a camera, and a description."""

    name: str
    toml: tuple
    unit: str
    log: bool = True
    scale: float = 1.0
    floating_only: bool = False
    camera_only: bool = False
    doc: str = ""
    nonnegative: bool = False  # a linear parameter that cannot be negative (a friction)


PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("E", ("rod", "youngs_modulus"), "Pa", doc="rod Young's modulus"),
        Parameter("damping", ("rod", "damping"), "Pa s", doc="rod material viscosity eta"),
        Parameter("tip_mass", ("rod", "tip_mass"), "kg", doc="point mass at the rod tip"),
        Parameter(
            "radius",
            ("tendons", "radius"),
            "m",
            doc="tendon moment arm: every tendon offset scaled to this radius",
        ),
        Parameter(
            "friction",
            ("tendons", "friction"),
            "1",
            log=False,
            scale=0.05,
            doc="Coulomb tendon friction coefficient mu (T_eff = T (1 + mu tanh(ldot/v0)))",
            nonnegative=True,
        ),
        Parameter(
            "viscous",
            ("tendons", "viscous_friction"),
            "N s/m",
            log=False,
            scale=1.0,
            doc="viscous tendon friction c_v (T_eff += c_v ldot)",
            nonnegative=True,
        ),
        Parameter("drone_mass", ("drone", "mass"), "kg", floating_only=True, doc="drone mass"),
        Parameter(
            "inertia_x", ("drone", "inertia", 0), "kg m^2", floating_only=True, doc="drone Ixx"
        ),
        Parameter(
            "inertia_y", ("drone", "inertia", 1), "kg m^2", floating_only=True, doc="drone Iyy"
        ),
        Parameter(
            "inertia_z", ("drone", "inertia", 2), "kg m^2", floating_only=True, doc="drone Izz"
        ),
        Parameter(
            "thrust",
            ("drone", "thrust_constant"),
            "1",
            floating_only=True,
            doc="thrust constant k_T: the rotors produce k_T times the recorded thrust commands",
        ),
        Parameter(
            "camera_offset",
            ("cameras", "local", "offset"),
            "m",
            log=False,
            scale=0.01,
            camera_only=True,
            doc="C_L's offset beyond the tip along the backbone",
        ),
    )
}

#: ``--params`` shorthands.
ALIASES = {
    "youngs_modulus": ["E"],
    "inertia": ["inertia_x", "inertia_y", "inertia_z"],
    "moment_arm": ["radius"],
    "mass": ["drone_mass"],
}

#: The paper robot's five main parameters (the benchmark): rod stiffness, damping, tip mass,
#: tendon moment arm (clamped-rod experiments) and drone mass (hover experiment).
MAIN_PARAMETERS = ("E", "damping", "tip_mass", "radius", "drone_mass")


def parse_params(text) -> list[str]:
    """``"E,damping,inertia"`` (or a list) -> parameter names, aliases expanded, checked."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[str] = []
    for raw in items:
        name = raw.strip()
        if not name:
            continue
        names = ALIASES.get(name, [name])
        for n in names:
            if n not in PARAMETERS:
                raise ValueError(
                    f"unknown parameter {name!r}; choose from {', '.join(PARAMETERS)} "
                    f"(or {', '.join(ALIASES)})"
                )
            if n not in out:
                out.append(n)
    if not out:
        raise ValueError("no parameter given")
    return out
