"""The coupled TD-ACM: a GVS Cosserat rod hanging from a quadrotor (or a clamp).

This is the thin, validated Python API over the numba kernels of :mod:`tdacm.system.kernels`.
Model data (parameters, precomputed quadrature and basis arrays) lives in the object; every
algorithm is a function of ``(q, qdot)``.

Conventions (paper section II, ``shared/NOTES.md``): ``q = [phi, theta, psi, x, y, z, q_s]``
(ZYX Euler angles, inertial position of the drone's centre of mass; ``q = q_s`` for a fixed
base); poses are 4x4 in the inertial frame; Jacobians map ``qdot`` to the twist ``[w; v]`` of the
frame in that frame (local, angular first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from ..base import FixedBase, Quadrotor
from ..lie.euler import SINGULAR_COS
from ..lie.magnus import MAGNUS_POINTS
from ..rod import Rod, Tendons
from . import kernels as K


class SingularConfigurationError(ValueError):
    """The ZYX Euler parameterization is singular (``theta = +-90 deg``)."""


def default_attachment(offset: float = 0.1) -> np.ndarray:
    """``g_a^b``: the rod hangs ``offset`` metres below the drone's centre of mass, its backbone
    (local x) pointing along body -z, local y along body y and local z along body x
    (a rotation of +90 deg about body y)."""
    g = np.eye(4)
    g[:3, :3] = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    g[2, 3] = -offset
    return g


class Loads:
    """External loads (constant during one integration call; change them between calls).

    gravity : gravitational acceleration in the inertial frame (m/s^2), default ``[0, 0, -9.81]``
    base_wrench : point wrench ``W_b^b`` on the drone in its body frame ``[m; f]`` (eq. (16))
    rod_wrench : distributed wrench density on the rod in the section frame ``[m; f]`` per metre
    rod_force : distributed force density on the rod in the inertial frame (N/m), e.g. downwash
    tip_wrench : wrench on the tip in the tip frame (a follower load)
    tip_force : force on the tip in the inertial frame (a dead load)

    The values live in one packed (27,) array (the kernels' layout, ``kernels.LOAD_SLICES``);
    each attribute is a view into it, so ``loads.gravity[2] = -1.62`` works too.
    """

    __slots__ = ("_packed",)

    def __init__(
        self,
        gravity=(0.0, 0.0, -9.81),
        base_wrench=None,
        rod_wrench=None,
        rod_force=None,
        tip_wrench=None,
        tip_force=None,
    ):
        self._packed = np.zeros(K.N_LOADS)
        self.gravity = gravity
        for name, value in (
            ("base_wrench", base_wrench),
            ("rod_wrench", rod_wrench),
            ("rod_force", rod_force),
            ("tip_wrench", tip_wrench),
            ("tip_force", tip_force),
        ):
            if value is not None:
                setattr(self, name, value)

    def packed(self) -> np.ndarray:
        """The packed (27,) array itself (no copy; treat it as read-only)."""
        return self._packed

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={getattr(self, k).tolist()}" for k in K.LOAD_SLICES)
        return f"Loads({body})"


def _load_property(name: str, sl: slice):
    def get(self):
        return self._packed[sl]

    def set_(self, value):
        self._packed[sl] = V.array(name, value, (sl.stop - sl.start,))

    return property(get, set_, doc=f"``{name}`` (a view into the packed loads)")


for _name, _sl in K.LOAD_SLICES.items():
    setattr(Loads, _name, _load_property(_name, _sl))


@dataclass(frozen=True)
class Terms:
    """Terms of ``M qdd + (C + D) qd + K = B u + tau_ext`` at one state (paper eq. (9))."""

    M: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    tau_ext: np.ndarray
    B: np.ndarray


class TDACM:
    """A tendon-driven continuum rod on a quadrotor (or on a fixed base).

    Parameters
    ----------
    rod : :class:`~tdacm.rod.Rod`
    tendons : :class:`~tdacm.rod.Tendons`
    base : :class:`~tdacm.base.Quadrotor` (floating, underactuated) or :class:`FixedBase`
    attachment : ``g_a^b`` (4x4), pose of the rod base in the drone frame
    loads : :class:`Loads` (gravity on by default)
    """

    def __init__(
        self,
        rod: Rod | None = None,
        tendons: Tendons | None = None,
        base: Quadrotor | FixedBase | None = None,
        attachment: np.ndarray | None = None,
        loads: Loads | None = None,
    ):
        self.rod = rod if rod is not None else Rod()
        self.tendons = tendons if tendons is not None else Tendons.parallel()
        self.base = base if base is not None else Quadrotor()
        if not isinstance(self.rod, Rod):
            raise ValueError(f"rod must be a Rod, got {self.rod!r}")
        if not isinstance(self.tendons, Tendons):
            raise ValueError(f"tendons must be a Tendons, got {self.tendons!r}")
        if not isinstance(self.base, Quadrotor | FixedBase):
            raise ValueError(f"base must be a Quadrotor or a FixedBase, got {self.base!r}")
        self.attachment = V.transform(
            "attachment", default_attachment() if attachment is None else attachment
        )
        self.loads = loads if loads is not None else Loads()
        self._build()

    # ------------------------------------------------------------------ construction
    def _steps(self, nodes: np.ndarray):
        """Magnus step arrays between consecutive normalized ``nodes``."""
        rod = self.rod
        frac = MAGNUS_POINTS[rod.magnus_order]
        x0 = nodes[:-1]
        dx = np.diff(nodes)
        xs = x0[:, None] + dx[:, None] * frac[None, :]
        bs = rod.basis(xs.ravel()).reshape(*xs.shape, 6, rod.basis.n)
        xi0 = np.broadcast_to(np.asarray(rod.reference_strain), (*xs.shape, 6)).copy()
        return dx * rod.length, xi0, bs

    def _build(self):
        rod, basis = self.rod, self.rod.basis
        self.floating = bool(self.base.floating)
        self.n_s = basis.n
        self.n_a = self.tendons.n
        self.n = self.n_s + (6 if self.floating else 0)
        self.n_u = self.n_a + (4 if self.floating else 0)
        xg, wg = rod.quadrature()
        self.quadrature_points = xg * rod.length
        h, xi0s, bs = self._steps(np.concatenate([[0.0], xg, [1.0]]))
        bg = basis(xg)
        hbar, dbar = rod.stiffness_density, rod.damping_density
        ks = np.einsum("g,gai,ab,gbj->ij", wg * rod.length, bg, hbar, bg)
        ds = np.einsum("g,gai,ab,gbj->ij", wg * rod.length, bg, dbar, bg)
        off = self.n - self.n_s
        stiffness = np.zeros((self.n, self.n))
        damping = np.zeros((self.n, self.n))
        stiffness[off:, off:] = ks
        damping[off:, off:] = ds
        d, dd = self.tendons.at(xg, rod.length)
        if self.floating:
            mb6 = np.diag(self.base.spatial_inertia).copy()
            gamma = self.base.gamma
            g_fixed = np.eye(4)
        else:
            mb6 = np.zeros(6)
            gamma = np.zeros((6, 4))
            g_fixed = self.base.pose
        self._m = K.ModelArrays(
            self.floating,
            np.ascontiguousarray(g_fixed),
            np.ascontiguousarray(self.attachment),
            np.ascontiguousarray(h),
            np.ascontiguousarray(xi0s),
            np.ascontiguousarray(bs),
            np.ascontiguousarray(wg * rod.length),
            np.diag(rod.inertia_density).copy(),
            np.diag(rod.tip_spatial_inertia).copy(),
            mb6,
            stiffness,
            damping,
            np.ascontiguousarray(gamma),
            np.broadcast_to(np.asarray(rod.reference_strain), (len(xg), 6)).copy(),
            np.ascontiguousarray(bg),
            np.ascontiguousarray(d),
            np.ascontiguousarray(dd),
        )

    @property
    def model_arrays(self) -> K.ModelArrays:
        """The constant arrays handed to the kernels (read-only by convention)."""
        return self._m

    @property
    def total_mass(self) -> float:
        mb = self.base.mass if self.floating else 0.0
        return mb + self.rod.mass + self.rod.tip_mass

    # ------------------------------------------------------------------ validation
    def _q(self, q, name="q") -> np.ndarray:
        # fast path: this runs on every API call of the integrators and controllers; a @ a is
        # finite iff every entry is (an overflow falls back to the full check, which passes)
        a = np.asarray(q, dtype=float)
        if a.shape != (self.n,) or not math.isfinite(a @ a):
            return V.array(name, q, (self.n,))  # raises the explanatory error
        return a

    def _u(self, u) -> np.ndarray:
        a = np.asarray(u, dtype=float)
        u = a if a.shape == (self.n_u,) and math.isfinite(a @ a) else V.array("u", u, (self.n_u,))
        if min(u[self.n_u - self.n_a :].tolist()) < 0:
            tensions = u[self.n_u - self.n_a :]
            raise ValueError(
                f"tendon tensions must be non-negative (tendons only pull), got {tensions!r}"
            )
        return u

    def check_regular(self, q) -> None:
        """Raise :class:`SingularConfigurationError` at the Euler singularity."""
        if self.floating and abs(math.cos(q[1])) < SINGULAR_COS:
            raise SingularConfigurationError(
                f"theta = {q[1]!r} rad is the ZYX Euler singularity (theta = +-pi/2): the drone "
                "attitude cannot be represented by these coordinates"
            )

    def _s(self, s) -> float:
        s = V.finite_scalar("s", s)
        if not -1e-12 <= s <= self.rod.length * (1 + 1e-12):
            raise ValueError(f"s must lie in [0, L = {self.rod.length}], got {s!r}")
        return min(max(s, 0.0), self.rod.length)

    # ------------------------------------------------------------------ kinematics
    def base_pose(self, q) -> np.ndarray:
        """Drone pose ``g_b`` (eq. (1)); the clamp pose for a fixed base."""
        q = self._q(q)
        g, _, _ = K.base_state(q, np.zeros(self.n), self.floating, self._m.g_fixed, self.n)
        return g

    def _chain_to(self, s: float):
        """Magnus steps from 0 to ``s``: the dynamics grid below ``s`` and a last partial step."""
        x = s / self.rod.length
        grid = np.concatenate([[0.0], self.quadrature_points / self.rod.length, [1.0]])
        nodes = np.concatenate([grid[grid < x - 1e-14], [x]])
        if nodes.size == 1:  # s = 0
            return (
                np.zeros(0),
                np.zeros((0, *self._m.xi0s.shape[1:])),
                np.zeros((0, *self._m.bs.shape[1:])),
            )
        return self._steps(nodes)

    def pose(self, q, s) -> np.ndarray:
        """Pose ``g_s`` of the cross-section at arc length ``s`` (eq. (5)-(7))."""
        return self.jacobian(q, s, _pose_only=True)

    def jacobian(self, q, s, _pose_only=False) -> np.ndarray:
        """``J_s^s(q, s)`` (6 x n): ``qdot`` -> twist ``[w; v]`` of section ``s`` in its frame (eq. (9))."""
        q = self._q(q)
        h, xi0s, bs = self._chain_to(self._s(s))
        g, j, _ = K.chain_jacobian(
            q, np.zeros(self.n), self.floating, self._m.g_fixed, self._m.g_att, h, xi0s, bs
        )
        return g if _pose_only else j

    def jacobian_dot(self, q, qd, s) -> np.ndarray:
        """Time derivative of ``J_s^s`` along ``qdot``."""
        q, qd = self._q(q), self._q(qd, "qd")
        h, xi0s, bs = self._chain_to(self._s(s))
        _, _, jd = K.chain_jacobian(
            q, qd, self.floating, self._m.g_fixed, self._m.g_att, h, xi0s, bs
        )
        return jd

    def tip_pose(self, q) -> np.ndarray:
        """Tip pose ``g_L`` (the end of the dynamics grid)."""
        return self.tip_kinematics(q, np.zeros(self.n))[0]

    def tip_jacobian(self, q) -> np.ndarray:
        """``J_L^L(q)`` (6 x n), eq. (10)."""
        return self.tip_kinematics(q, np.zeros(self.n))[1]

    def tip_jacobian_dot(self, q, qd) -> np.ndarray:
        """Time derivative of ``J_L^L`` along ``qdot``."""
        return self.tip_kinematics(q, qd)[2]

    def tip_kinematics(self, q, qd):
        """Tip pose, Jacobian and Jacobian rate in one recursion."""
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        return K.chain_jacobian(q, qd, self.floating, m.g_fixed, m.g_att, m.h, m.xi0s, m.bs)

    def backbone(self, q, n_points: int = 21) -> np.ndarray:
        """Poses at ``n_points`` equally spaced arc lengths from 0 to L, shape (n_points, 4, 4).

        Uses order-4 Magnus steps between the points (exact for piecewise-constant strains; for
        richer bases the drawing accuracy is that of the point spacing)."""
        q = self._q(q)
        if n_points < 2:
            raise ValueError(f"n_points must be >= 2, got {n_points!r}")
        h, xi0s, bs = self._steps(np.linspace(0.0, 1.0, n_points))
        poses, g0, _ = K.chain_poses(q, self.floating, self._m.g_fixed, self._m.g_att, h, xi0s, bs)
        return np.concatenate([g0[None], poses])

    def strain(self, q, s) -> np.ndarray:
        """Strain twist ``xi(s) = xi* + B_q(s) q_s``."""
        q = self._q(q)
        x = self._s(s) / self.rod.length
        return np.asarray(self.rod.reference_strain) + self.rod.basis(x) @ q[self.n - self.n_s :]

    # ------------------------------------------------------------------ dynamics
    def terms(self, q, qd) -> Terms:
        """``M, C, D, K, tau_ext, B`` at ``(q, qdot)`` (paper eqs. (9)-(19))."""
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        mm, cc, _, tau, _, _, _ = K.coupled_terms(q, qd, m, self.loads.packed(), True)
        return Terms(mm, cc, m.damping.copy(), m.stiffness @ q, tau, K.input_matrix(q, m))

    def input_matrix(self, q) -> np.ndarray:
        """``B(q)``: ``u = [motor thrusts (4), tensions (n_a)]`` -> generalized forces (eq. (16))."""
        return K.input_matrix(self._q(q), self._m)

    def tendon_matrix(self, q) -> np.ndarray:
        """``B_s(q)`` (n_s x n_a), eq. (13)."""
        q = self._q(q)
        return K.tendon_matrix(q[self.n - self.n_s :], self._m)

    def tendon_lengths(self, q) -> np.ndarray:
        """Tendon path lengths ``l_i = int |k x d_i + u + d_i'| ds`` on the Gauss quadrature
        (the same discretization as :meth:`tendon_matrix`, so ``B_s = -dl/dq_s``)."""
        q = self._q(q)
        m = self._m
        qs = q[self.n - self.n_s :]
        xi = m.xi0g + np.einsum("gij,j->gi", m.bg, qs)
        v = np.cross(xi[:, None, :3], m.tendon_d) + xi[:, None, 3:] + m.tendon_dd
        return m.wq @ np.linalg.norm(v, axis=2)

    def forward_dynamics(self, q, qd, u=None) -> np.ndarray:
        """Generalized accelerations for inputs ``u = [4 thrusts, tensions]`` (tensions only for
        a fixed base); ``u = None`` means no input."""
        q, qd = self._q(q), self._q(qd, "qd")
        u = np.zeros(self.n_u) if u is None else self._u(u)
        self.check_regular(q)
        qdd, ok = K.forward_dynamics(q, qd, u, self._m, self.loads.packed())
        if not ok:
            raise SingularConfigurationError(
                f"the mass matrix is not positive definite at q = {q!r}"
            )
        return qdd

    def energy(self, q, qd) -> dict:
        """Kinetic and potential energies (J).

        ``potential`` = gravity (drone, rod, tip) + elastic ``1/2 q^T K q`` + the work potential
        of the conservative loads (``rod_force`` and ``tip_force``, constant inertial forces).
        Follower loads (``rod_wrench``, ``tip_wrench``, ``base_wrench``) have no potential.
        """
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        mm, _, _, _, g_tip, _, _ = K.coupled_terms(q, qd, m, self.loads.packed(), False)
        poses, _, gb = K.chain_poses(q, self.floating, m.g_fixed, m.g_att, m.h, m.xi0s, m.bs)
        grav = self.loads.gravity
        r_sections = poses[:-1, :3, 3]
        rod_pos = m.wq @ r_sections  # int r ds
        e_grav = -(m.mbar[3] * grav) @ rod_pos - m.tip6[3] * grav @ g_tip[:3, 3]
        if self.floating:
            e_grav -= self.base.mass * grav @ gb[:3, 3]
        e_loads = -self.loads.rod_force @ rod_pos - self.loads.tip_force @ g_tip[:3, 3]
        e_el = 0.5 * q @ m.stiffness @ q
        kin = 0.5 * qd @ mm @ qd
        pot = e_grav + e_el + e_loads
        return {
            "kinetic": kin,
            "gravity": e_grav,
            "elastic": e_el,
            "loads": e_loads,
            "potential": pot,
            "total": kin + pot,
        }

    def momentum(self, q, qd) -> np.ndarray:
        """Total linear momentum in the inertial frame (drone, rod sections, tip)."""
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        p = np.zeros(3)
        if self.floating:
            p += self.base.mass * qd[3:6]
        grid = np.concatenate([self.quadrature_points, [self.rod.length]])
        weights = np.concatenate([m.wq * m.mbar[3], [m.tip6[3]]])
        for s, w in zip(grid, weights, strict=True):
            if w == 0.0:
                continue
            g = self.pose(q, s)
            v = self.jacobian(q, s) @ qd
            p += w * g[:3, :3] @ v[3:]
        return p

    def natural_frequencies(self, q=None) -> np.ndarray:
        """Undamped natural frequencies (rad/s) of the rod coordinates linearized at ``q``
        (default: straight), with the base held: eigenvalues of ``(K_s, M_ss)``."""
        from scipy.linalg import eigh

        q = np.zeros(self.n) if q is None else self._q(q)
        if self.floating:
            self.check_regular(q)
        off = self.n - self.n_s
        m = self.terms(q, np.zeros(self.n)).M[off:, off:]
        k = self._m.stiffness[off:, off:]
        return np.sqrt(np.clip(eigh(k, m, eigvals_only=True), 0.0, None))

    def suggested_dt(self, safety: float = 1.0) -> float:
        """A stable, accurate RK4 step: ``min(10 ms, safety * 1.5 / w_max)``.

        RK4's stability limit on the imaginary axis is ``2.83 / w``; 1.5 keeps the fastest rod
        mode accurate to ~1 %.  The 10 ms cap (half the paper's control period) bounds the error
        of the slow drone-rod motion: for the paper system (``w_max = 3.3 rad/s``) 5 s of bent,
        swinging, tendon-loaded motion at 10 ms stay within 1e-6 m of the tip position of an
        adaptive DOP853 reference at rtol 1e-11 (2e-5 m at 20 ms).
        """
        w = float(self.natural_frequencies().max())
        return min(1e-2, safety * 1.5 / w) if w > 0 else 1e-2

    # ------------------------------------------------------------------ statics
    def static_equilibrium(
        self, u=None, q0=None, base_q=None, load_steps: int = 1, tol: float = 1e-12
    ):
        """Equilibrium strains ``q_s`` of the rod with the base held (fixed base, or the drone
        held at ``base_q = [phi, theta, psi, x, y, z]``) under inputs ``u`` and the loads.

        Solves ``K q + D*0 = B_s u + tau_ext`` restricted to the rod coordinates with Newton's
        method (finite-difference Jacobian; converged when the Newton step is below
        ``tol (1 + |q_s|)``), optionally ramping the loads and inputs over
        ``load_steps`` increments for large deflections.  Returns the full ``q``.
        """
        from .statics import solve_equilibrium

        return solve_equilibrium(self, u, q0, base_q, load_steps, tol)

    # ------------------------------------------------------------------ reporting
    def summary(self) -> str:
        rod, b = self.rod, self.base
        lines = [
            f"TD-ACM model: n = {self.n} generalized coordinates "
            f"({'6 drone + ' if self.floating else 'fixed base, '}{self.n_s} rod strains), "
            f"{self.n_u} inputs ({'4 motor thrusts + ' if self.floating else ''}{self.n_a} tendon tensions)",
            f"  rod: L = {rod.length} m, d = {rod.diameter * 1e3:g} mm, rho = {rod.density:g} kg/m^3, "
            f"E = {rod.youngs_modulus:.3g} Pa, nu = {rod.poisson_ratio}, eta = {rod.damping:g} Pa s",
            f"       mass = {rod.mass * 1e3:.2f} g, EI = {rod.bending_stiffness:.4g} N m^2, "
            f"tip mass = {rod.tip_mass * 1e3:g} g",
            f"  strain basis: {rod.basis.describe()}",
            f"  quadrature: {rod.n_gauss} Gauss-Legendre points, Magnus order {rod.magnus_order}",
            f"  tendons: {self.n_a}, max tension {self.tendons.max_tension:g} N",
        ]
        if self.floating:
            lines.append(
                f"  drone: m = {b.mass} kg, I = {[float(x) for x in b.inertia]} kg m^2, r_m = {b.arm_length} m, "
                f"k_d = {b.drag_factor} m, max thrust {b.max_thrust} N/motor"
            )
        else:
            lines.append("  base: fixed (clamped)")
        lines.append(
            f"  total mass = {self.total_mass:.4f} kg, gravity = {self.loads.gravity.tolist()}"
        )
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"TDACM(n={self.n}, n_s={self.n_s}, n_a={self.n_a}, floating={self.floating})"
