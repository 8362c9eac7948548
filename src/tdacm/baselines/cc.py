"""The constant-curvature (CC) coupled Lagrangian baseline with the GVS model's interface.

:class:`CCLagrangian` evaluates the code generated from the symbolic derivation
(:mod:`tdacm.baselines.derivation`, :mod:`tdacm.baselines.codegen`) and exposes
``terms(q, qd)``, ``forward_dynamics(q, qd, u)``, ``energy(q, qd)`` and ``tip_pose(q)`` exactly
like :class:`tdacm.TDACM`, so the same integrators and controllers drive both.

Coordinates: ``q = [phi, theta, psi, x, y, z, k_y, k_z]`` (floating) or ``q = [k_y, k_z]``
(clamp), the same as the GVS model with the paper's bending-only order-0 basis; inputs
``u = [4 motor thrusts, 4 tendon tensions]`` (tensions only for a clamp).

Model content (the classical CC Lagrangian model): drone rigid body; rod of constant curvature
with translational and rotational section inertia and gravity evaluated at ``n_gauss``
Gauss-Legendre sections; tip point mass; bending stiffness ``K = EI L [k_y, k_z]``; damping
``D = 3 eta I L`` on the curvatures (Rayleigh dissipation of the Kelvin-Voigt material); four
parallel tendons; constant gravity and a constant dead load on the tip (``loads.tip_force``).
Other loads of :class:`tdacm.Loads` (distributed or follower wrenches, the drone wrench) are not
part of the baseline and are rejected.
"""

from __future__ import annotations

import numpy as np

from .. import paper_values as PV
from ..lie.euler import rot_zyx
from ..system import Loads, SingularConfigurationError, Terms
from ..system.tdacm import default_attachment, energy_record
from .codegen import generated_module
from .derivation import DerivationSpec


def _attachment_offset(g: np.ndarray) -> float | None:
    h = -float(g[2, 3])
    return h if np.allclose(g, default_attachment(h), atol=1e-12) else None


class CCLagrangian:
    """Constant-curvature coupled Lagrangian TD-ACM (symbolically derived, generated code).

    Parameters (SI; defaults = the paper's Table I system, see :func:`tdacm.paper_system`)
    ----------
    floating : drone (``n = 8``) or clamp (``n = 2``)
    base_pose : clamp pose ``g_b`` (4x4) for ``floating=False`` (the rod starts at
        ``g_b @ g_a^b`` as in the GVS model)
    n_gauss : Gauss sections for the rod's kinetic and gravitational energies
    loads : :class:`tdacm.Loads` (only ``gravity`` and ``tip_force`` may be non-zero)
    rebuild : ignore the on-disk cache and derive again
    """

    def __init__(
        self,
        *,
        floating: bool = True,
        base_pose=None,
        n_gauss: int = 5,
        length: float = PV.ROD_LENGTH,
        diameter: float = PV.ROD_DIAMETER,
        density: float = PV.ROD_DENSITY,
        youngs_modulus: float = PV.ROD_YOUNGS_MODULUS,
        damping: float = PV.ROD_DAMPING,
        drone_mass: float = PV.DRONE_MASS,
        drone_inertia=PV.DRONE_INERTIA,
        arm_length: float = PV.DRONE_ARM_LENGTH,
        drag_factor: float = PV.DRONE_DRAG_FACTOR,
        tendon_radius: float = PV.TENDON_RADIUS,
        tip_mass: float = PV.TIP_MASS,
        attachment_offset: float = PV.ATTACHMENT_OFFSET,
        loads: Loads | None = None,
        rebuild: bool = False,
    ):
        self.floating = bool(floating)
        self.spec = DerivationSpec(floating=self.floating, n_gauss=int(n_gauss))
        self.module, self.build_info = generated_module(self.spec, rebuild=rebuild)
        self.n = self.spec.n
        self.n_u = self.spec.n_u
        self.n_s = 2
        self.n_a = 4
        self.base_pose_fixed = np.eye(4) if base_pose is None else np.asarray(base_pose, float)
        if self.floating and base_pose is not None:
            raise ValueError("base_pose is only meaningful for a clamped rod (floating=False)")
        self.length = float(length)
        area = np.pi * diameter**2 / 4.0
        inertia = np.pi * diameter**4 / 64.0
        self.bending_stiffness = youngs_modulus * inertia
        self.drone_mass = float(drone_mass) if self.floating else 0.0
        self.rod_mass = density * area * length
        self.tip_mass = float(tip_mass)
        self._base = [
            float(drone_mass),
            *(float(x) for x in drone_inertia),
            density * area,
            density * inertia,
            self.length,
            self.tip_mass,
            float(attachment_offset),
            self.bending_stiffness,
            float(tendon_radius),
            float(arm_length),
            float(drag_factor),
        ]
        self.loads = loads if loads is not None else Loads()
        off = self.n - 2
        self.damping = np.zeros((self.n, self.n))
        self.damping[off:, off:] = 3.0 * damping * inertia * length * np.eye(2)
        self.stiffness = np.zeros((self.n, self.n))
        self.stiffness[off:, off:] = self.bending_stiffness * length * np.eye(2)
        self._sizes = self.module.SIZES
        self._iu = np.triu_indices(self.n)
        # parallel tendons on a CC rod: l_i = L (1 + k_y d_z - k_z d_y) is linear in q, so
        # B_s = -dl/dq_s is constant (derived symbolically; evaluated once here)
        zero = np.zeros(self.n)
        self._tendon_matrix = self._eval(zero, zero)[5][self.n - 2 :, self.n_u - 4 :].copy()
        #: structural objects (set by :meth:`from_system`) so that controllers written for
        #: :class:`tdacm.TDACM` (thrust/tension limits, ``Gamma``) can drive the baseline
        self.base = None
        self.tendons = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_system(cls, system, rebuild: bool = False) -> CCLagrangian:
        """The CC model of a :class:`tdacm.TDACM` with the paper's layout: bending-only order-0
        basis, four parallel tendons, the default attachment, tip point mass, no tip inertia."""
        rod, tendons, base = system.rod, system.tendons, system.base
        if rod.basis.orders != (None, 0, 0, None, None, None):
            raise ValueError(
                f"the CC baseline has two constant bending curvatures, got {rod.basis}"
            )
        if any(rod.tip_inertia) or tuple(rod.reference_strain) != (0, 0, 0, 1, 0, 0):
            raise ValueError("the CC baseline needs a straight reference and a point-mass tip")
        if tendons.offset_function is not None or tendons.n != 4:
            raise ValueError("the CC baseline has four parallel tendons")
        r = float(np.linalg.norm(tendons.offsets[0]))
        from ..rod import Tendons

        if not np.allclose(tendons.offsets, Tendons.parallel(r).offsets, atol=1e-12):
            raise ValueError("the CC baseline's tendons sit on +y, +z, -y, -z at one radius")
        h = _attachment_offset(system.attachment)
        if h is None:
            raise ValueError("the CC baseline uses default_attachment(offset)")
        kw = dict(
            floating=system.floating,
            n_gauss=rod.n_gauss,
            length=rod.length,
            diameter=rod.diameter,
            density=rod.density,
            youngs_modulus=rod.youngs_modulus,
            damping=rod.damping,
            tendon_radius=r,
            tip_mass=rod.tip_mass,
            attachment_offset=h,
            loads=system.loads,
            rebuild=rebuild,
        )
        if system.floating:
            kw.update(
                drone_mass=base.mass,
                drone_inertia=base.inertia,
                arm_length=base.arm_length,
                drag_factor=base.drag_factor,
            )
        else:
            kw["base_pose"] = base.pose
        out = cls(**kw)
        out.base, out.tendons = base, tendons
        return out

    # ------------------------------------------------------------------ numerics
    def _params(self) -> list:
        ld = self.loads
        for name in ("base_wrench", "rod_wrench", "rod_force", "tip_wrench"):
            if np.any(getattr(ld, name) != 0):
                raise NotImplementedError(
                    f"the CC baseline has no {name} (only gravity, tip_force)"
                )
        g, f = ld.gravity, ld.tip_force
        if not self.floating:  # clamp pose R: potentials -m g.(R p + t) = -m (R^T g).p + const
            rt = self.base_pose_fixed[:3, :3].T
            g, f = rt @ g, rt @ f
        return self._base + [float(x) for x in g] + [float(x) for x in f]

    def _q(self, q, name="q"):
        a = np.asarray(q, dtype=float)
        if a.shape != (self.n,) or not np.isfinite(a).all():
            raise ValueError(f"{name} must be a finite ({self.n},) array, got {q!r}")
        return a

    def _eval(self, q, qd, params=None):
        params = self._params() if params is None else params
        out = self.module._evaluate(q.tolist(), qd.tolist(), params)
        n = self.n
        nm, nc, _, _, _, _ = self._sizes
        m = np.empty((n, n))
        m[self._iu] = out[:nm]
        m.T[self._iu] = out[:nm]
        a = nm + nc
        c = np.array(out[nm:a]).reshape(n, n)
        g = np.array(out[a : a + n])
        k = np.array(out[a + n : a + 2 * n])
        tl = np.array(out[a + 2 * n : a + 3 * n])
        b = np.array(out[a + 3 * n :]).reshape(n, self.n_u)
        return m, c, g, k, tl, b

    def terms(self, q, qd) -> Terms:
        """``M, C, D, K, tau_ext, B`` (same meaning as :meth:`tdacm.TDACM.terms`; ``tau_ext`` =
        ``-G + tau_load``: gravity and the tip dead load)."""
        q, qd = self._q(q), self._q(qd, "qd")
        m, c, g, k, tl, b = self._eval(q, qd)
        return Terms(m, c, self.damping.copy(), k, tl - g, b)

    def gravity_force(self, q) -> np.ndarray:
        """``G(q) = dV_gravity/dq``."""
        q = self._q(q)
        return self._eval(q, np.zeros(self.n))[2]

    def input_matrix(self, q) -> np.ndarray:
        q = self._q(q)
        return self._eval(q, np.zeros(self.n))[5]

    def tendon_matrix(self, q) -> np.ndarray:
        """``B_s`` (2 x 4), constant for parallel tendons on a CC rod."""
        self._q(q)
        return self._tendon_matrix.copy()

    def base_pose(self, q) -> np.ndarray:
        """Drone pose ``g_b`` (ZYX Euler angles and position); the clamp pose for a fixed base."""
        q = self._q(q)
        if not self.floating:
            return self.base_pose_fixed.copy()
        g = np.eye(4)
        g[:3, :3] = rot_zyx(q[0], q[1], q[2])
        g[:3, 3] = q[3:6]
        return g

    def check_regular(self, q) -> None:
        if self.floating and abs(np.cos(q[1])) < 1e-6:
            raise SingularConfigurationError(f"theta = {q[1]!r} rad is the ZYX Euler singularity")

    def forward_dynamics(self, q, qd, u=None) -> np.ndarray:
        """``qdd = M^-1 (B u - G + tau_load - C qd - D qd - K)``."""
        q, qd = self._q(q), self._q(qd, "qd")
        self.check_regular(q)
        m, c, g, k, tl, b = self._eval(q, qd)
        rhs = tl - g - c @ qd - self.damping @ qd - k
        if u is not None:
            u = np.asarray(u, dtype=float)
            if u.shape != (self.n_u,):
                raise ValueError(f"u must have shape ({self.n_u},), got {u.shape}")
            if np.any(u[-4:] < 0):
                raise ValueError(f"tendon tensions must be non-negative, got {u[-4:]!r}")
            rhs = rhs + b @ u
        return np.linalg.solve(m, rhs)

    def forward_dynamics_unchecked(self, q, qd, u, params) -> np.ndarray:
        """:meth:`forward_dynamics` without input validation, with the parameter list
        ``params = self._params()`` precomputed (the counterpart of the GVS numba kernel
        ``kernels.forward_dynamics`` in timing comparisons)."""
        m, c, g, k, tl, b = self._eval(q, qd, params)
        return np.linalg.solve(m, b @ u + tl - g - c @ qd - self.damping @ qd - k)

    def energy(self, q, qd) -> dict:
        """Kinetic and potential energies (J), same keys as :meth:`tdacm.TDACM.energy`."""
        q, qd = self._q(q), self._q(qd, "qd")
        out = self.module._energy(q.tolist(), qd.tolist(), self._params())
        kin, vg, ve, vl = out[:4]
        if not self.floating:  # the constant part of the clamp translation
            t = self.base_pose_fixed[:3, 3]
            mass = self.rod_mass + self.tip_mass
            vg -= mass * self.loads.gravity @ t
            vl -= self.loads.tip_force @ t
        return energy_record(kin, vg, ve, vl)

    def tip_pose(self, q) -> np.ndarray:
        """Tip pose ``g_L`` (4x4, inertial)."""
        q = self._q(q)
        out = self.module._energy(q.tolist(), [0.0] * self.n, self._params())
        g = np.eye(4)
        g[:3, 3] = out[4:7]
        g[:3, :3] = np.array(out[7:16]).reshape(3, 3)
        if not self.floating:
            g = self.base_pose_fixed @ g
        return g

    @property
    def n_rods(self) -> int:
        """One rod (the constant-curvature model of the paper's single TD-CR)."""
        return 1

    @property
    def total_mass(self) -> float:
        return self.drone_mass + self.rod_mass + self.tip_mass

    @property
    def derivation_seconds(self) -> float:
        """Wall time of the symbolic derivation when the cached code was generated."""
        return float(self.module.DERIVATION_SECONDS)

    def __repr__(self) -> str:
        return f"CCLagrangian(n={self.n}, floating={self.floating}, n_gauss={self.spec.n_gauss})"


def cc_paper_system(rebuild: bool = False, **overrides) -> CCLagrangian:
    """The CC baseline of :func:`tdacm.paper_system` with the same ``overrides``."""
    from ..system import paper_system

    return CCLagrangian.from_system(paper_system(**overrides), rebuild=rebuild)
