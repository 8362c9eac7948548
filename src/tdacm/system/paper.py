"""The paper's Table I system, every constant overridable."""

from __future__ import annotations

from .. import paper_values as PV
from ..base import FixedBase, Quadrotor
from ..rod import Rod, StrainBasis, Tendons
from .tdacm import TDACM, Loads, default_attachment

#: Values the paper does not give, with the reason for each default.
PAPER_DEFAULTS_NOT_IN_PAPER = PV.PAPER_DEFAULTS_NOT_IN_PAPER


def paper_system(
    *,
    length: float = PV.ROD_LENGTH,
    diameter: float = PV.ROD_DIAMETER,
    density: float = PV.ROD_DENSITY,
    youngs_modulus: float = PV.ROD_YOUNGS_MODULUS,
    poisson_ratio: float = PV.ROD_POISSON_RATIO,
    damping: float = PV.ROD_DAMPING,
    drone_mass: float = PV.DRONE_MASS,
    drone_inertia: tuple = PV.DRONE_INERTIA,
    arm_length: float = PV.DRONE_ARM_LENGTH,
    drag_factor: float = PV.DRONE_DRAG_FACTOR,
    max_thrust: float = PV.DRONE_MAX_THRUST,
    tendon_radius: float = PV.TENDON_RADIUS,
    max_tension: float = PV.TENDON_MAX_TENSION,
    tip_mass: float = PV.TIP_MASS,
    attachment_offset: float = PV.ATTACHMENT_OFFSET,
    basis: StrainBasis | None = None,
    n_gauss: int | None = None,
    magnus_order: int | None = None,
    fixed_base_pose=None,
    loads: Loads | None = None,
) -> TDACM:
    """The paper's TD-ACM (Table I): a 1 m Nitinol rod (2 bending strains of order 0, ``n = 8``)
    under a 0.7331 kg quadrotor, four parallel tendons in two antagonistic pairs.

    ``fixed_base_pose`` (4x4) replaces the drone by a clamp at that pose (the paper's ground tests
    A and B; ``n = 2``).  Values missing from the paper: :data:`PAPER_DEFAULTS_NOT_IN_PAPER`.
    The paper uses a second-order Magnus expansion (the default for the paper's basis); with the
    order-0 basis both orders are exact.  Five Gauss points integrate ``M``, ``C`` and
    ``tau_ext`` of this system to 1e-14 relative to a 32-point rule (measured at
    ``q_s = [0.3, 0.4]``).  With another ``basis`` the defaults are those of :class:`Rod`
    (Magnus order 4 and :func:`~tdacm.rod.default_gauss_points`), the accurate choice.
    """
    if basis is None:
        n_gauss = PV.ROD_N_GAUSS if n_gauss is None else n_gauss
        magnus_order = PV.ROD_MAGNUS_ORDER if magnus_order is None else magnus_order
    rod = Rod(
        length=length,
        diameter=diameter,
        density=density,
        youngs_modulus=youngs_modulus,
        poisson_ratio=poisson_ratio,
        damping=damping,
        basis=basis if basis is not None else StrainBasis.bending(0),
        n_gauss=n_gauss,
        magnus_order=magnus_order,
        tip_mass=tip_mass,
    )
    tendons = Tendons.parallel(radius=tendon_radius, count=PV.TENDON_COUNT, max_tension=max_tension)
    if fixed_base_pose is None:
        base = Quadrotor(
            mass=drone_mass,
            inertia=drone_inertia,
            arm_length=arm_length,
            drag_factor=drag_factor,
            max_thrust=max_thrust,
        )
    else:
        base = FixedBase(pose=fixed_base_pose)
    return TDACM(rod, tendons, base, default_attachment(attachment_offset), loads)


def dual_paper_system(
    *,
    separation: float = 0.3,
    attachment_offset: float = PV.ATTACHMENT_OFFSET,
    basis: StrainBasis | None = None,
    n_gauss: int | None = None,
    magnus_order: int | None = None,
    fixed_base_pose=None,
    loads: Loads | None = None,
    **rod_and_drone,
) -> TDACM:
    """Two of the paper's TD-CRs under one quadrotor (the paper's future-work "dual TD-CR
    configuration"): identical rods, each with its own four tendons, hanging ``attachment_offset``
    below the drone at ``+-separation/2`` along the body x axis (the rod base frames are those
    of :func:`~tdacm.system.default_attachment`, shifted).

    ``q = [phi, theta, psi, x, y, z, q_s of rod 0 (2), q_s of rod 1 (2)]`` (``n = 10``),
    ``u = [4 thrusts, 4 tensions of rod 0, 4 tensions of rod 1]``.  Other keyword arguments
    are those of :func:`paper_system` (material, drone, tendon radius...).
    """
    one = paper_system(
        basis=basis,
        n_gauss=n_gauss,
        magnus_order=magnus_order,
        attachment_offset=attachment_offset,
        fixed_base_pose=fixed_base_pose,
        **rod_and_drone,
    )
    separation = float(separation)
    atts = []
    for sign in (1.0, -1.0):
        g = default_attachment(attachment_offset)
        g[0, 3] = sign * separation / 2
        atts.append(g)
    tendons = Tendons.parallel(
        radius=float(one.tendons.offsets[0, 1]),
        count=PV.TENDON_COUNT,
        max_tension=one.tendons.max_tension,
    )
    return TDACM([one.rod, one.rod], [tendons, tendons], one.base, atts, loads)
