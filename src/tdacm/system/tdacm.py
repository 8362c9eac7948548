"""The coupled TD-ACM: a GVS Cosserat rod hanging from a quadrotor (or a clamp).

This is the thin, validated Python API over the numba kernels of :mod:`tdacm.system.kernels`.
Model data (parameters, precomputed quadrature and basis arrays) lives in the object; every
algorithm is a function of ``(q, qdot)``.

Conventions (paper section II, ``docs/model.md``): ``q = [phi, theta, psi, x, y, z, q_s]``
(ZYX Euler angles, inertial position of the drone's centre of mass; ``q = q_s`` for a fixed
base); poses are 4x4 in the inertial frame; Jacobians map ``qdot`` to the twist ``[w; v]`` of the
frame in that frame (local, angular first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from .. import paper_values as PV
from ..base import FixedBase, Quadrotor
from ..lie.euler import SINGULAR_COS
from ..lie.magnus import MAGNUS_POINTS
from ..rod import Rod, SectionedRod, Tendons
from . import kernels as K
from .forward import nonzero_columns, nonzero_rows, run_constants


def _row_ranges(*mats):
    """``(lo, hi)`` (n,) int: row ``i`` of every matrix in ``mats`` is zero outside the
    columns ``lo[i] <= c < hi[i]`` (``lo = hi = 0`` for a zero row)."""
    nz = np.zeros(mats[0].shape, bool)
    for a in mats:
        nz |= a != 0.0
    n = nz.shape[1]
    any_ = nz.any(axis=1)
    lo = np.where(any_, np.argmax(nz, axis=1), 0)
    hi = np.where(any_, n - np.argmax(nz[:, ::-1], axis=1), 0)
    return lo.astype(np.int64), hi.astype(np.int64)


class SingularConfigurationError(ValueError):
    """The ZYX Euler parameterization is singular (``theta = +-90 deg``)."""


def default_attachment(offset: float = PV.ATTACHMENT_OFFSET) -> np.ndarray:
    """``g_a^b``: the rod hangs ``offset`` metres below the drone's centre of mass, its backbone
    (local x) pointing along body -z, local y along body y and local z along body x
    (a rotation of +90 deg about body y)."""
    g = np.eye(4)
    g[:3, :3] = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    g[2, 3] = -offset
    return g


def energy_record(kinetic: float, gravity: float, elastic: float, loads: float) -> dict:
    """The energies of :meth:`TDACM.energy` (J) as its dict: the three potentials, their sum
    ``potential`` and ``total = kinetic + potential``."""
    pot = gravity + elastic + loads
    return {
        "kinetic": kinetic,
        "gravity": gravity,
        "elastic": elastic,
        "loads": loads,
        "potential": pot,
        "total": kinetic + pot,
    }


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


@dataclass(frozen=True)
class Arm:
    """One rod of a :class:`TDACM` with its tendons and attachment ``g_a^b``, and where its
    coordinates sit: ``strains`` indexes ``q`` (and ``qdot``), ``tensions`` indexes ``u``."""

    rod: Rod | SectionedRod
    tendons: Tendons
    attachment: np.ndarray
    strains: slice
    tensions: slice

    @property
    def sections(self) -> tuple:
        return self.rod.sections if isinstance(self.rod, SectionedRod) else (self.rod,)

    @property
    def length(self) -> float:
        return self.rod.length


@dataclass(frozen=True)
class _Section:
    """Build-time data of one section: its rod, place on its arm, coordinates and quadrature."""

    rod: Rod
    arm: int
    s0: float  # arc length of its start on the arm's rod (m)
    col: int  # first strain coordinate (index into q_s)
    xg: np.ndarray  # Gauss points, normalized on the section
    wg: np.ndarray  # their weights (summing to 1)


class TDACM:
    """Tendon-driven continuum rods on a quadrotor (or on a fixed base).

    Parameters
    ----------
    rod : :class:`~tdacm.rod.Rod` (one uniform section), :class:`~tdacm.rod.SectionedRod`
        (sections joined end to end), or a list of them for several rods on one base
    tendons : :class:`~tdacm.rod.Tendons` (a list, one per rod, for several rods)
    base : :class:`~tdacm.base.Quadrotor` (floating, underactuated) or :class:`FixedBase`
    attachment : ``g_a^b`` (4x4), pose of the rod base in the drone frame (a list, one per rod,
        required for several rods)
    loads : :class:`Loads` (gravity on by default); the rod and tip loads act on every rod

    Coordinates: ``q = [drone (6, floating only), strains of rod 1, rod 2, ...]``, each rod's
    strains section after section; inputs ``u = [4 thrusts (floating only), tensions of rod 1,
    rod 2, ...]``.  :attr:`arms` says where each rod's coordinates and tensions sit.  Methods that
    concern one rod (``pose``, ``jacobian``, ``tip_pose``, ``backbone``, ``strain``...) take
    ``rod=i`` (default 0).
    """

    def __init__(
        self,
        rod: Rod | SectionedRod | list | None = None,
        tendons: Tendons | list | None = None,
        base: Quadrotor | FixedBase | None = None,
        attachment: np.ndarray | list | None = None,
        loads: Loads | None = None,
    ):
        multi = isinstance(rod, list | tuple)
        rods = list(rod) if multi else [rod if rod is not None else Rod()]
        k = len(rods)
        if k < 1:
            raise ValueError("rod: a list of rods needs at least one rod")
        if multi:
            if tendons is None:
                tendons = [Tendons.parallel() for _ in rods]
            if not isinstance(tendons, list | tuple) or len(tendons) != k:
                raise ValueError(
                    f"tendons must be a list of {k} Tendons (one per rod), got {tendons!r}"
                )
            if not isinstance(attachment, list | tuple) or len(attachment) != k:
                raise ValueError(
                    f"attachment must be a list of {k} 4x4 poses (one per rod), got {attachment!r}"
                )
            tendon_sets, atts = list(tendons), list(attachment)
        else:
            tendon_sets = [tendons if tendons is not None else Tendons.parallel()]
            atts = [default_attachment() if attachment is None else attachment]
        self.base = base if base is not None else Quadrotor()
        for i, r in enumerate(rods):
            if not isinstance(r, Rod | SectionedRod):
                raise ValueError(
                    f"rod{f'[{i}]' if multi else ''} must be a Rod or a SectionedRod, got {r!r}"
                )
        for i, t in enumerate(tendon_sets):
            if not isinstance(t, Tendons):
                raise ValueError(f"tendons{f'[{i}]' if multi else ''} must be a Tendons, got {t!r}")
        if not isinstance(self.base, Quadrotor | FixedBase):
            raise ValueError(f"base must be a Quadrotor or a FixedBase, got {self.base!r}")
        atts = [
            V.transform(f"attachment[{i}]" if multi else "attachment", g)
            for i, g in enumerate(atts)
        ]
        self.floating = bool(self.base.floating)
        off, uoff = (6, 4) if self.floating else (0, 0)
        arms = []
        for r, t, g in zip(rods, tendon_sets, atts, strict=True):
            ns = r.n_strains if isinstance(r, SectionedRod) else r.basis.n
            t.end_lengths(r.length)  # validates the tendon ends against the rod
            arms.append(Arm(r, t, g, slice(off, off + ns), slice(uoff, uoff + t.n)))
            off, uoff = off + ns, uoff + t.n
        self.arms = tuple(arms)
        self.loads = loads if loads is not None else Loads()
        self._build()

    # single-rod views (the API of the paper system)
    def _single(self, what):
        if len(self.arms) != 1:
            raise AttributeError(
                f"this system has {len(self.arms)} rods: use system.arms[i].{what}"
            )
        return getattr(self.arms[0], what)

    rod = property(lambda self: self._single("rod"), doc="The rod (single-rod systems).")
    tendons = property(lambda self: self._single("tendons"), doc="The tendons (single-rod).")
    attachment = property(
        lambda self: self._single("attachment"), doc="``g_a^b`` (single-rod systems)."
    )

    @property
    def n_rods(self) -> int:
        return len(self.arms)

    # ------------------------------------------------------------------ construction
    def _section_steps(self, sec: _Section, nodes: np.ndarray):
        """Magnus step arrays between consecutive ``nodes`` (normalized on the section); the
        basis block is padded to the model's width."""
        rod = sec.rod
        frac = MAGNUS_POINTS[rod.magnus_order]
        x0 = nodes[:-1]
        dx = np.diff(nodes)
        xs = x0[:, None] + dx[:, None] * frac[None, :]
        bs = np.zeros((*xs.shape, 6, self._width))
        bs[..., : rod.basis.n] = rod.basis(xs.ravel()).reshape(*xs.shape, 6, rod.basis.n)
        xi0 = np.broadcast_to(np.asarray(rod.reference_strain), (*xs.shape, 6)).copy()
        return dx * rod.length, xi0, bs

    def _build(self):
        self.n_s = sum(a.strains.stop - a.strains.start for a in self.arms)
        self.n_a = sum(a.tendons.n for a in self.arms)
        self.n = self.n_s + (6 if self.floating else 0)
        self.n_u = self.n_a + (4 if self.floating else 0)
        off = self.n - self.n_s
        self._width = max(sec.basis.n for a in self.arms for sec in a.sections)
        stiffness = np.zeros((self.n, self.n))
        damping = np.zeros((self.n, self.n))
        st = {k: [] for k in ("h", "xi0s", "bs", "col", "nc", "w", "mass", "load", "s", "sec")}
        gp = {k: [] for k in ("wq", "xi0g", "bg", "col", "nc", "d", "dd", "on", "s")}
        rod_steps = [0]
        self._sections = []
        col = 0
        for ai, arm in enumerate(self.arms):
            length = arm.length
            ends = arm.tendons.end_lengths(length)
            t_lo = arm.tensions.start - (4 if self.floating else 0)
            secs = arm.sections
            starts = arm.rod.starts if isinstance(arm.rod, SectionedRod) else np.zeros(1)
            for si, rod in enumerate(secs):
                s0, ls = float(starts[si]), rod.length
                # split the quadrature where a tendon ends inside the section, so that every
                # tendon integrand is smooth on each Gauss interval
                tol = 1e-12 * length
                cuts = sorted({float(e) for e in ends if s0 + tol < e < s0 + ls - tol})
                xb = np.concatenate([[0.0], (np.array(cuts) - s0) / ls, [1.0]])
                x1, w1 = rod.quadrature()
                if xb.size == 2:
                    xg, wg = x1, w1
                else:
                    xg = np.concatenate(
                        [a + (b - a) * x1 for a, b in zip(xb[:-1], xb[1:], strict=True)]
                    )
                    wg = np.concatenate(
                        [(b - a) * w1 for a, b in zip(xb[:-1], xb[1:], strict=True)]
                    )
                sec = _Section(rod, ai, s0, col, xg, wg)
                self._sections.append(sec)
                h, xi0s, bs = self._section_steps(sec, np.concatenate([[0.0], xg, [1.0]]))
                nb = rod.basis.n
                ng = xg.size
                last = si == len(secs) - 1
                tip6 = np.diag(rod.tip_spatial_inertia).copy()
                has_tip = bool(np.any(tip6 > 0))
                st["h"].append(h)
                st["xi0s"].append(xi0s)
                st["bs"].append(bs)
                st["col"].append(np.full(ng + 1, col))
                st["nc"].append(np.full(ng + 1, nb))
                st["w"].append(np.r_[wg * ls, 1.0 if (last or has_tip) else 0.0])
                st["mass"].append(np.vstack([np.tile(np.diag(rod.inertia_density), (ng, 1)), tip6]))
                st["load"].append(
                    np.r_[np.full(ng, K.LOAD_DISTRIBUTED), K.LOAD_TIP if last else K.LOAD_GRAVITY]
                )
                st["s"].append(s0 + ls * np.r_[xg, 1.0])
                st["sec"].append(np.full(ng + 1, len(self._sections) - 1))
                bg = rod.basis(xg)
                bgp = np.zeros((ng, 6, self._width))
                bgp[..., :nb] = bg
                sg = s0 + ls * xg
                gp["wq"].append(wg * ls)
                gp["xi0g"].append(np.broadcast_to(np.asarray(rod.reference_strain), (ng, 6)))
                gp["bg"].append(bgp)
                gp["col"].append(np.full(ng, col))
                gp["nc"].append(np.full(ng, nb))
                gp["s"].append(sg)
                d = np.zeros((ng, self.n_a, 3))
                dd = np.zeros((ng, self.n_a, 3))
                on = np.zeros((ng, self.n_a))
                da, dda = arm.tendons.at(sg / length, length)
                na = arm.tendons.n
                d[:, t_lo : t_lo + na] = da
                dd[:, t_lo : t_lo + na] = dda
                on[:, t_lo : t_lo + na] = (sg[:, None] < ends[None, :]).astype(float)
                gp["d"].append(d)
                gp["dd"].append(dd)
                gp["on"].append(on)
                hbar, dbar = rod.stiffness_density, rod.damping_density
                ks = np.einsum("g,gai,ab,gbj->ij", wg * ls, bg, hbar, bg)
                ds = np.einsum("g,gai,ab,gbj->ij", wg * ls, bg, dbar, bg)
                c0 = off + col
                stiffness[c0 : c0 + nb, c0 : c0 + nb] = ks
                damping[c0 : c0 + nb, c0 : c0 + nb] = ds
                col += nb
            rod_steps.append(sum(x.size for x in st["h"]))
        cat = {k: np.concatenate(v) for k, v in st.items()}
        gcat = {k: np.concatenate(v) for k, v in gp.items()}
        self._step_s, self._step_sec = cat["s"], cat["sec"].astype(np.int64)
        self._rod_steps = np.array(rod_steps, dtype=np.int64)
        self.quadrature_points = gcat["s"]
        if self.floating:
            mb6 = np.diag(self.base.spatial_inertia).copy()
            gamma = self.base.gamma
            g_fixed = np.eye(4)
        else:
            mb6 = np.zeros(6)
            gamma = np.zeros((6, 4))
            g_fixed = self.base.pose
        c = np.ascontiguousarray
        i64 = lambda x: np.ascontiguousarray(x, dtype=np.int64)  # noqa: E731
        self._m = K.ModelArrays(
            self.floating,
            c(g_fixed),
            c(np.stack([a.attachment for a in self.arms])),
            self._rod_steps,
            c(cat["h"]),
            c(cat["xi0s"]),
            c(cat["bs"]),
            i64(cat["col"]),
            i64(cat["nc"]),
            c(cat["w"]),
            c(cat["mass"]),
            i64(cat["load"]),
            mb6,
            stiffness,
            damping,
            c(gamma),
            c(gcat["wq"]),
            c(gcat["xi0g"]),
            c(gcat["bg"]),
            i64(gcat["col"]),
            i64(gcat["nc"]),
            c(gcat["d"]),
            c(gcat["dd"]),
            c(gcat["on"]),
            *run_constants(cat["h"], cat["xi0s"], cat["bs"]),
            *nonzero_columns(c(gcat["bg"])),
            *nonzero_rows(c(gcat["bg"])),
            *_row_ranges(stiffness, damping),
        )

    @property
    def model_arrays(self) -> K.ModelArrays:
        """The constant arrays handed to the kernels (read-only by convention)."""
        return self._m

    @property
    def total_mass(self) -> float:
        mb = self.base.mass if self.floating else 0.0
        return mb + sum(a.rod.mass + a.rod.tip_mass for a in self.arms)

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

    def _arm(self, rod) -> int:
        if not isinstance(rod, int | np.integer) or not 0 <= rod < len(self.arms):
            raise ValueError(f"rod must be an index in [0, {len(self.arms)}), got {rod!r}")
        return int(rod)

    def _s(self, s, rod=0) -> float:
        s = V.finite_scalar("s", s)
        length = self.arms[rod].length
        if not -1e-12 <= s <= length * (1 + 1e-12):
            raise ValueError(f"s must lie in [0, L = {length}], got {s!r}")
        return min(max(s, 0.0), length)

    # ------------------------------------------------------------------ kinematics
    def base_pose(self, q) -> np.ndarray:
        """Drone pose ``g_b`` (eq. (1)); the clamp pose for a fixed base."""
        q = self._q(q)

        def compute():  # asked for four times a control period at the same q
            return K.base_state(q, np.zeros(self.n), self.floating, self._m.g_fixed, self.n)[0]

        return self._memo("_base_cache", q.tobytes(), compute, 1).copy()

    def _memo(self, slot: str, key, compute, size: int):
        """``compute()`` kept in ``self.<slot>`` for the last ``size`` keys (the control
        period asks for the same configuration's kinematics several times); the entries
        belong to the current model arrays, so a rebuilt model misses."""
        cache = self.__dict__.get(slot)
        if cache is None or cache[0] is not self._m:
            cache = (self._m, {})
            setattr(self, slot, cache)
        hit = cache[1].get(key)
        if hit is None:
            if len(cache[1]) >= size:
                cache[1].clear()
            hit = cache[1][key] = compute()
        return hit

    def _rod_chain(self, rod):
        m, lo, hi = self._m, self._rod_steps[rod], self._rod_steps[rod + 1]
        return m.h[lo:hi], m.xi0s[lo:hi], m.bs[lo:hi], m.step_col[lo:hi], m.step_nc[lo:hi]

    def _chain_to(self, s: float, rod: int = 0):
        """Magnus steps from 0 to ``s`` on rod ``rod``: the model's steps ending below ``s`` and
        a last partial step inside the section holding ``s``."""
        h, xi0s, bs, cols, ncs = self._rod_chain(rod)
        if s <= 1e-14:
            return h[:0], xi0s[:0], bs[:0], cols[:0], ncs[:0]
        lo = self._rod_steps[rod]
        ends = self._step_s[lo : self._rod_steps[rod + 1]]
        k = int(np.count_nonzero(ends < s - 1e-14))  # steps are ordered along the rod
        sec = self._sections[self._step_sec[lo + k]]
        start = ends[k - 1] if k > 0 else 0.0
        ls = sec.rod.length
        x = np.array([max(start - sec.s0, 0.0) / ls, (s - sec.s0) / ls])
        h2, xi2, bs2 = self._section_steps(sec, x)
        return (
            np.concatenate([h[:k], h2]),
            np.concatenate([xi0s[:k], xi2]),
            np.concatenate([bs[:k], bs2]),
            np.r_[cols[:k], sec.col].astype(np.int64),
            np.r_[ncs[:k], sec.rod.basis.n].astype(np.int64),
        )

    def pose(self, q, s, rod: int = 0) -> np.ndarray:
        """Pose ``g_s`` of the cross-section at arc length ``s`` of rod ``rod`` (eq. (5)-(7))."""
        return self.jacobian(q, s, rod, _pose_only=True)

    def jacobian(self, q, s, rod: int = 0, _pose_only=False) -> np.ndarray:
        """``J_s^s(q, s)`` (6 x n): ``qdot`` -> twist ``[w; v]`` of section ``s`` in its frame (eq. (9))."""
        q = self._q(q)
        rod = self._arm(rod)
        chain = self._chain_to(self._s(s, rod), rod)
        m = self._m
        g, j, _ = K.chain_jacobian(
            q, np.zeros(self.n), self.floating, m.g_fixed, m.g_att[rod], *chain
        )
        return g if _pose_only else j

    def jacobian_dot(self, q, qd, s, rod: int = 0) -> np.ndarray:
        """Time derivative of ``J_s^s`` along ``qdot``."""
        q, qd = self._q(q), self._q(qd, "qd")
        rod = self._arm(rod)
        chain = self._chain_to(self._s(s, rod), rod)
        m = self._m
        _, _, jd = K.chain_jacobian(q, qd, self.floating, m.g_fixed, m.g_att[rod], *chain)
        return jd

    def tip_pose(self, q, rod: int = 0) -> np.ndarray:
        """Tip pose ``g_L`` (the end of the dynamics grid) of rod ``rod``."""
        return self._tip_static(q, rod)[0].copy()

    def tip_jacobian(self, q, rod: int = 0) -> np.ndarray:
        """``J_L^L(q)`` (6 x n), eq. (10)."""
        return self._tip_static(q, rod)[1].copy()

    def _tip_static(self, q, rod: int):
        """``(g_L, J_L^L)`` at ``q``, kept for the last few configurations: a control period
        asks for the tip pose of the same ``q`` several times (the camera sensor, the servo,
        the logger's truth) and for the Jacobian at the servo's ``q``; the recursion is the
        costly part. The entries belong to the current model arrays (rebuilt models miss)."""
        q = self._q(q)

        def compute():
            return self.tip_kinematics(q, np.zeros(self.n), rod)[:2]

        return self._memo("_tip_cache", (rod, q.tobytes()), compute, 4)

    def tip_jacobian_dot(self, q, qd, rod: int = 0) -> np.ndarray:
        """Time derivative of ``J_L^L`` along ``qdot``."""
        return self.tip_kinematics(q, qd, rod)[2]

    def tip_kinematics(self, q, qd, rod: int = 0):
        """Tip pose, Jacobian and Jacobian rate in one recursion."""
        q, qd = self._q(q), self._q(qd, "qd")
        rod = self._arm(rod)
        m = self._m
        return K.chain_jacobian(
            q, qd, self.floating, m.g_fixed, m.g_att[rod], *self._rod_chain(rod)
        )

    def backbone(self, q, n_points: int = 21, rod: int = 0) -> np.ndarray:
        """Poses at ``n_points`` equally spaced arc lengths from 0 to L, shape (n_points, 4, 4).

        Uses order-4 Magnus steps between the points (exact for piecewise-constant strains; for
        richer bases the drawing accuracy is that of the point spacing); the section joints
        are extra nodes."""
        q = self._q(q)
        rod = self._arm(rod)
        if n_points < 2:
            raise ValueError(f"n_points must be >= 2, got {n_points!r}")
        xp = np.linspace(0.0, 1.0, n_points)
        arm = self.arms[rod]
        secs = [sec for sec in self._sections if sec.arm == rod]
        if len(secs) == 1:
            chain = (*self._section_steps(secs[0], xp), *self._cols(secs[0], n_points - 1))
            keep = np.arange(n_points - 1)
        else:
            sp = xp * arm.length
            parts, ends = [], []
            for sec in secs:
                ls = sec.rod.length
                inner = sp[(sp > sec.s0 + 1e-12 * ls) & (sp < sec.s0 + ls - 1e-12 * ls)]
                nodes = np.concatenate([[0.0], (inner - sec.s0) / ls, [1.0]])
                parts.append((*self._section_steps(sec, nodes), *self._cols(sec, nodes.size - 1)))
                ends.append(sec.s0 + ls * nodes[1:])
            chain = tuple(np.concatenate([p[i] for p in parts]) for i in range(5))
            ends = np.concatenate(ends)
            keep = np.array([int(np.argmin(np.abs(ends - x))) for x in sp[1:]])
        m = self._m
        poses, g0, _ = K.chain_poses(q, self.floating, m.g_fixed, m.g_att[rod], *chain)
        return np.concatenate([g0[None], poses[keep]])

    @staticmethod
    def _cols(sec, k):
        return np.full(k, sec.col, dtype=np.int64), np.full(k, sec.rod.basis.n, dtype=np.int64)

    def strain(self, q, s, rod: int = 0) -> np.ndarray:
        """Strain twist ``xi(s) = xi* + B_q(s) q_s`` of rod ``rod`` (the first section at a joint)."""
        q = self._q(q)
        rod = self._arm(rod)
        s = self._s(s, rod)
        arm = self.arms[rod]
        si = arm.rod.section_at(s) if isinstance(arm.rod, SectionedRod) else 0
        sec = [x for x in self._sections if x.arm == rod][si]
        x = min(max((s - sec.s0) / sec.rod.length, 0.0), 1.0)
        c0 = self.n - self.n_s + sec.col
        qs = q[c0 : c0 + sec.rod.basis.n]
        return np.asarray(sec.rod.reference_strain) + sec.rod.basis(x) @ qs

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
        """Tendon path lengths ``l_i = int_0^{end_i} |k x d_i + u + d_i'| ds`` on the Gauss
        quadrature (the same discretization as :meth:`tendon_matrix`, so ``B_s = -dl/dq_s``)."""
        q = self._q(q)
        return K.tendon_lengths_and_matrix(q[self.n - self.n_s :], self._m)[0]

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

        ``potential`` = gravity (drone, rods, joint and tip bodies) + elastic ``1/2 q^T K q`` +
        the work potential of the conservative loads (``rod_force`` and ``tip_force``, constant
        inertial forces).  Follower loads (``rod_wrench``, ``tip_wrench``, ``base_wrench``) have
        no potential.
        """
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        mm, _, _, _, _, _, _ = K.coupled_terms(q, qd, m, self.loads.packed(), False)
        grav = self.loads.gravity
        e_grav = 0.0
        rod_pos = np.zeros(3)  # int r ds over the rods
        tip_pos = np.zeros(3)  # sum of the tip positions
        zero = np.zeros(self.n)
        for rod in range(len(self.arms)):
            poses, _ = K.chain_frames(q, zero, m, rod)
            sl = slice(self._rod_steps[rod], self._rod_steps[rod + 1])
            r = poses[:, :3, 3]
            w, mass, load = m.step_w[sl], m.step_mass[sl, 3], m.step_load[sl]
            e_grav -= (w * mass) @ r @ grav
            dist = load == K.LOAD_DISTRIBUTED
            rod_pos += w[dist] @ r[dist]
            tip_pos += r[load == K.LOAD_TIP].sum(axis=0)
        if self.floating:
            gb = self.base_pose(q)
            e_grav -= self.base.mass * grav @ gb[:3, 3]
        e_loads = -self.loads.rod_force @ rod_pos - self.loads.tip_force @ tip_pos
        e_el = 0.5 * q @ m.stiffness @ q
        kin = 0.5 * qd @ mm @ qd
        return energy_record(kin, e_grav, e_el, e_loads)

    def momentum(self, q, qd) -> np.ndarray:
        """Total linear momentum in the inertial frame (drone, rod sections, joint and tip bodies)."""
        q, qd = self._q(q), self._q(qd, "qd")
        m = self._m
        p = np.zeros(3)
        if self.floating:
            p += self.base.mass * qd[3:6]
        for rod in range(len(self.arms)):
            poses, twists = K.chain_frames(q, qd, m, rod)
            sl = slice(self._rod_steps[rod], self._rod_steps[rod + 1])
            wm = m.step_w[sl] * m.step_mass[sl, 3]
            p += np.einsum("k,kij,kj->i", wm, poses[:, :3, :3], twists[:, 3:])
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

    def suggested_dt(self, safety: float = 1.0, q=None) -> float:
        """A stable, accurate RK4 step: ``min(10 ms, safety * 1.5 / w_max)``, ``w_max`` the
        highest rod frequency linearized at ``q`` (default: straight; a sequence of
        configurations takes the highest over them).

        RK4's stability limit on the imaginary axis is ``2.83 / w``; 1.5 keeps the fastest rod
        mode accurate to ~1 %.  The 10 ms cap (half the paper's control period) bounds the error
        of the slow drone-rod motion: for the paper system (``w_max = 3.3 rad/s``) 5 s of bent,
        swinging, tendon-loaded motion at 10 ms stay within 1e-6 m of the tip position of an
        adaptive DOP853 reference at rtol 1e-11 (2e-5 m at 20 ms).

        Bending can raise the highest mode a lot in rich bases (measured: a clamped
        ``StrainBasis.full(0)`` rod, 9,900 rad/s straight, 26,600 rad/s bent; RK4 at the
        straight-rod step failed on the first step there): pass the configurations the run
        will visit, or use ``simulate(method="auto")``, which integrates such bases with Radau.
        """
        qs = [None] if q is None else ([q] if np.ndim(q) == 1 else list(q))
        w = max(float(self.natural_frequencies(qi).max()) for qi in qs)
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
        b = self.base
        rods = f"{self.n_rods} rods, " if self.n_rods > 1 else ""
        lines = [
            f"TD-ACM model: n = {self.n} generalized coordinates "
            f"({'6 drone + ' if self.floating else 'fixed base, '}{rods}{self.n_s} rod strains), "
            f"{self.n_u} inputs ({'4 motor thrusts + ' if self.floating else ''}{self.n_a} tendon tensions)",
        ]
        for i, arm in enumerate(self.arms):
            if self.n_rods > 1:
                p = arm.attachment[:3, 3]
                lines.append(
                    f"  rod {i}: q[{arm.strains.start}:{arm.strains.stop}], "
                    f"u[{arm.tensions.start}:{arm.tensions.stop}], attached at {p.round(4).tolist()} m"
                )
            secs = arm.sections
            if len(secs) > 1:
                lines.append(
                    f"  sectioned rod: {len(secs)} sections, L = {arm.length:g} m, "
                    f"mass = {arm.rod.mass * 1e3:.2f} g, tip mass = {arm.rod.tip_mass * 1e3:g} g"
                )
            for j, rod in enumerate(secs):
                pre = f"  section {j}: " if len(secs) > 1 else "  rod: "
                pad = " " * len(pre)
                lines += [
                    f"{pre}L = {rod.length} m, d = {rod.diameter * 1e3:g} mm, rho = {rod.density:g} kg/m^3, "
                    f"E = {rod.youngs_modulus:.3g} Pa, nu = {rod.poisson_ratio}, eta = {rod.damping:g} Pa s",
                    f"{pad}mass = {rod.mass * 1e3:.2f} g, EI = {rod.bending_stiffness:.4g} N m^2, "
                    f"{'tip' if j == len(secs) - 1 else 'joint'} mass = {rod.tip_mass * 1e3:g} g",
                    f"{pad}strain basis: {rod.basis.describe()}",
                    f"{pad}quadrature: {rod.n_gauss} Gauss-Legendre points, Magnus order {rod.magnus_order}",
                ]
            t = arm.tendons
            ends = ""
            if t.ends is not None:
                ends = (
                    ", anchored at s = " + str(t.end_lengths(arm.length).round(4).tolist()) + " m"
                )
            lines.append(f"  tendons: {t.n}, max tension {t.max_tension:g} N{ends}")
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
        rods = f", rods={self.n_rods}" if self.n_rods > 1 else ""
        return f"TDACM(n={self.n}, n_s={self.n_s}, n_a={self.n_a}, floating={self.floating}{rods})"
