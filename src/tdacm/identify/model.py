"""The model the fit adjusts: a TD-ACM rebuilt from parameter values, simulated segment-wise.

:class:`IdentModel` keeps the structure of a recording's robot (rod geometry and basis, tendon
routing, base, attachment, gravity) and rebuilds the :class:`~tdacm.system.TDACM` for any
values of the :data:`~tdacm.identify.params.PARAMETERS`; :meth:`IdentModel.simulate` runs the
segments of a multiple-shooting fit and returns the measured poses (drone and tip).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from .. import paper_values as PV
from ..rod import Rod, Tendons
from ..system import TDACM, Loads
from ..system import kernels as K
from . import kernels as IK
from .params import FRICTION_V0, PARAMETERS

#: ``|lambda|_max dt`` above which the shooting steps are ROS34PW2 instead of RK4 (RK4 is
#: stable to 2.79 on the negative real axis; 1.5 keeps a margin for the trial models).
RK4_LIMIT = 1.5

#: The segments run on every numba thread only on the ROS34PW2 path (a step costs ``n + 4``
#: evaluations of the dynamics and an LU: a call lasts long); an RK4 call of a few
#: milliseconds runs on one thread. Measured on the shared 2-core machine at load average
#: 17-22: a ``bending:2`` (ROS34PW2) Jacobian 41 s wall on two threads against 64 s on one,
#: but the five main parameters (RK4) 23-36 s on two against 14-21 s on one: thousands of
#: short parallel loops, each waiting at its end for a thread the busy machine preempted.
#: The result is the same to the bit either way.
PARALLEL_STIFF_ONLY = True


@dataclass
class Prediction:
    """States and poses of every sample of every segment (T rows), ``ok`` False when a segment
    hit a singular mass matrix or a non-finite state."""

    q: np.ndarray
    qd: np.ndarray
    base: np.ndarray  # (T, 4, 4)
    tip: np.ndarray  # (T, 4, 4)
    ok: bool


def _basis_text(basis) -> str:
    """``"bending:P"`` when ``basis`` is one, else its description."""
    from ..sim.robot import parse_basis

    for p in range(8):
        if basis == parse_basis(f"bending:{p}"):
            return f"bending:{p}"
    return basis.describe()


class IdentModel:
    """A single-rod TD-ACM whose physical parameters can be replaced.

    ``system`` gives the structure and the nominal values; ``tip_mount`` (``g_{C_L}^L``) and the
    camera offset are used by camera measurements only.
    """

    def __init__(
        self,
        system: TDACM,
        tip_mount: np.ndarray | None = None,
        camera_offset=PV.LOCAL_CAMERA_OFFSET,
    ):
        if system.n_rods != 1 or not isinstance(system.rod, Rod):
            raise ValueError("identification supports one uniform rod (a Rod, not sectioned)")
        t = system.tendons
        if t.offset_function is not None:
            raise ValueError("identification supports parallel tendons (constant offsets)")
        self.system = system
        self.floating = system.floating
        self.tip_mount = np.eye(4) if tip_mount is None else np.asarray(tip_mount, float)
        radius = float(np.max(np.linalg.norm(t.offsets, axis=1)))
        base = system.base
        self.nominal = {
            "E": system.rod.youngs_modulus,
            "damping": system.rod.damping,
            "tip_mass": system.rod.tip_mass,
            "radius": radius,
            "friction": 0.0,
            "viscous": 0.0,
            "camera_offset": float(camera_offset),
        }
        if self.floating:
            self.nominal.update(
                drone_mass=base.mass,
                inertia_x=base.inertia[0],
                inertia_y=base.inertia[1],
                inertia_z=base.inertia[2],
                thrust=1.0,
            )
        self._cache_key = None
        self._cache = None
        self._basis_text = _basis_text(system.rod.basis)
        self._rate = None

    @property
    def basis(self) -> str:
        """The rod's strain basis as a scenario writes it (``robot.rod.basis``)."""
        return self._basis_text

    def with_basis(self, text: str) -> IdentModel:
        """The same robot with the rod's strain basis ``text`` (``"bending:P"``, ``"full:P"``,
        ``"modes:..."``; the quadrature of :func:`tdacm.sim.robot.rod_quadrature`)."""
        from ..sim.robot import parse_basis, rod_quadrature

        basis = parse_basis(text)
        n_gauss, magnus = rod_quadrature(basis)
        s = self.system
        rod = replace(s.rod, basis=basis, n_gauss=n_gauss, magnus_order=magnus)
        sysnew = TDACM(rod, s.tendons, s.base, s.attachment, Loads(gravity=s.loads.gravity.copy()))
        out = IdentModel(sysnew, self.tip_mount, self.nominal["camera_offset"])
        out._basis_text = text
        return out

    def check(self, names) -> None:
        for n in names:
            if PARAMETERS[n].floating_only and not self.floating:
                raise ValueError(f"{n} needs a flying base; this recording's base is fixed")

    def values(self, overrides: dict | None = None) -> dict:
        v = dict(self.nominal)
        v.update(overrides or {})
        return v

    def build(self, overrides: dict | None = None) -> TDACM:
        """The system with ``overrides`` (parameter name -> value) replacing the nominal ones."""
        v = self.values(overrides)
        key = tuple(sorted((k, float(x)) for k, x in v.items()))
        if key == self._cache_key:
            return self._cache
        s = self.system
        rod = replace(s.rod, youngs_modulus=v["E"], damping=v["damping"], tip_mass=v["tip_mass"])
        t = s.tendons
        scale = v["radius"] / self.nominal["radius"]
        tendons = Tendons(offsets=t.offsets * scale, max_tension=t.max_tension, ends=t.ends)
        base = s.base
        if self.floating:
            base = replace(
                base,
                mass=v["drone_mass"],
                inertia=(v["inertia_x"], v["inertia_y"], v["inertia_z"]),
            )
        loads = Loads(gravity=s.loads.gravity.copy())
        sysnew = TDACM(rod, tendons, base, s.attachment, loads)
        self._cache_key, self._cache = key, sysnew
        return sysnew

    def fastest_rate(self, values: dict | None = None) -> float:
        """The largest ``|lambda|`` (1/s) of the dynamics linearized about the straight rod at
        rest (finite differences of the forward dynamics, eq. (17)) with ``values`` (default
        nominal, cached): the damped higher modes of a richer basis set it (4.7 1/s for the
        paper robot's bending:0, 160 for bending:2, 1200 for bending:3 at the synthetic
        truth's damping)."""
        if values is None and getattr(self, "_rate", None) is not None:
            return self._rate
        sysm = self.build(self.values(values))
        m, loads = sysm.model_arrays, sysm.loads.packed()
        n = sysm.n
        q, qd, u = np.zeros(n), np.zeros(n), np.zeros(sysm.n_u)
        a0, _ = K.forward_dynamics(q, qd, u, m, loads)
        jac = np.zeros((2 * n, 2 * n))
        jac[:n, n:] = np.eye(n)
        for j in range(2 * n):
            x = np.zeros(2 * n)
            x[j] = 1e-6
            aj, _ = K.forward_dynamics(q + x[:n], qd + x[n:], u, m, loads)
            jac[n:, j] = (aj - a0) / 1e-6
        rate = float(np.max(np.abs(np.linalg.eigvals(jac))))
        if values is None:
            self._rate = rate
        return rate

    def simulate(self, values: dict, q0s, qd0s, starts, ends, u, dt_sample, substeps=1):
        """Run the segments (see :func:`tdacm.identify.kernels.shoot`) with parameters
        ``values`` and return their :class:`Prediction`. The step ``dt_sample / substeps`` is
        taken by RK4, or by the L-stable ROS34PW2 when ``|lambda|_max dt`` at the nominal
        values exceeds :data:`RK4_LIMIT` (:meth:`fastest_rate`; a property of the structure and
        the step, so every trial model of a fit uses the same integrator). The segments run in
        parallel over the cores on the ROS34PW2 path (:meth:`simulate_many`)."""
        starts = np.asarray(starts, dtype=np.int64)
        ends = np.asarray(ends, dtype=np.int64)
        return self.simulate_many(values, q0s, qd0s, starts, ends - starts, starts,
                                  int(ends[-1]), u, dt_sample, substeps)  # fmt: skip

    def simulate_many(self, values: dict, q0s, qd0s, in0, lengths, out0, total, u, dt_sample,
                      substeps=1) -> Prediction:  # fmt: skip
        """Independent segments with parameters ``values``, in parallel over the cores
        (:func:`tdacm.identify.kernels.shoot_many`; on one thread on the RK4 path, see
        :data:`PARALLEL_STIFF_ONLY`): segment ``i`` starts at ``(q0s[i],
        qd0s[i])``, reads the inputs from row ``in0[i]`` of ``u`` and fills ``lengths[i]`` rows
        from ``out0[i]`` of the ``total`` rows returned (integrator as :meth:`simulate`)."""
        stiff = self.fastest_rate() * dt_sample / substeps > RK4_LIMIT
        v = self.values(values)
        sysm = self.build(v)
        dt = dt_sample / substeps
        threads = numba.get_num_threads()
        if PARALLEL_STIFF_ONLY and not stiff:
            numba.set_num_threads(1)
        try:
            q, qd, ok, base, tip = self._shoot_many(sysm, v, q0s, qd0s, in0, lengths, out0,
                                                    total, u, substeps, dt, stiff)  # fmt: skip
        finally:
            numba.set_num_threads(threads)
        return Prediction(q, qd, base, tip, bool(np.all(ok)))

    def _shoot_many(self, sysm, v, q0s, qd0s, in0, lengths, out0, total, u, substeps, dt, stiff):
        m = sysm.model_arrays
        q, qd, ok = IK.shoot_many(
            np.ascontiguousarray(q0s, dtype=float),
            np.ascontiguousarray(qd0s, dtype=float),
            np.asarray(in0, dtype=np.int64),
            np.asarray(lengths, dtype=np.int64),
            np.asarray(out0, dtype=np.int64),
            int(total),
            np.ascontiguousarray(u, dtype=float),
            int(substeps),
            float(dt),
            m,
            sysm.loads.packed(),
            float(v.get("thrust", 1.0)),
            float(v["friction"]),
            float(v["viscous"]),
            FRICTION_V0,
            stiff,
        )
        base, tip = self.poses(sysm, q, parallel=True)
        return q, qd, ok, base, tip

    def camera_mount(self, offset=None) -> np.ndarray:
        """``g_{C_L}^L`` with the optical centre ``offset`` beyond the tip (default nominal)."""
        g = self.tip_mount.copy()
        g[:3, 3] = [self.nominal["camera_offset"] if offset is None else offset, 0.0, 0.0]
        return g

    @staticmethod
    def poses(system: TDACM, q: np.ndarray, parallel: bool = False):
        """Drone and tip poses (T, 4, 4) of the rows of ``q`` (``parallel``: over the cores,
        the same result)."""
        m = system.model_arrays
        lo, hi = m.rod_steps[0], m.rod_steps[1]
        return (IK.poses_many if parallel else IK.poses)(
            np.ascontiguousarray(q, dtype=float),
            m.floating,
            m.g_fixed,
            m.g_att[0],
            m.h[lo:hi],
            m.xi0s[lo:hi],
            m.bs[lo:hi],
            m.step_col[lo:hi],
            m.step_nc[lo:hi],
        )
