"""The model kernels against frozen outputs (``data/kernel_reference.npz``).

The file holds the states and the outputs of ``forward_dynamics_env``, ``coupled_terms_env``
(with and without ``C``), ``input_matrix``, ``chain_jacobian`` and a short ``rk4_run_env`` for
systems that cover every branch of the recursion: the paper system (order-2 Magnus steps, one
section), an 18-DoF rod (torsion and both bendings of order 3, order-4 Magnus steps), a
two-section floating rod with tendons ending part-way, two rods on one drone, a clamped
two-section rod, and the paper system with aerodynamics and contact.  It was written once by
running this module (``python tests/system/test_kernel_reference.py``) with the kernels as they
were before their rewrite for speed; the rewritten kernels must reproduce it to 1e-12
(relative to each array's largest entry, and absolutely below 1e-12 for arrays of zeros).

Do not regenerate the file to make the test pass: it is the reference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tdacm
from tdacm.aero import Aerodynamics
from tdacm.contact import ContactModel, Plane
from tdacm.rod import StrainBasis
from tdacm.system import kernels as K
from tdacm.system.aero import aero_array
from tdacm.system.contact import contact_array

DATA = Path(__file__).parent / "data" / "kernel_reference.npz"
N_STATES = 4
TOL = 1e-12


def _sectioned_floating():
    s1 = tdacm.Rod(length=0.5, basis=StrainBasis.bending(1), tip_mass=0.003)
    s2 = tdacm.Rod(length=0.5, diameter=1.5e-3, basis=StrainBasis((1, 1, 1, None, None, None)))
    tendons = tdacm.Tendons.parallel(0.01, count=4, ends=[0.5, 0.5, None, 0.8])
    return tdacm.TDACM(tdacm.SectionedRod([s1, s2]), tendons, tdacm.Quadrotor())


def _clamped_sections():
    s1 = tdacm.Rod(length=0.4, diameter=2e-3, damping=0.01, basis=StrainBasis.bending(2))
    s2 = tdacm.Rod(
        length=0.6, diameter=2.5e-3, youngs_modulus=7e10, basis=StrainBasis.bending(1),
        tip_mass=0.005,
    )  # fmt: skip
    tendons = tdacm.Tendons(offsets=[[0.0, 0.01, 0.0], [0.0, 0.0, 0.01]], ends=[0.4, None])
    return tdacm.TDACM(
        tdacm.SectionedRod([s1, s2]),
        tendons,
        tdacm.FixedBase(),
        attachment=np.eye(4),
        loads=tdacm.Loads(gravity=(0.0, 0.0, -9.81)),
    )


def _systems():
    """name -> (system, aero array, contact array)."""
    paper = tdacm.paper_system()
    rich = tdacm.paper_system(
        basis=StrainBasis((3, 3, 3, None, None, None)), n_gauss=8, magnus_order=4
    )
    out = {
        "paper": (paper, np.empty(0), np.empty(0)),
        "rich": (rich, np.empty(0), np.empty(0)),
        "sectioned": (_sectioned_floating(), np.empty(0), np.empty(0)),
        "dual": (tdacm.dual_paper_system(basis=StrainBasis.bending(1)), np.empty(0), np.empty(0)),
        "clamped": (_clamped_sections(), np.empty(0), np.empty(0)),
    }
    q, _, _ = _state(paper, 0)
    tip = paper.tip_pose(q)[:3, 3]
    plane = Plane(tuple(tip + [0.0, 0.0, 0.01]), (0.3, 0.1, -1.0))
    env = (
        paper,
        aero_array(paper, Aerodynamics(), wind=(1.5, -0.5, 0.2)),
        contact_array(paper, ContactModel(obstacles=(plane,), tip_radius=0.02)),
    )
    out["paper_env"] = env
    return out


def _state(system, k):
    rng = np.random.default_rng(1000 + k)
    q = rng.normal(size=system.n) * 0.4
    qd = rng.normal(size=system.n)
    u = np.abs(rng.normal(size=system.n_u)) * 2.0
    if system.floating:
        q[0:3] *= 0.5
        q[3:6] += [0.2, -0.1, 3.0]
    return q, qd, u


def _outputs(system, aero, contact):
    """name -> array of every kernel output on the ``N_STATES`` states (stacked)."""
    m, loads = system.model_arrays, system.loads.packed()
    rows: dict[str, list] = {}

    def put(key, value):
        rows.setdefault(key, []).append(np.asarray(value, dtype=float))

    for k in range(N_STATES):
        q, qd, u = _state(system, k)
        put("q", q)
        put("qd", qd)
        put("u", u)
        qdd, ok = K.forward_dynamics_env(q, qd, u, m, loads, aero, contact)
        put("qdd", qdd)
        put("ok", float(ok))
        for want_c in (False, True):
            res = K.coupled_terms_env(q, qd, m, loads, want_c, u, aero, contact)
            for name, value in zip(("M", "C", "Cqd", "tau", "g", "J", "Jd"), res, strict=True):
                put(f"{name}_{int(want_c)}", value)
        put("B", K.input_matrix(q, m))
        if aero.shape[0] == 0 and contact.shape[0] == 0:
            qdd2, _ = K.forward_dynamics(q, qd, u, m, loads)
            put("qdd_plain", qdd2)
        qs, qds, ok = K.rk4_run_env(q, 0.1 * qd, u, 2e-5, 6, 2, m, loads, aero, contact)
        put("rk4_len", qs.shape[0])  # shorter when the mass matrix became singular
        put("rk4_q", np.vstack([qs, np.zeros((4 - qs.shape[0], system.n))]))
        put("rk4_qd", np.vstack([qds, np.zeros((4 - qs.shape[0], system.n))]))
        put("rk4_ok", float(ok))
    return {key: np.stack(v) for key, v in rows.items()}


def _chain_outputs(system):
    m = system.model_arrays
    out: dict[str, list] = {}
    for k in range(N_STATES):
        q, qd, _ = _state(system, k)
        lo, hi = m.rod_steps[0], m.rod_steps[1]
        g, j, jd = K.chain_jacobian(
            q, qd, m.floating, m.g_fixed, m.g_att[0], m.h[lo:hi], m.xi0s[lo:hi], m.bs[lo:hi],
            m.step_col[lo:hi], m.step_nc[lo:hi],
        )  # fmt: skip
        for name, value in (("chain_g", g), ("chain_J", j), ("chain_Jd", jd)):
            out.setdefault(name, []).append(value)
    return {key: np.stack(v) for key, v in out.items()}


def _all_outputs():
    res = {}
    for name, (system, aero, contact) in _systems().items():
        outs = _outputs(system, aero, contact)
        if aero.shape[0] == 0:
            outs.update(_chain_outputs(system))
        for key, value in outs.items():
            res[f"{name}/{key}"] = value
    return res


@pytest.fixture(scope="module")
def reference():
    with np.load(DATA) as f:
        return {key: f[key] for key in f.files}


@pytest.fixture(scope="module")
def current():
    return _all_outputs()


def test_reference_covers_every_case(reference, current):
    assert sorted(reference) == sorted(current)
    assert len(reference) > 100


@pytest.mark.parametrize("case", ["paper", "rich", "sectioned", "dual", "clamped", "paper_env"])
def test_kernels_reproduce_the_frozen_outputs(reference, current, case):
    keys = [k for k in reference if k.startswith(case + "/")]
    assert keys
    for key in keys:
        ref, now = reference[key], current[key]
        assert ref.shape == now.shape, key
        scale = max(1.0, float(np.abs(ref).max()))
        err = float(np.abs(now - ref).max())
        assert err <= TOL * scale, f"{key}: max difference {err:.3e} (scale {scale:.3e})"


def test_the_cases_touch_the_obstacle(reference):
    # the contact case must exercise the contact branch: its tau differs from the plain one
    diff = reference["paper_env/tau_0"] - reference["paper/tau_0"]
    assert np.abs(diff).max() > 1e-6


if __name__ == "__main__":  # written once, from the kernels before their rewrite for speed
    DATA.parent.mkdir(exist_ok=True)
    np.savez_compressed(DATA, **_all_outputs())
    print(f"written {DATA}")
